"""Keep freed memory in the process for reuse (glibc), for the streaming commands.

`convert` and `windows` allocate and free the same large arrays piece after piece. By default glibc
hands blocks above its mmap threshold (at most 32 MB, adjusted as the program runs) straight back to
the kernel and trims the heap top, so every piece faults in fresh, zeroed pages: system time that
grows with the rows (measured in BENCHMARKS.md, "Whole datasets"). Raising both thresholds keeps
what one piece freed for the next; the high-water mark, and so the peak memory, is the same.
With ``arrow``, Arrow's buffers (Parquet pages, filtered and concatenated tables) move to the same
heap: its default pool (mimalloc) returns freed memory to the kernel between pieces. `windows`
asks for it (a track group of a long recording: system time 1.9-2.4 -> 0.5 s on 30 minutes, peak 0.97
-> 0.86 GB); `convert` does not (its peak rose 0.6 -> 1.0 GB on 120 minutes, for 0.1 s).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

import pyarrow as pa

M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
KEEP_BYTES = 1 << 30  # blocks up to this size come from the heap; this much freed memory is kept


@functools.cache
def keep_freed_memory(keep_bytes: int = KEEP_BYTES, arrow: bool = False) -> bool:
    """Ask glibc to keep up to ``keep_bytes`` of freed memory for reuse (and with ``arrow`` Arrow
    to allocate from it); False where the C library is not glibc (nothing changes then). Once per
    process."""
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
    if not (mallopt(M_MMAP_THRESHOLD, keep_bytes) and mallopt(M_TRIM_THRESHOLD, keep_bytes)):
        return False
    if arrow:
        pa.set_memory_pool(pa.system_memory_pool())
    return True
