"""Arrow columns read as numpy arrays from their buffers, without ``pyarrow.compute``.

Importing ``pyarrow.compute`` builds a Python wrapper, signature and docstring for each of Arrow's
several hundred compute functions: 0.04 s, a sixth of a short command such as ``lanecast info``.
What every read needs of a column (where it is null, its values with nulls filled, the codes of a
dictionary column, whether a string holds a byte) is read here from the validity bitmap, the data
buffer or the dictionary indices; the rest of lanecast imports ``pyarrow.compute`` where it uses it.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TypeAlias

import numpy as np
import pyarrow as pa

Column: TypeAlias = pa.Array | pa.ChunkedArray


def _chunks(column: Column) -> Iterator[pa.Array]:
    yield from column.chunks if isinstance(column, pa.ChunkedArray) else [column]


def _valid(chunk: pa.Array) -> np.ndarray:
    if chunk.null_count == 0:
        return np.ones(len(chunk), dtype=bool)
    bitmap = chunk.buffers()[0]
    if bitmap is None:  # the null type: no bitmap, every value null
        return np.zeros(len(chunk), dtype=bool)
    bits = np.unpackbits(np.frombuffer(bitmap, dtype=np.uint8), bitorder="little")
    return bits[chunk.offset : chunk.offset + len(chunk)].astype(bool)


def valid_mask(column: Column) -> np.ndarray:
    """bool [n]: True where ``column`` holds a value, False where it is null."""
    parts = [_valid(chunk) for chunk in _chunks(column)]
    return np.concatenate(parts) if parts else np.zeros(0, dtype=bool)


def _stored(chunk: pa.Array) -> np.ndarray:
    """The values [n] of a fixed-width numeric ``chunk`` as its data buffer holds them (whatever
    lies under a null), a view of the buffer."""
    dtype = np.dtype(chunk.type.to_pandas_dtype())
    if len(chunk) == 0:
        return np.zeros(0, dtype=dtype)
    return np.frombuffer(chunk.buffers()[1], dtype=dtype)[chunk.offset : chunk.offset + len(chunk)]


def filled(column: Column, fill: int | float) -> np.ndarray:
    """The values [n] of a fixed-width numeric ``column`` in its own numpy type, ``fill`` where null
    (exact for 64-bit integers, which a conversion through float64 is not)."""
    parts = []
    for chunk in _chunks(column):
        values = _stored(chunk)
        parts.append(
            values if chunk.null_count == 0 else np.where(_valid(chunk), values, values.dtype.type(fill))
        )
    if not parts:
        return np.zeros(0, dtype=np.dtype(column.type.to_pandas_dtype()))
    return np.concatenate(parts) if len(parts) > 1 else parts[0]


def holds_any_byte(column: Column, needles: bytes) -> bool:
    """Whether a value of the ``string`` or ``large_string`` ``column`` holds one of the bytes
    ``needles``: the bytes its values use (between their first and last offset), searched in place."""
    for chunk in _chunks(column):
        if len(chunk) == 0:
            continue
        offsets_dtype = np.int64 if pa.types.is_large_string(chunk.type) else np.int32
        offsets = np.frombuffer(chunk.buffers()[1], dtype=offsets_dtype)
        lo, hi = int(offsets[chunk.offset]), int(offsets[chunk.offset + len(chunk)])
        if hi == lo:
            continue
        data = np.frombuffer(chunk.buffers()[2], dtype=np.uint8, count=hi - lo, offset=lo)
        if any((data == needle).any() for needle in needles):  # a null value's bytes are empty
            return True
    return False


def dictionary_codes(column: Column) -> tuple[np.ndarray, np.ndarray]:
    """(sorted entries str [K] that some row uses, the entry of each row as a code int64 [n]) of a
    dictionary ``column`` without nulls, without a string per row: one pass over each chunk's
    indices finds the entries in use (a slice keeps its parent's whole dictionary), one maps them."""
    chunks = [c for c in _chunks(column) if len(c)]
    entries = [np.asarray(c.dictionary.to_pylist(), dtype=object).astype(str) for c in chunks]
    indices = [c.indices.to_numpy(zero_copy_only=False) for c in chunks]
    used = [e[np.bincount(i, minlength=e.size) > 0] for e, i in zip(entries, indices, strict=True)]
    names = np.unique(np.concatenate(used)) if used else np.zeros(0, dtype=str)
    codes = np.empty(len(column), dtype=np.int64)
    lo = 0
    for e, i in zip(entries, indices, strict=True):  # an unused entry maps anywhere: never read
        np.take(np.searchsorted(names, e), i, out=codes[lo : lo + i.size], mode="clip")
        lo += i.size
    return names.astype(str), codes


def take(column: Column, order: np.ndarray) -> pa.Array:
    """``column.take(order)`` (``order`` int [m], rows of ``column``): numeric and dictionary columns
    gathered by numpy from their buffers, any other type by Arrow's take."""
    kind = column.type
    if pa.types.is_dictionary(kind):
        chunks = list(_chunks(column))
        dictionary = chunks[0].dictionary if chunks else pa.array([], kind.value_type)
        if all(c.dictionary.equals(dictionary) for c in chunks[1:]):
            indices = take(pa.chunked_array([c.indices for c in chunks], kind.index_type), order)
            return pa.DictionaryArray.from_arrays(indices, dictionary)
    elif pa.types.is_integer(kind) or pa.types.is_floating(kind):
        chunks = list(_chunks(column))  # a null's stored value is gathered too, and never read
        source = _stored(chunks[0]) if len(chunks) == 1 else filled(column, 0)
        # the gather written into Arrow's memory pool, whose pages are reused (a fresh numpy array's are
        # faulted in anew: twice the time)
        values = pa.allocate_buffer(len(order) * source.dtype.itemsize)
        np.take(source, order, out=np.frombuffer(values, dtype=source.dtype))
        if column.null_count == 0:
            return pa.Array.from_buffers(kind, len(order), [None, values], null_count=0)
        valid = np.take(valid_mask(column), order)
        bitmap = pa.py_buffer(np.packbits(valid, bitorder="little"))
        nulls = len(order) - int(np.count_nonzero(valid))
        return pa.Array.from_buffers(kind, len(order), [bitmap, values], null_count=nulls)
    import pyarrow.compute as pc  # other types: not on every start

    taken = pc.take(column, pa.array(order))
    return taken.combine_chunks() if isinstance(taken, pa.ChunkedArray) else taken
