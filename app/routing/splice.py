"""Copy-on-write patching of a graph's column arrays, in proportion to what an edit touches.

A graph version is immutable (requests may still search an older one), so an edit builds the
next version's arrays from the previous ones. Rebuilding them from all rows costs seconds on a
million segments (sorts, unique, per-vertex geometry); an edit touches a handful of rows. So:
a column the edit leaves unchanged is shared, a changed one is copied once with its rows
patched (:func:`replaced`, :func:`spliced`), and when rows come and go (a split, a merge, a
segment added or deleted) the next version's columns are laid out as runs of the previous
ones around the fresh rows (:class:`Layout`): memory copies, no sorting.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


def ragged_take(offsets: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and flat gather indices selecting the variable-length runs ``idx``."""
    lengths = offsets[idx + 1] - offsets[idx]
    new_offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    gather = np.repeat(offsets[idx] - new_offsets[:-1], lengths) + np.arange(new_offsets[-1])
    return new_offsets, gather


def replaced(column: np.ndarray, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``column`` with ``values`` at ``rows``: the very same array when nothing changes there
    (later versions share it), else a patched copy (earlier versions may still be searched)."""
    if np.array_equal(column[rows], values, equal_nan=column.dtype.kind == "f"):
        return column
    out = column.copy(order="K")
    out[rows] = values
    return out


def spliced(offsets: np.ndarray, values: np.ndarray, rows: np.ndarray,
            new_offsets: np.ndarray, new_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A ragged array (runs delimited by ``offsets``) with the runs at ``rows`` (ascending)
    replaced by the runs of ``new_values``. Same run lengths: patched in place of a copy (or
    shared when equal); otherwise the untouched stretches are copied around the new runs."""
    new_lengths = np.diff(new_offsets)
    if np.array_equal(offsets[rows + 1] - offsets[rows], new_lengths):
        return offsets, replaced(values, ragged_take(offsets, rows)[1], new_values)
    lengths = np.diff(offsets)
    lengths[rows] = new_lengths
    pieces, after = [], 0
    for i, r in enumerate(rows.tolist()):
        pieces += [values[offsets[after]:offsets[r]], new_values[new_offsets[i]:new_offsets[i + 1]]]
        after = r + 1
    pieces.append(values[offsets[after]:])
    return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64), np.concatenate(pieces)


@dataclass(frozen=True)
class Layout:
    """Rows of a patched table, in id order: runs ``(True, a, b)`` of the old rows ``a:b``
    and ``(False, i, j)`` of the fresh rows ``i:j``. Old rows that were replaced or deleted
    are in no run."""

    runs: tuple[tuple[bool, int, int], ...]
    n_old: int

    @classmethod
    def of(cls, old_ids: np.ndarray, rows: np.ndarray, fresh_ids: np.ndarray) -> Layout:
        """Old rows (ids ascending) without ``rows`` (ascending), plus the fresh rows (ids
        ascending, a replaced row's id included) each where its id belongs."""
        places = np.searchsorted(old_ids, fresh_ids).astype(np.int64)  # fresh i before row
        # Every part int64: an empty part of another type (no fresh rows, as when an isolated
        # segment is deleted) would make the bounds floats, which cannot slice.
        bounds = np.unique(np.concatenate([np.array([0, len(old_ids)], np.int64),
                                           rows.astype(np.int64), rows.astype(np.int64) + 1,
                                           places]))
        before = places.tolist()
        gone = set(rows.tolist())
        runs: list[tuple[bool, int, int]] = []
        i = 0
        for a, b in itertools.pairwise(bounds.tolist()):
            j = i
            while j < len(before) and before[j] == a:
                j += 1
            if j > i:
                runs.append((False, i, j))
                i = j
            if a not in gone:
                runs.append((True, a, b))
        if i < len(before):
            runs.append((False, i, len(before)))
        return cls(tuple(runs), len(old_ids))

    def join(self, old: np.ndarray, fresh: np.ndarray) -> np.ndarray:
        """A per-row array of the patched table (1-D, or rows of a 2-D array)."""
        parts = [(old if kept else fresh)[a:b] for kept, a, b in self.runs]
        return np.concatenate(parts) if parts else old[:0]

    def join_ragged(self, old_offsets: np.ndarray, old: np.ndarray, fresh_offsets: np.ndarray,
                    fresh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(offsets, values) of a ragged per-row array of the patched table."""
        lengths = self.join(np.diff(old_offsets), np.diff(fresh_offsets))
        parts = [old[old_offsets[a]:old_offsets[b]] if kept else
                 fresh[fresh_offsets[a]:fresh_offsets[b]] for kept, a, b in self.runs]
        values = np.concatenate(parts) if parts else old[:0]
        return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64), values

    def row_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(new row of every old row, -1 where dropped; new row of every fresh row)."""
        old_to_new = np.full(self.n_old, -1, np.int64)
        fresh_to_new: list[np.ndarray] = []
        at = 0
        for kept, a, b in self.runs:
            if kept:
                old_to_new[a:b] = np.arange(at, at + b - a)
            else:
                fresh_to_new.append(np.arange(at, at + b - a))
            at += b - a
        return old_to_new, (np.concatenate(fresh_to_new) if fresh_to_new
                            else np.zeros(0, np.int64))
