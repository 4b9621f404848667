"""Text fields at byte spans of a wire buffer, column-wise: strings, categories, decimal numbers.

Protobuf strings are spans buf[starts[i]:ends[i]] of one byte buffer; these helpers read many at
once without making a Python string per value: fixed-width byte windows, short strings packed into
one integer each (equal codes ⇔ equal strings) and factorised into categories, and decimal
strings parsed in bulk by Arrow's correctly rounded string-to-float cast (anything it refuses goes
through ``float()``, whose ValueError then says what is wrong). Used by
:mod:`lanecast.io_adapters.logs.foxglove.scene_update_decode`.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.logs.messages.protobuf_wire import windows

_MAX_STRING = 256  # bytes kept of a string (class names, frame ids, ids): bounds the [n, width] work


def strings(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Byte strings buf[starts[i]:ends[i]] (at most _MAX_STRING bytes) as a fixed-width bytes array [n]."""
    lengths = np.minimum(ends - starts, _MAX_STRING)
    width = max(int(lengths.max()) if lengths.size else 1, 1)
    raw = windows(buf, starts, width)
    raw = np.where(np.arange(width)[None, :] < lengths[:, None], raw, 0).astype(np.uint8)
    return raw.view(f"S{width}").ravel()


_MAX_NUMBER = 64  # longer decimal strings are parsed one by one (bounds the [n, width] work)


def _binary_of_spans(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> pa.Array:
    """Arrow binary [2n]: element 2i is buf[starts[i]:ends[i]] (at most _MAX_NUMBER bytes), odd
    elements are null (the padding between the values, so one gather of fixed windows suffices)."""
    n = starts.size
    lengths = np.minimum(ends - starts, _MAX_NUMBER)
    width = max(int(lengths.max()) if n else 0, 1)
    raw = np.ascontiguousarray(windows(buf, starts, width))
    offsets = np.empty(2 * n + 1, dtype=np.int64)
    offsets[0::2] = np.arange(n + 1, dtype=np.int64) * width
    offsets[1::2] = offsets[0:-1:2] + lengths
    validity = np.full((2 * n + 7) // 8, 0x55, dtype=np.uint8)  # bits 0, 2, 4, …: the values
    return pa.Array.from_buffers(
        pa.large_binary(),
        2 * n,
        [pa.py_buffer(validity), pa.py_buffer(offsets), pa.py_buffer(raw)],
        null_count=n,
    )


def _cast_spans(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, dtype: pa.DataType) -> np.ndarray:
    """Decimal strings buf[starts[i]:ends[i]] [n] → values [n] by Arrow's cast (raises ArrowInvalid)."""
    out = pc.cast(_binary_of_spans(buf, starts, ends), dtype)
    values = np.frombuffer(out.buffers()[1], dtype=dtype.to_pandas_dtype(), count=2 * starts.size)
    return values[0::2]


def parse_floats(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Decimal strings buf[starts[i]:ends[i]] [n] → float64 [n], the values Python's float() gives
    (Arrow's correctly rounded parser; anything it refuses goes through float(), whose ValueError
    then says what is wrong)."""
    if not starts.size:
        return np.zeros(0)
    long = (ends - starts) > _MAX_NUMBER
    try:
        value = np.array(_cast_spans(buf, starts, ends, pa.float64()))
    except pa.ArrowInvalid:
        long[:] = True
        value = np.zeros(starts.size)
    if long.any():
        bad = np.flatnonzero(long)
        value[bad] = [float(bytes(buf[starts[i] : ends[i]])) for i in bad.tolist()]
    return value


_LOW_BYTES = np.array([(1 << (8 * k)) - 1 for k in range(8)], dtype=np.uint64)


def short_codes(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """uint64 [n]: strings buf[starts[i]:ends[i]] of at most 7 bytes packed with their length
    (bytes little-endian, length in the top byte): equal codes ⇔ equal strings. Longer ones: 0."""
    length = ends - starts
    short = (length >= 0) & (length <= 7)
    word = np.ascontiguousarray(windows(buf, starts, 8)).view("<u8").ravel()
    code = (word & _LOW_BYTES[np.where(short, length, 0)]) | (length.astype(np.uint64) << np.uint64(56))
    return np.where(short, code, np.uint64(0))


def _factorize(codes: np.ndarray, limit: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """uint64 codes [n] → (int32 index [n] into the distinct codes, distinct codes): one pass per
    distinct value while there are few (classes, frame ids), else a sort."""
    out = np.zeros(codes.size, dtype=np.int32)
    distinct: list[int] = []
    rest = codes
    where = np.arange(codes.size)
    while rest.size and len(distinct) < limit:
        same = rest == rest[0]
        out[where[same]] = len(distinct)
        distinct.append(int(rest[0]))
        if same.all():
            return out, np.asarray(distinct, dtype=np.uint64)
        rest, where = rest[~same], where[~same]
    cats, inverse = np.unique(codes, return_inverse=True)
    return inverse.astype(np.int32).ravel(), cats


def text(raw: bytes, what: str) -> str:
    """``raw`` (a protobuf string field, at most _MAX_STRING bytes kept) as text; ValueError naming
    ``what`` if it is not UTF-8 (protobuf strings must be: a damaged byte would otherwise become
    U+FFFD and a new class, frame or track). A character cut by the _MAX_STRING limit is dropped."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        if len(raw) == _MAX_STRING and exc.reason == "unexpected end of data":
            return raw[: exc.start].decode("utf-8")
        raise ValueError(
            f"{what} {raw[:40]!r} is not UTF-8 (byte {exc.start} of the string; protobuf strings are UTF-8)"
        ) from None


def check_text(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, what: str) -> None:
    """ValueError (see :func:`text`) if a string buf[starts[i]:ends[i]] is not UTF-8; the common
    all-ASCII case costs one pass over the bytes, without a Python string per value."""
    if not starts.size:
        return
    raw = strings(buf, starts, ends)
    high = (raw.view(np.uint8).reshape(raw.size, -1) >= 0x80).any(axis=1)
    for value in np.unique(raw[high]).tolist():
        text(value, what)


def categories(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, what: str = "a string field"
) -> tuple[np.ndarray, list[str]]:
    """Strings buf[starts[i]:ends[i]] [n] → (int32 codes [n], category strings); ValueError if one
    is not UTF-8."""
    if not starts.size:
        return np.zeros(0, np.int32), []
    if int((ends - starts).max()) <= 7:  # class names, frame ids: one integer each
        codes, cats = _factorize(short_codes(buf, starts, ends))
        names = [(c & ((1 << 56) - 1)).to_bytes(c >> 56, "little") for c in cats.tolist()]
    else:
        uniq, inverse = np.unique(strings(buf, starts, ends), return_inverse=True)
        codes, names = inverse.astype(np.int32).ravel(), uniq.tolist()
    return codes, [text(c, what) for c in names]
