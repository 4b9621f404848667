"""Keep freed memory in the process for reuse (glibc), for the streaming commands.

`convert` and `windows` allocate and free the same large arrays piece after piece. By default glibc
hands blocks above its mmap threshold (at most 32 MB, adjusted as the program runs) straight back to
the kernel and trims the heap top, so every piece faults in fresh, zeroed pages: system time that
grows with the rows (measured in BENCHMARKS.md, "Whole datasets"). Raising both thresholds keeps
what one piece freed for the next; the high-water mark, and so the peak memory, is the same.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
KEEP_BYTES = 1 << 30  # blocks up to this size come from the heap; this much freed memory is kept


@functools.cache
def keep_freed_memory(keep_bytes: int = KEEP_BYTES) -> bool:
    """Ask glibc to keep up to ``keep_bytes`` of freed memory for reuse; False where the C library
    is not glibc (nothing changes then). Once per process."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, keep_bytes)) and bool(mallopt(M_TRIM_THRESHOLD, keep_bytes))
