"""Large outputs written around the page cache: sequential appends through one aligned staging
buffer with ``O_DIRECT`` where the file system allows it, plain buffered writes elsewhere.

Why: a windows dataset is mostly one 1.2 GB-per-10 M-rows ``inputs.npy`` written once and read
later. Through the page cache, every written page is fresh memory for the kernel to find and
fault in; on a virtual machine that returns freed memory to its host (this project's machines)
that costs about 2 s of system time per GB, more than cutting the windows. Written directly, the
same bytes go from one reused 8 MB buffer to the disk (0.1 s of system time per GB measured
here, BENCHMARKS.md). The bytes in the file are the same either way.

A direct write makes the caller wait for the disk (0.5 s per GB here, with almost no CPU), so
:meth:`DirectWriter.commit` hands the filled staging buffer to a writer thread and goes on in a
second one: the disk writes while the next piece is cut.
"""

from __future__ import annotations

import mmap
import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

ALIGN = 4096  # file offsets, lengths and buffer addresses of direct I/O are multiples of this
STAGE_BYTES = 8 << 20  # the staging buffer (a multiple of ALIGN)
O_DIRECT: int = getattr(os, "O_DIRECT", 0)


def _round_up(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def _open_direct(path: Path, flags: int) -> int | None:
    """A file descriptor of ``path`` opened with O_DIRECT, or None where the system or file system
    has none (macOS, some tmpfs): the caller falls back to buffered I/O."""
    if not O_DIRECT:
        return None
    try:
        return os.open(path, flags | O_DIRECT, 0o666)
    except OSError:
        return None


class DirectWriter:
    """Appends bytes to a new file ``path`` sequentially; :meth:`close` then rewrites its first
    bytes (a header whose size was reserved at the start) and sets its exact length.

    ``direct=False`` forces buffered writes (what happens anyway where O_DIRECT is refused).
    """

    def __init__(self, path: Path, *, direct: bool = True) -> None:
        self.path = path
        flags = os.O_RDWR | os.O_CREAT | os.O_TRUNC
        fd = _open_direct(path, flags) if direct else None
        self.direct = fd is not None
        self._fd = fd if fd is not None else os.open(path, flags, 0o666)
        self._stage = mmap.mmap(-1, STAGE_BYTES)  # page-aligned, reused for every write
        self._view = memoryview(self._stage)
        self._filled = 0  # bytes in the staging buffer
        self._flushed = 0  # bytes in the file (a multiple of ALIGN when direct)
        self._read: mmap.mmap | None = None  # a buffer for direct reads (append_file)
        self._spare: mmap.mmap | None = None  # the other staging buffer (commit), maybe being written
        self._pending: Future[None] | None = None  # the write of the spare
        self._thread: ThreadPoolExecutor | None = None

    @property
    def size(self) -> int:
        """Bytes written so far."""
        return self._flushed + self._filled

    def write(self, data: Any) -> None:
        """Append ``data`` (any C-contiguous buffer)."""
        src = memoryview(data).cast("B")
        if not self.direct and self._filled == 0 and len(src) >= len(self._stage):
            self._write_all(src)  # buffered: large blocks need no staging
            return
        while len(src):
            n = min(len(src), len(self._stage) - self._filled)
            self._view[self._filled : self._filled + n] = src[:n]
            self._filled += n
            src = src[n:]
            if self._filled == len(self._stage):
                self._write_all(self._view)
                self._filled = 0

    def reserve(self, nbytes: int) -> memoryview:
        """The next ``nbytes`` of the file as writable memory (in the staging buffer, grown if
        needed): fill it, then :meth:`commit` it, with no write in between. Saves the copy of
        :meth:`write` for data computed in place."""
        end = self._filled + nbytes
        if end > len(self._stage):
            grown = mmap.mmap(-1, max(_round_up(end), len(self._stage) * 3 // 2 // ALIGN * ALIGN))
            grown[: self._filled] = self._stage[: self._filled]
            self._stage, self._view = grown, memoryview(grown)  # the old one goes with its last view
        return self._view[self._filled : end]

    def commit(self, nbytes: int) -> None:
        """Append the ``nbytes`` filled in by the caller after :meth:`reserve`."""
        self._filled += nbytes
        if not self.direct:
            self._write_all(self._view[: self._filled])
            self._filled = 0
            return
        whole = self._filled // ALIGN * ALIGN  # written now, by the thread; the tail waits for more
        if whole:
            tail = self._filled - whole
            nxt = self._wait()
            if nxt is None:
                nxt = mmap.mmap(-1, len(self._stage))
            nxt[:tail] = self._stage[whole : self._filled]
            if self._thread is None:
                self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="direct-write")
            self._pending = self._thread.submit(self._pwrite, self._view[:whole], self._flushed)
            self._flushed += whole
            self._spare, self._stage, self._view = self._stage, nxt, memoryview(nxt)
            self._filled = tail

    def append_file(self, path: Path, start: int) -> int:
        """Append the bytes of file ``path`` from offset ``start`` to its end (read directly too
        when ``start`` is aligned: no page cache on either side); the number of bytes."""
        fd = _open_direct(path, os.O_RDONLY) if self.direct and start % ALIGN == 0 else None
        if fd is None:
            fd = os.open(path, os.O_RDONLY)
        if self._read is None:
            self._read = mmap.mmap(-1, STAGE_BYTES)  # direct reads need an aligned buffer
        buf, total = memoryview(self._read), 0
        try:
            while True:
                n = os.preadv(fd, [buf], start + total)
                if n == 0:
                    return total
                self.write(buf[:n])
                total += n
        finally:
            os.close(fd)

    def close(self, header: bytes) -> None:
        """Write the staged tail, put ``header`` at offset 0 (over bytes reserved there) and close."""
        size = self.size
        try:
            self._wait()
            if self.direct:
                padded = _round_up(self._filled)
                self._view[self._filled : padded] = bytes(padded - self._filled)
                self._write_all(self._view[:padded])
                first = self._view[:ALIGN]  # read-modify-write the first aligned block
                os.preadv(self._fd, [first], 0)
                first[: len(header)] = header
                os.pwrite(self._fd, first, 0)
                os.ftruncate(self._fd, size)
            else:
                self._write_all(self._view[: self._filled])
                os.pwrite(self._fd, header, 0)
            self._filled = 0
        finally:
            self.abort()

    def abort(self) -> None:
        """Close without finishing (idempotent); a write still running is waited for first."""
        try:
            self._wait()
        except OSError:
            pass  # the file is abandoned anyway
        finally:
            if self._thread is not None:
                self._thread.shutdown()
                self._thread = None
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1

    def _wait(self) -> mmap.mmap | None:
        """Wait for the thread's write (raising its error) and return the spare buffer, free."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()
        return self._spare

    def _write_all(self, data: memoryview) -> None:
        """Write ``data`` at the end of the flushed bytes (aligned offsets and lengths when direct)."""
        self._pwrite(data, self._flushed)
        self._flushed += len(data)

    def _pwrite(self, data: memoryview, offset: int) -> None:
        done = 0
        while done < len(data):
            n = os.pwrite(self._fd, data[done:], offset + done)
            if n <= 0:
                raise OSError(f"{self.path}: wrote {n} bytes")
            done += n
