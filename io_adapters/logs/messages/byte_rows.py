"""Many byte strings built column-wise in numpy: how forecast messages are encoded in bulk.

A :class:`ByteRows` is N byte strings held as a padded matrix: ``matrix`` uint8 [N, W] and ``mask``
bool [N, W], row i being the bytes of ``matrix[i]`` where ``mask[i]`` (in order). Messages are
assembled the way a serializer writes them, for all rows at once: a row-wise concatenation is one
``hstack``, grouping every k rows into one is a reshape, an optional field is a mask; the bytes are
compacted once, at the end (:meth:`ByteRows.join`). No Python object per entity, and no index
arithmetic per byte (``lanecast.io_adapters.logs.forecast_messages``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ByteRows:
    """N byte strings: row i = ``matrix[i][mask[i]]`` (uint8 [N, W], bool [N, W])."""

    matrix: np.ndarray
    mask: np.ndarray

    def __len__(self) -> int:
        return self.matrix.shape[0]

    @property
    def lengths(self) -> np.ndarray:
        """int64 [N]."""
        return self.mask.sum(axis=1, dtype=np.int64)

    @classmethod
    def from_matrix(cls, matrix: np.ndarray, lengths: np.ndarray | int) -> ByteRows:
        """Row i = the first ``lengths[i]`` bytes of ``matrix[i]`` (uint8 [N, W])."""
        matrix = np.asarray(matrix, np.uint8)
        lengths = np.broadcast_to(np.asarray(lengths, np.int64), (matrix.shape[0],))
        return cls(matrix, np.arange(matrix.shape[1]) < lengths[:, None])

    @classmethod
    def from_strings(cls, values: np.ndarray) -> ByteRows:
        """Rows from a fixed-width bytes array (numpy ``S`` dtype; no NUL inside a value)."""
        values = np.ascontiguousarray(values)
        if values.dtype.kind != "S":
            raise TypeError(f"expected a bytes (S) array, got {values.dtype}")
        matrix = values.view(np.uint8).reshape(len(values), values.dtype.itemsize)
        return cls(matrix, matrix != 0)

    @classmethod
    def constant(cls, value: bytes, n: int) -> ByteRows:
        """``value`` in each of n rows."""
        row = np.frombuffer(value, np.uint8)
        return cls(np.broadcast_to(row, (n, len(row))), np.ones((n, len(row)), bool))

    def take(self, rows: np.ndarray) -> ByteRows:
        """The rows at ``rows`` (int [M]), in that order."""
        return ByteRows(self.matrix[rows], self.mask[rows])

    def blank(self, keep: np.ndarray) -> ByteRows:
        """The same N rows, those where ``keep`` (bool [N]) is False made empty."""
        return ByteRows(self.matrix, self.mask & np.asarray(keep, bool)[:, None])

    def group_every(self, size: int) -> ByteRows:
        """Every ``size`` consecutive rows joined into one (a reshape)."""
        n, width = len(self) // size, size * self.matrix.shape[1]
        return ByteRows(self.matrix.reshape(n, width), self.mask.reshape(n, width))

    def join(self, bounds: np.ndarray | None = None, separator: bytes = b"") -> list[bytes]:
        """The rows as ``bytes``, or with ``bounds`` (int [G + 1]) group g = rows ``bounds[g]`` to
        ``bounds[g + 1]`` joined by ``separator``."""
        n = len(self)
        rows = self
        if separator and n:
            first = np.zeros(n, bool)
            if bounds is not None:
                first[np.asarray(bounds[:-1], np.int64)[np.diff(bounds) > 0]] = True
            else:
                first[:] = True
            rows = concat(n, ByteRows.constant(separator, n).blank(~first), self)
        flat = np.ascontiguousarray(rows.matrix)[rows.mask].tobytes()
        offsets = np.zeros(n + 1, np.int64)
        np.cumsum(rows.lengths, out=offsets[1:])
        cuts = offsets if bounds is None else offsets[np.asarray(bounds, np.int64)]
        return [flat[a:b] for a, b in itertools.pairwise(cuts.tolist())]


Column = ByteRows | bytes


def concat(n: int, *columns: Column) -> ByteRows:
    """Row-wise concatenation: row i = columns[0][i] + columns[1][i] + … (``bytes``: the same in every row)."""
    parts = [ByteRows.constant(c, n) if isinstance(c, bytes) else c for c in columns]
    if not parts:
        return ByteRows(np.zeros((n, 0), np.uint8), np.zeros((n, 0), bool))
    return ByteRows(np.hstack([p.matrix for p in parts]), np.hstack([p.mask for p in parts]))


# ------------------------------------------------------------------------------------------ protobuf


def varints(values: np.ndarray) -> ByteRows:
    """Protobuf base-128 varints of int64 values (negative ones as 10-byte two's complement)."""
    v = np.asarray(values, np.int64).astype(np.uint64)
    size = np.ones(len(v), np.int64)
    for i in range(1, 10):
        size += v >= np.uint64(1) << np.uint64(7 * i)
    width = int(size.max()) if len(v) else 1
    groups = (v[:, None] >> (np.arange(width, dtype=np.uint64) * np.uint64(7))) & np.uint64(0x7F)
    matrix = groups.astype(np.uint8)
    matrix[np.arange(width) < (size - 1)[:, None]] |= 0x80
    return ByteRows.from_matrix(matrix, size)


def tag(field: int, wire_type: int) -> bytes:
    """The key of a protobuf field (field number < 2^11: at most 2 bytes)."""
    key = (field << 3) | wire_type
    return bytes([key]) if key < 0x80 else bytes([(key & 0x7F) | 0x80, key >> 7])


def length_delimited(field: int, payload: ByteRows) -> ByteRows:
    """Each row as a length-delimited field (message, string, bytes): key, varint length, payload."""
    return concat(len(payload), tag(field, 2), varints(payload.lengths), payload)


def doubles(field: int, values: np.ndarray) -> ByteRows:
    """Each value as a proto3 ``double`` field, omitted (empty row) where it is +0.0, as serializers do."""
    values = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
    matrix = np.empty((len(values), 9), np.uint8)
    matrix[:, 0] = tag(field, 1)[0]
    matrix[:, 1:] = values.view(np.uint8).reshape(-1, 8)
    present = values.view(np.uint64) != 0
    return ByteRows(matrix, np.broadcast_to(present[:, None], matrix.shape))


def int_field(field: int, values: np.ndarray) -> ByteRows:
    """Each value as a proto3 varint field (int32/int64), omitted where it is 0."""
    values = np.asarray(values, np.int64)
    return concat(len(values), tag(field, 0), varints(values)).blank(values != 0)


def fixed(values: np.ndarray, dtype: str) -> ByteRows:
    """Each row of ``values`` [N, …] as its little-endian bytes in ``dtype`` (e.g. "<f8", "<u4")."""
    values = np.ascontiguousarray(values, dtype=dtype)
    n = values.shape[0]
    matrix = values.view(np.uint8).reshape(n, -1)
    return ByteRows(matrix, np.ones(matrix.shape, bool))


# ---------------------------------------------------------------------------------------------- JSON


def split_text(text: bytes, separator: int = 0x2C) -> ByteRows:
    """The tokens of ``text`` between ``separator`` bytes (default ``,``) as rows."""
    raw = np.frombuffer(text, np.uint8)
    cuts = np.flatnonzero(raw == separator)
    starts = np.concatenate([[0], cuts + 1])
    lengths = np.concatenate([cuts, [len(raw)]]) - starts
    width = int(lengths.max()) if len(lengths) else 0
    index = np.minimum(starts[:, None] + np.arange(width), max(len(raw) - 1, 0))
    matrix = raw[index] if len(raw) else np.zeros((len(starts), width), np.uint8)
    return ByteRows.from_matrix(matrix, lengths)


def json_numbers(values: np.ndarray) -> ByteRows:
    """Each float64 value as JSON text: Python's ``repr`` (shortest round trip, as ``json.dumps``); NaN → null.

    CPython formats the numbers (one ``repr`` each, in C); numpy only cuts the text into rows.
    """
    flat = np.asarray(values, np.float64).reshape(-1)
    if flat.size == 0:
        return ByteRows(np.zeros((0, 0), np.uint8), np.zeros((0, 0), bool))
    rows = split_text(",".join(map(float.__repr__, flat.tolist())).encode())
    nan = np.isnan(flat)
    if nan.any():
        null = ByteRows.constant(b"null", len(flat))
        rows = concat(len(flat), rows.blank(~nan), null.blank(nan))
    return rows


def json_ints(values: np.ndarray) -> ByteRows:
    """Each integer as JSON text."""
    flat = np.asarray(values, np.int64).reshape(-1)
    if flat.size == 0:
        return ByteRows(np.zeros((0, 0), np.uint8), np.zeros((0, 0), bool))
    return split_text(",".join(map(str, flat.tolist())).encode())


def json_lists(items: ByteRows, n: int, width: int, separator: bytes = b",") -> ByteRows:
    """Every ``width`` consecutive items (n × width in all) as one JSON array ``[a,b,…]``."""
    if width == 0:
        return ByteRows.constant(b"[]", n)
    first = (np.arange(n * width) % width) == 0
    with_sep = concat(n * width, ByteRows.constant(separator, n * width).blank(~first), items)
    return concat(n, b"[", with_sep.group_every(width), b"]")


def escape_quotes(rows: ByteRows) -> ByteRows:
    """JSON string content: every ``"`` and backslash preceded by a backslash (printable ASCII rows)."""
    special = rows.mask & ((rows.matrix == 0x22) | (rows.matrix == 0x5C))
    if not special.any():
        return rows
    n, w = rows.matrix.shape
    matrix = np.stack([np.full((n, w), 0x5C, np.uint8), rows.matrix], axis=2).reshape(n, 2 * w)
    mask = np.stack([special, rows.mask], axis=2).reshape(n, 2 * w)
    return ByteRows(matrix, mask)
