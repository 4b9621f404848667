""".npy files grown on disk block by block (docs/design.md §2, the windows dataset on disk).

A file is written with a header of fixed size holding a placeholder shape, rows are appended
(:class:`~lanecast.io_adapters.windows_store.direct_file.DirectWriter`: around the page cache where possible),
and the header is rewritten with the final row count on close; ``np.load`` then memory-maps it
like any other .npy file. Shards (a worker's part of a dataset) get a header of one aligned block,
so that their rows can be appended to the dataset by direct reads as well.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.windows_store.direct_file import ALIGN, DirectWriter

HEADER_BYTES = 128  # a dataset array's header (magic + length + dict, padded)
SHARD_HEADER_BYTES = ALIGN  # a shard's: its rows start on an aligned offset


def npy_header(dtype: np.dtype, shape: tuple[int, ...], size: int = HEADER_BYTES) -> bytes:
    """A version 1.0 .npy header of exactly ``size`` bytes (a multiple of 64)."""
    text = f"{{'descr': {dtype.str!r}, 'fortran_order': False, 'shape': {shape!r}, }}"
    pad = size - 10 - len(text) - 1
    if pad < 0:
        raise ValueError(f"shape {shape} does not fit a {size}-byte header")
    body = (text + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + len(body).to_bytes(2, "little") + body


def read_npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, offset of the data) of a C-order .npy file; InputError if it is none."""
    try:
        with path.open("rb") as src:
            version = np.lib.format.read_magic(src)
            read = (
                np.lib.format.read_array_header_1_0
                if version == (1, 0)
                else np.lib.format.read_array_header_2_0
            )
            shape, fortran, dtype = read(src)
            offset = src.tell()
    except (OSError, ValueError) as exc:
        raise InputError(path, f"not a readable .npy array: {exc}") from exc
    if fortran:
        raise InputError(path, "a Fortran-order .npy array", expected="C order")
    return tuple(shape), np.dtype(dtype), offset


class NpyAppender:
    """A .npy file of rows [N, *row_shape] grown on disk: :meth:`append` blocks or
    :meth:`append_npy` other files' rows, then :meth:`close` writes the final row count."""

    def __init__(
        self,
        path: Path,
        dtype: np.dtype,
        row_shape: tuple[int, ...],
        *,
        header_bytes: int = HEADER_BYTES,
        direct: bool = True,
    ) -> None:
        self.path, self.dtype, self.row_shape = path, np.dtype(dtype), tuple(row_shape)
        self.header_bytes = header_bytes
        self.rows = 0
        self._reserved: np.ndarray | None = None
        self._out = DirectWriter(path, direct=direct)
        self._out.write(npy_header(self.dtype, (0, *self.row_shape), header_bytes))

    def reserve(self, rows: int) -> np.ndarray:
        """The next ``rows`` rows [rows, *row_shape] as an array in the file's staging memory, to
        fill and then :meth:`append` without a copy (valid until the next append)."""
        row_bytes = self.dtype.itemsize * int(np.prod(self.row_shape))
        view = self._out.reserve(rows * row_bytes)
        self._reserved = np.frombuffer(view, dtype=self.dtype).reshape(rows, *self.row_shape)
        return self._reserved

    def append(self, block: np.ndarray) -> None:
        """Append rows [B, *row_shape] (C order): the array :meth:`reserve` gave, or any other."""
        if block.dtype != self.dtype or block.shape[1:] != self.row_shape:
            raise ValueError(f"{self.path.name}: block {block.dtype}{block.shape} does not match the array")
        reserved, self._reserved = self._reserved, None
        if reserved is not None and _same_memory(block, reserved):
            self._out.commit(block.nbytes)
        elif block.size:
            self._out.write(np.ascontiguousarray(block).reshape(-1).view(np.uint8))
        self.rows += block.shape[0]

    def append_npy(self, path: Path) -> int:
        """Append the rows of a .npy file (same dtype and row shape) by copying its bytes; its row count."""
        shape, dtype, offset = read_npy_header(path)
        if dtype != self.dtype or shape[1:] != self.row_shape:
            raise InputError(
                path, f"shard array {dtype}{list(shape)}", expected=f"{self.dtype}[N, *{self.row_shape}]"
            )
        rows = int(shape[0]) if shape else 0
        copied = self._out.append_file(path, offset)
        expected = rows * self.dtype.itemsize * int(np.prod(self.row_shape))
        if copied != expected:
            raise InputError(path, f"{copied} bytes of rows", expected=f"{expected} bytes for shape {shape}")
        self.rows += rows
        return rows

    def close(self) -> None:
        """Write the final shape into the header and close."""
        self._out.close(npy_header(self.dtype, (self.rows, *self.row_shape), self.header_bytes))

    def abort(self) -> None:
        self._out.abort()


def _same_memory(a: np.ndarray, b: np.ndarray) -> bool:
    """``a`` is exactly the array ``b`` (same first byte, shape and strides)."""
    return (
        a.__array_interface__["data"][0] == b.__array_interface__["data"][0]
        and a.shape == b.shape
        and a.strides == b.strides
    )


def save_npy(path: Path, array: np.ndarray, *, header_bytes: int = HEADER_BYTES) -> Path:
    """``array`` [N, ...] as a .npy file written through :class:`NpyAppender` (a shard: with
    ``header_bytes`` SHARD_HEADER_BYTES)."""
    out = NpyAppender(path, array.dtype, array.shape[1:], header_bytes=header_bytes)
    try:
        out.append(array)
    except BaseException:
        out.abort()
        raise
    out.close()
    return path
