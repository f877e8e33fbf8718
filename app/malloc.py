"""glibc's malloc capped at a few arenas in a serving process.

glibc gives each thread that allocates while another holds the main arena an arena of its own
(up to 8 per core), and memory freed in an arena goes back to the system only from the top of
its heap. A worker answers heavy requests (a 5,000-point match, 10,000 features, a whole
Lanelet2 map) on the thread pool's threads, so each thread grew an arena of its own, and
fragments of them stayed after the load: ``bench/heavy_mix.py``'s server was at 1.19-1.24x its
size 30 s after the load in four runs. With two arenas per process (``MALLOC_ARENA_MAX=2``,
the usual setting for threaded Python servers): 1.12x and 1.13x, light requests' p99 no
slower. ``mallopt`` sets the same limit from inside the process, before the thread pool's
threads exist, so ``ugvmap serve`` with one worker (no new process) gets it too.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_ARENA_MAX = -8
"""``mallopt``'s parameter number for the arena limit (glibc's malloc.h)."""
ARENAS = 2


def cap_arenas(arenas: int = ARENAS) -> bool:
    """Limit the process to ``arenas`` malloc arenas; False where the C library is not glibc
    (nothing changed)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):  # not glibc: musl has no mallopt
        return False
    return bool(mallopt(M_ARENA_MAX, arenas))
