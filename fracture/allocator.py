"""Keep freed memory in the process for the next allocation of the same size.

Every refinement iteration allocates and frees the same large arrays again
(hash grids, pair lists, edge tables: tens of MB at 100K triangles). glibc
hands blocks above its mmap threshold back to the kernel on ``free`` and
trims the top of its heap beyond another threshold, so each new array is
zeroed and faulted in again page by page (``docs/design-measurements.md`` has the
counts). With both thresholds raised, freed blocks stay in the heap and the
next arrays reuse pages already mapped.

The setting is process-wide and lasts: a process keeps the memory of its
peak (which it had anyway) until it ends. Without glibc (macOS, musl) this
does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_LARGE = 1 << 30  # blocks up to 1 GiB come from the heap, and up to 1 GiB free stays there
_CLASSIC_MAX = 32 << 20  # the largest mmap threshold every glibc accepts (64-bit)

_done = False


def keep_freed_memory() -> bool:
    """Tell glibc to keep freed blocks for reuse (module notes); returns whether it took the setting.

    Safe to call more than once; only the first call does anything.
    """
    global _done
    if _done:
        return True
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):  # no glibc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    if not (mallopt(_M_MMAP_THRESHOLD, _LARGE) or mallopt(_M_MMAP_THRESHOLD, _CLASSIC_MAX)):
        return False
    mallopt(_M_TRIM_THRESHOLD, _LARGE)
    _done = True
    return True
