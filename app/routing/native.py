"""How the routing hot paths are compiled: numba, ahead of the first request.

Why compiled: a city route is planned in well under a millisecond, and after three rounds of
vectorising, most of what was left was numpy's cost per call (1-3 us each, dozens per request)
on arrays of a few dozen to a few hundred elements: snapping measured ~16 candidate segments
with ~30 array operations (74 us), the overview's simplification and polyline encoding took
another ~120 us. A loop compiled by numba (LLVM) does the same arithmetic in a few
microseconds, and reads like the scalar maths it is.

Each kernel is compiled for the argument types it is given in :func:`kernel`'s signature when
its module is imported, and kept in numba's on-disk cache (``__pycache__`` beside the source,
or ``NUMBA_CACHE_DIR``): the first import on a machine compiles (a few seconds, once), later
ones load the machine code in milliseconds, and no request ever waits for a compiler.
``error_model="numpy"``: a division by zero gives inf/NaN as numpy does, never an exception.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from numba import njit

F = TypeVar("F", bound=Callable[..., Any])


def kernel(signature: str) -> Callable[[F], F]:
    """Compile the decorated function now for ``signature`` (numba's notation), cached on disk,
    releasing the GIL (plans also run in the thread pool)."""
    return njit(signature, cache=True, nogil=True, error_model="numpy")  # type: ignore[return-value]
