"""Reading a drive's frames: a directory with ``frames.csv``, or a video + frame times.

* Directory: ``frames.csv`` inside it, header ``t,file`` (``t`` in seconds on the pose clock,
  ``file`` relative to the directory), one row per frame in drive order.
* Video (any file OpenCV's FFmpeg backend reads) plus ``--frame-times`` (a CSV with a ``t``
  column, one row per frame, in order).

With poses from QR codes (``--qr-pose``) the times are not needed (``t`` may be absent).

A frame that cannot be read (missing, corrupt, truncated, or the video ends early) is not an
error of the drive: its ``load`` raises :class:`FrameError` and the job skips and counts it.
Truncation is caught explicitly (a JPEG must end with its EOI marker): decoders otherwise
return the top of a truncated JPEG padded with grey, which would be stitched as ground.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ingest.ipm import IpmInputError

UNREADABLE = "unreadable"


class FrameError(Exception):
    """This frame cannot be used; the message says why (one line)."""


@dataclass(frozen=True)
class FrameRef:
    """One selected frame; ``load`` gives its pixels and is called in a worker thread (for a
    frames directory that is where the file is read and decoded), so a bad frame costs only
    itself and only the frames in flight are in memory."""

    t: float
    """Seconds on the pose clock; NaN when unknown."""
    name: str
    load: Callable[[], np.ndarray]
    """Decode the frame (BGR uint8); raises :class:`FrameError`."""


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Decode JPEG/PNG/... bytes strictly: truncated or corrupt data raises FrameError."""
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise FrameError(f"{name}: truncated JPEG (no end-of-image marker)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if image is None:
        raise FrameError(f"{name}: not a readable image")
    return image


def _file_loader(path: Path) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise FrameError(f"{path.name}: {exc.strerror or exc}") from exc
        return decode_image(data, path.name)
    return load


def _times(rows: list[dict[str, str]], source: Path, line0: int,
           required: bool) -> list[float]:
    times = []
    for i, row in enumerate(rows):
        value = (row.get("t") or "").strip()
        if not value and not required:
            times.append(math.nan)
            continue
        try:
            t = float(value)
        except ValueError:
            t = math.nan
        if not math.isfinite(t):
            raise IpmInputError(f"{source} line {line0 + i}: t {value!r} is not a time in "
                                "seconds")
        times.append(t)
    return times


def _read_csv(path: Path, columns: tuple[str, ...]) -> list[dict[str, str]]:
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in columns if c not in (reader.fieldnames or [])]
            if missing:
                raise IpmInputError(f"{path}: missing column(s) {', '.join(missing)}")
            return list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise IpmInputError(f"{path}: cannot read ({exc})") from exc


@dataclass
class FrameSet:
    """The selected frames of a drive: ``count`` of them, read by iterating."""

    count: int
    frames: Callable[[], Iterator[FrameRef]]

    def __iter__(self) -> Iterator[FrameRef]:
        return self.frames()


def directory_frames(folder: Path, selection: slice, need_times: bool) -> FrameSet:
    """The frames listed in ``folder/frames.csv``; the listing is read and its times checked
    now, the images only when loaded."""
    listing = folder / "frames.csv"
    if not listing.is_file():
        raise IpmInputError(f"{folder}: no frames.csv (header t,file) in the frames directory")
    rows = _read_csv(listing, ("t", "file") if need_times else ("file",))
    times = _times(rows, listing, 2, need_times)
    indices = range(len(rows))[selection]
    refs = [FrameRef(times[i], rows[i]["file"], _file_loader(folder / rows[i]["file"]))
            for i in indices]
    return FrameSet(len(refs), lambda: iter(refs))


def video_frames(video: Path, times_file: Path | None, selection: slice) -> FrameSet:
    """The frames of ``video``, decoded in one sequential pass when iterated (videos cannot
    be read out of order cheaply); frames the video lacks load as :class:`FrameError`."""
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise IpmInputError(f"{video}: not a video OpenCV can read")
    declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    capture.release()
    if times_file is not None:
        times = _times(_read_csv(times_file, ("t",)), times_file, 2, True)
    else:
        times = [math.nan] * max(declared, 0)
    indices = range(len(times))[selection]

    def frames() -> Iterator[FrameRef]:
        cap = cv2.VideoCapture(str(video))
        try:
            position, ended = 0, False
            for i in indices:
                while not ended and position < i:
                    ended = not cap.grab()
                    position += 1
                image = None
                if not ended:
                    ok, image = cap.read()
                    position += 1
                    ended = not ok
                yield FrameRef(times[i], f"{video.name}#{i}", _loaded(image, video, i))
        finally:
            cap.release()

    return FrameSet(len(indices), frames)


def _loaded(image: np.ndarray | None, video: Path, index: int) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        if image is None:
            raise FrameError(f"{video.name}: the video ends or breaks before frame {index}")
        return image
    return load


def open_frames(path: Path, frame_times: Path | None, selection: slice,
                need_times: bool) -> FrameSet:
    """The frames of a drive at ``path`` (directory or video), validated up front."""
    if path.is_dir():
        if frame_times is not None:
            raise IpmInputError("--frame-times is for a video; a frames directory has "
                                "frames.csv")
        return directory_frames(path, selection, need_times)
    if not path.is_file():
        raise IpmInputError(f"{path}: no such frames directory or video")
    if need_times and frame_times is None:
        raise IpmInputError(f"{path} is a video: give its frame times with --frame-times "
                            "times.csv (column t, one row per frame)")
    return video_frames(path, frame_times, selection)
