"""A streaming writer of OSM XML as Lanelet2 and Autoware read it.

Elements arrive in any order (a segment's points, ways and lanelet together) but OSM files
list nodes, then ways, then relations (JOSM and osmium expect it), so each kind goes to its own
temporary file and :meth:`OsmXmlWriter.close` concatenates them: memory stays flat however big
the map. Every element carries ``version="1"`` and ``visible="true"``: JOSM refuses positive
ids without a version, and lanelet2 maps use positive ids.
"""

from __future__ import annotations

import re
import shutil
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from xml.sax.saxutils import escape

import numpy as np

# Characters XML 1.0 cannot carry at all (a name edited in through the API might hold one).
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")
_ATTR = {'"': "&quot;", "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}
Member = tuple[str, int, str]  # (type: way/relation, ref, role)


def attr(value: object) -> str:
    """A value as an XML attribute body (double-quoted)."""
    return escape(_NOT_XML.sub("", str(value)), _ATTR)


def _tags(tags: Mapping[str, object]) -> str:
    return "".join(f'<tag k="{attr(k)}" v="{attr(v)}"/>' for k, v in tags.items()
                   if v is not None)


class OsmXmlWriter:
    """Write nodes, ways and relations to ``path`` (complete only after :meth:`close`)."""

    def __init__(self, path: Path, *, comment: str, meta: Mapping[str, str],
                 bounds: tuple[float, float, float, float],
                 ground: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.path = path
        self.ground = ground  # heights of the ground at lon/lat rows (NaN: none), for ``ele``
        self._dir = tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.name}.")
        parts = Path(self._dir.name)
        self._files = [open(parts / name, "w", encoding="utf-8")  # noqa: SIM115 (closed in close)
                       for name in ("nodes", "ways", "relations")]
        self.comment = comment
        self._meta = " ".join(f'{k}="{attr(v)}"' for k, v in meta.items())
        w, s, e, n = bounds
        self._bounds = f'minlat="{s:.9f}" minlon="{w:.9f}" maxlat="{n:.9f}" maxlon="{e:.9f}"'
        self.counts = {"nodes": 0, "ways": 0, "relations": 0}

    def set_comment(self, comment: str) -> None:
        """The comment heading the file (written at :meth:`close`: it may sum up the map)."""
        self.comment = comment

    def _head(self) -> str:
        comment = re.sub("-(?=-)", "- ", _NOT_XML.sub("", self.comment))  # no "--" in comments
        return ('<?xml version="1.0" encoding="UTF-8"?>\n'
                '<osm version="0.6" generator="ugvmap" upload="false">\n'
                f"<!--\n{comment}\n-->\n<MetaInfo {self._meta}/>\n<bounds {self._bounds}/>\n")

    def nodes(self, ids: np.ndarray, lonlat: np.ndarray, local: np.ndarray,
              ele: float | np.ndarray = 0.0) -> None:
        """Points with their lat/lon (1e-9°, 0.1 mm), Autoware's ``local_x``/``local_y`` (mm)
        and ``ele`` (every node needs one for Autoware): ``ele`` above the ground's height
        where the writer has one (an elevation layer), else above 0."""
        if not len(ids):
            return
        eles = np.broadcast_to(np.asarray(ele, dtype=np.float64), (len(ids),))
        if self.ground is not None:
            eles = eles + np.nan_to_num(self.ground(lonlat), nan=0.0)
        self._files[0].write("".join(
            f'<node id="{i}" visible="true" version="1" lat="{lat:.9f}" lon="{lon:.9f}">'
            f'<tag k="ele" v="{z:.2f}"/><tag k="local_x" v="{x:.3f}"/>'
            f'<tag k="local_y" v="{y:.3f}"/></node>\n'
            for i, lon, lat, x, y, z in zip(ids.tolist(), lonlat[:, 0].tolist(),
                                            lonlat[:, 1].tolist(), local[:, 0].tolist(),
                                            local[:, 1].tolist(), eles.tolist(), strict=True)))
        self.counts["nodes"] += len(ids)

    def ways(self, items: Iterable[tuple[int, Sequence[int], Mapping[str, object]]]) -> None:
        """Ways as (id, node refs, tags)."""
        text = "".join(
            f'<way id="{wid}" visible="true" version="1">'
            + "".join(f'<nd ref="{r}"/>' for r in refs) + _tags(tags) + "</way>\n"
            for wid, refs, tags in items)
        self.counts["ways"] += text.count("<way ")
        self._files[1].write(text)

    def relations(self, items: Iterable[tuple[int, Sequence[Member], Mapping[str, object]]]
                  ) -> None:
        """Relations as (id, members (type, ref, role), tags)."""
        text = "".join(
            f'<relation id="{rid}" visible="true" version="1">'
            + "".join(f'<member type="{t}" ref="{r}" role="{role}"/>' for t, r, role in members)
            + _tags(tags) + "</relation>\n"
            for rid, members, tags in items)
        self.counts["relations"] += text.count("<relation ")
        self._files[2].write(text)

    def close(self) -> None:
        """Write the file: header, nodes, ways, relations (to ``path``, replacing it)."""
        try:
            for f in self._files:
                f.close()
            tmp = Path(self._dir.name) / "osm"
            with open(tmp, "w", encoding="utf-8") as out:
                out.write(self._head())
                for f in self._files:
                    with open(f.name, encoding="utf-8") as part:
                        shutil.copyfileobj(part, out, 1 << 20)
                out.write("</osm>\n")
            tmp.replace(self.path)
        finally:
            self.discard()

    def discard(self) -> None:
        """Drop the temporary parts (after :meth:`close`, or instead of it on failure)."""
        for f in self._files:
            f.close()
        self._dir.cleanup()

    def __enter__(self) -> OsmXmlWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.discard()
