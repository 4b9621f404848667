"""Vectorised decoding of protobuf ``foxglove.SceneUpdate`` messages straight from the wire format.

upb gives one Python object per field access (~15 µs per entity), so SceneUpdates are decoded
with numpy, many messages at once: every level of nesting is one pass that walks the fields of
all its messages in parallel (one iteration per field position, not per message). Layouts the
usual serialisers write take fast paths (checked, element by element); anything else a valid
SceneUpdate may hold takes the general one. Entities are decoded ~16k at a time so that the bytes
and arrays of a group stay in the CPU cache; bytes are read with single-byte gathers where
possible (numpy gathers unaligned words several times slower). Decimal metadata values are parsed
in bulk by Arrow's (correctly rounded) string-to-float cast, numeric entity ids digit by digit.

Size: one vectorised protobuf decoder: the generic wire walk and the SceneUpdate field map are
read together and share the batch structures.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.logs.tracked_objects import MAX_STAMP_SEC, NAN, Categorical, track_id_of, yaw_of

# Bytes a fixed-width field's value takes, by wire type (VARINT and LEN are measured).
_FIXED_WIDTH = np.array([0, 8, 0, 0, 0, 4, 0, 0], dtype=np.int64)


@dataclass
class _Fields:
    """Fields of a batch of protobuf messages, one entry per field occurrence (arrays [m])."""

    owner: np.ndarray  # index of the top-level object the message belongs to
    tag: np.ndarray  # field number << 3 | wire type
    start: np.ndarray  # value span (LEN: payload; fixed: the bytes; VARINT: the varint)
    end: np.ndarray

    def pick(self, field_no: int, wire: int) -> np.ndarray:
        """Indices [k] (ascending) of the occurrences of field ``field_no`` with wire type ``wire``."""
        return np.flatnonzero(self.tag == (field_no << 3 | wire))


_SHIFTS = np.arange(0, 70, 7, dtype=np.uint64)


_LOW_MASK = np.array([(1 << (8 * (k + 1))) - 1 for k in range(8)], dtype=np.uint64)
_HIGH_BITS = np.uint64(0x8080808080808080)


def _varints(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Varints at byte offsets pos [n] of buf (uint8 [N]) → (values uint64 [n], next offsets [n]).

    One-byte varints (most tags and lengths) take one gather; up to 8 bytes, one 8-byte read
    whose 7-bit groups are joined with shifts; longer ones a 10-byte window each.
    """
    b = buf[np.minimum(pos, buf.size - 1)]
    value = b.astype(np.uint64)
    nxt = pos + 1
    more = np.flatnonzero(b >= 0x80)
    if not more.size:
        return value, nxt
    at = pos[more]
    word = np.ndarray((buf.size - 7,), dtype="<u8", buffer=buf, strides=(1,))[np.minimum(at, buf.size - 8)]
    stop = ~word & _HIGH_BITS  # the high bit of every byte that ends a varint
    short = stop != 0
    last = np.frexp((stop & (~stop + np.uint64(1))).astype(np.float64))[1] // 8 - 1  # its byte index
    last = np.where(short, last, 0)
    x = word & _LOW_MASK[last]
    joined = x & np.uint64(0x7F)
    for i in range(1, 8):
        joined |= (x >> np.uint64(i)) & np.uint64(0x7F << (7 * i))
    value[more] = joined
    nxt[more] += last
    if not short.all():
        long = more[~short]
        window = _windows(buf, pos[long], 10)
        cont = window >= 0x80
        if cont.all(axis=1).any():
            raise ValueError("malformed protobuf varint")
        stop10 = np.argmin(cont, axis=1)
        used = np.arange(10)[None, :] <= stop10[:, None]
        parts = np.where(used, (window & 0x7F).astype(np.uint64) << _SHIFTS, np.uint64(0))
        value[long] = np.bitwise_or.reduce(parts, axis=1)
        nxt[long] = pos[long] + 1 + stop10
    return value, nxt


_BAD_WIRE = np.array([False, False, False, True, True, False, True, True])


def _fields_at(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fields starting at pos [n]: (tag int64, value start, value end)."""
    tag_u, p = _varints(buf, pos)
    tag = tag_u.astype(np.int64)
    wire = tag & 7
    vstart = p
    vend = p + _FIXED_WIDTH[wire]
    w = np.flatnonzero(wire == 2)
    if w.size:
        length, q = _varints(buf, p[w])
        vstart = p.copy()
        vstart[w] = q
        vend[w] = q + length.astype(np.int64)
    w = np.flatnonzero(wire == 0)
    if w.size:
        vend[w] = _varints(buf, p[w])[1]
    return tag, vstart, vend


PAD = 1024  # zero bytes the decoder wants after the last message (fixed-width reads need no clamping)


def _len_fields(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Fast path of :func:`_scan`: (tag, value start, value end) [n] of the fields at pos [n] when all
    are length-delimited with a one-byte tag and a length of one or two bytes; else None.

    Byte gathers only (numpy gathers single bytes several times faster than unaligned words).
    """
    tag = buf[pos]
    if ((tag & 0x87) != 2).any():
        return None
    l0 = buf[pos + 1]
    two = l0 >= 0x80
    if two.any():
        l1 = buf[pos + 2]
        if (two & (l1 >= 0x80)).any():
            return None
        length = np.where(two, (l0 & 0x7F).astype(np.int64) | (l1.astype(np.int64) << 7), l0)
        vstart = pos + 2 + two
    else:
        length = l0
        vstart = pos + 2
    return tag.astype(np.int64), vstart, vstart + length


def _scan(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, owners: np.ndarray) -> _Fields:
    """All fields of the messages buf[starts[i]:ends[i]] [n], tagged with owners[i].

    ``buf`` holds at least :data:`PAD` bytes after the last message. Raises ValueError on field
    number 0, a wire type protobuf does not define (or a group), or a field past its message. One
    vectorised pass per field position while many messages are walked together; when only a few
    long ones are left, the rest goes through :func:`_scan_few`, so that the work stays a small
    constant per byte read (a long run of tiny fields is not one numpy pass per field).
    """
    out: list[tuple[np.ndarray, ...]] = []
    keep = starts < ends
    owner, pos, end = owners[keep], starts[keep], ends[keep]
    passes = 0
    while pos.size:
        passes += 1
        if pos.size <= _FEW and passes > _FEW_AFTER:
            out.append(_scan_few(buf, owner, pos, end))
            break
        fast = _len_fields(buf, pos)
        if fast is not None:
            # Every field here is length-delimited, tag and length short: the usual case for
            # messages of sub-messages and strings.
            tag, vstart, vend = fast
        else:
            tag, vstart, vend = _fields_at(buf, pos)
            if _BAD_WIRE[tag & 7].any():
                raise ValueError("malformed protobuf message (bad wire type)")
        if (tag < 8).any():
            raise ValueError("malformed protobuf message (field number 0)")
        if (vend > end).any() or (vend < vstart).any():
            raise ValueError("malformed protobuf message (a field runs past its message)")
        out.append((owner, tag, vstart, vend))
        more = vend < end
        if more.all():
            pos = vend
        else:
            owner, pos, end = owner[more], vend[more], end[more]
    if not out:
        e = np.zeros(0, dtype=np.int64)
        return _Fields(e, e, e, e)
    if len(out) == 1:
        return _Fields(*out[0])
    return _Fields(*(np.concatenate(c) for c in zip(*out, strict=True)))


_FEW = 4  # messages still being walked at or below which the scalar walk takes over …
_FEW_AFTER = 16  # … once this many vectorised passes have been made


def _scan_few(
    buf: np.ndarray, owners: np.ndarray, starts: np.ndarray, ends: np.ndarray
) -> tuple[np.ndarray, ...]:
    """The fields of a few messages buf[starts[i]:ends[i]], walked one field at a time in Python
    (well under a microsecond per field with one-byte tags and lengths, the common case):
    (owner, tag, value start, value end) arrays [m]."""
    data = buf.tobytes()
    owner_col: list[int] = []
    tag_col: list[int] = []
    start_col: list[int] = []
    end_col: list[int] = []
    for owner, pos, end in zip(owners.tolist(), starts.tolist(), ends.tolist(), strict=True):
        first = len(tag_col)
        while pos < end:
            tag = data[pos]
            pos += 1
            if tag >= 0x80:
                tag, pos = _varint_at(data, pos - 1, end)
            wire = tag & 7
            if wire == 2:
                length = data[pos] if pos < end else 0x80
                if length < 0x80:
                    vstart = pos + 1
                else:
                    length, vstart = _varint_at(data, pos, end)
                vend = vstart + length
            elif wire == 0:
                vstart = vend = pos
                while vend < end and data[vend] >= 0x80:
                    vend += 1
                vend += 1
                if vend - vstart > 10:
                    raise ValueError("malformed protobuf varint")
            elif wire == 1 or wire == 5:
                vstart, vend = pos, pos + (8 if wire == 1 else 4)
            else:
                raise ValueError("malformed protobuf message (bad wire type)")
            if tag < 8:
                raise ValueError("malformed protobuf message (field number 0)")
            if vend > end:
                raise ValueError("malformed protobuf message (a field runs past its message)")
            tag_col.append(tag)
            start_col.append(vstart)
            end_col.append(vend)
            pos = vend
        owner_col.extend([owner] * (len(tag_col) - first))
    return tuple(np.asarray(c, dtype=np.int64) for c in (owner_col, tag_col, start_col, end_col))


def _varint_at(data: bytes, pos: int, end: int) -> tuple[int, int]:
    """The varint at data[pos] (at most 10 bytes, before ``end``) and the offset after it."""
    value = shift = 0
    for i in range(pos, min(pos + 10, end)):
        byte = data[i]
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, i + 1
        shift += 7
    raise ValueError("malformed protobuf varint")


def _sub(buf: np.ndarray, f: _Fields, sel: np.ndarray) -> _Fields:
    """The fields of the sub-messages at indices ``sel`` of f (owners carried over)."""
    return _scan(buf, f.start[sel], f.end[sel], f.owner[sel])


def _f64(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """float64 [n] stored little-endian at byte offsets pos [n] of buf."""
    if buf.size < 8:
        raise ValueError("buffer too short for a double")
    # An overlapping view: element i is the 8 bytes from buf[i] (copied, then seen as float64).
    every_byte = np.ndarray((buf.size - 7,), dtype="V8", buffer=buf, strides=(1,))
    return every_byte[pos].view("<f8")


def _double_messages(
    buf: np.ndarray, kinds: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]], n: int
) -> list[np.ndarray]:
    """float64 [k, n] per kind (start, end, owner, k): double fields 1..k of the messages
    buf[start[i]:end[i]] (Vector3, Point, Quaternion), column = owner[i]; 0 where absent. All kinds
    in one pass.

    Such a message is a run of 9-byte fields (tag, 8 bytes), any of them omitted when zero: read
    slot by slot at a fixed stride; other layouts go through the general scan.
    """
    ks = [k for *_, k in kinds]
    width = max(ks)
    out = np.zeros((sum(ks), n))
    flat = out.reshape(-1)
    start = np.concatenate([s for s, *_ in kinds])
    end = np.concatenate([e for _, e, *_ in kinds])
    owner = np.concatenate([o for _, _, o, _ in kinds])
    sizes = [s.size for s, *_ in kinds]
    k_row = np.repeat(ks, sizes)
    # Flat index of each message's field 1 in out (its kind's first row, its owner's column).
    cell = np.repeat(np.cumsum([0, *ks[:-1]]) * n, sizes) + owner
    length = end - start
    slots = length // 9
    ok = (length % 9 == 0) & (slots <= k_row)
    rows = np.flatnonzero(ok)
    for slot in range(width):
        if slot:
            rows = rows[slots[rows] > slot]
        if not rows.size:
            break
        at = start[rows] + 9 * slot
        tag = buf[at]
        field_no = (tag >> 3).astype(np.int64)
        good = ((tag & 7) == 1) & (field_no >= 1) & (field_no <= k_row[rows])
        if not good.all():
            ok[rows[~good]] = False
            rows, at, field_no = rows[good], at[good], field_no[good]
        flat[cell[rows] + (field_no - 1) * n] = _f64(buf, at + 1)
    if not ok.all():
        slow = np.flatnonzero(~ok)
        g = _scan(buf, start[slow], end[slow], slow)
        field_no, wire = g.tag >> 3, g.tag & 7
        m = (wire == 1) & (field_no >= 1) & (field_no <= k_row[g.owner])
        flat[cell[g.owner[m]] + (field_no[m] - 1) * n] = _f64(buf, g.start[m])
    return np.split(out, np.cumsum(ks)[:-1])


def _cube_parts(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, owners: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """The (start, end, owner, k) spans of the position (k=3), orientation (4) and size (3)
    messages of the CubePrimitives buf[starts[i]:ends[i]] [m], for :func:`_double_messages`.

    The layout serialisers write, ``pose {position, orientation} size [color]`` with one-byte
    lengths, is matched byte by byte at fixed offsets, all cubes at once (the whole cube is walked
    and checked, as the general scan would); any other cube goes through the general scan.
    """
    s = starts
    pose_len = buf[s + 1].astype(np.int64)
    pos_len = buf[s + 3].astype(np.int64)
    q = s + 4 + pos_len  # orientation tag
    q_len = buf[q + 1].astype(np.int64)
    z = s + 2 + pose_len  # size tag
    z_len = buf[z + 1].astype(np.int64)
    c = z + 2 + z_len  # color tag, or the cube's end
    c_len = buf[c + 1].astype(np.int64)
    fast = (
        (buf[s] == 0x0A)
        & (pose_len < 0x80)
        & (buf[s + 2] == 0x0A)
        & (pos_len < 0x80)
        & (buf[q] == 0x12)
        & (q_len < 0x80)
        & (q + 2 + q_len == z)
        & (buf[z] == 0x12)
        & (z_len < 0x80)
        & ((c == ends) | ((buf[c] == 0x1A) & (c_len < 0x80) & (c + 2 + c_len == ends)))
    )
    if fast.all():
        return [(s + 4, q, owners, 3), (q + 2, z, owners, 4), (z + 2, c, owners, 3)]
    slow = ~fast
    cube = _scan(buf, starts[slow], ends[slow], owners[slow])
    pose = _sub(buf, cube, cube.pick(1, 2))
    general = [(pose, pose.pick(1, 2)), (pose, pose.pick(2, 2)), (cube, cube.pick(2, 2))]
    fixed = [(s + 4, q), (q + 2, z), (z + 2, c)]
    return [
        (
            np.concatenate([a[fast], g.start[sel]]),
            np.concatenate([b[fast], g.end[sel]]),
            np.concatenate([owners[fast], g.owner[sel]]),
            k,
        )
        for (a, b), (g, sel), k in zip(fixed, general, (3, 4, 3), strict=True)
    ]


def _windows(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """uint8 [n, width]: the ``width`` bytes from each offset starts[i] (past the end: zeros)."""
    if starts.size and int(starts.max()) + width <= buf.size:
        every_byte = np.ndarray((buf.size - width + 1,), dtype=f"V{width}", buffer=buf, strides=(1,))
        return every_byte[starts].view(np.uint8).reshape(-1, width)
    idx = starts[:, None] + np.arange(width)
    return np.where(idx < buf.size, buf[np.minimum(idx, buf.size - 1)], 0).astype(np.uint8)


_MAX_STRING = 256  # bytes kept of a string (class names, frame ids, ids): bounds the [n, width] work


def _strings(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Byte strings buf[starts[i]:ends[i]] (at most _MAX_STRING bytes) as a fixed-width bytes array [n]."""
    lengths = np.minimum(ends - starts, _MAX_STRING)
    width = max(int(lengths.max()) if lengths.size else 1, 1)
    raw = _windows(buf, starts, width)
    raw = np.where(np.arange(width)[None, :] < lengths[:, None], raw, 0).astype(np.uint8)
    return raw.view(f"S{width}").ravel()


_MAX_NUMBER = 64  # longer decimal strings are parsed one by one (bounds the [n, width] work)


def _binary_of_spans(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> pa.Array:
    """Arrow binary [2n]: element 2i is buf[starts[i]:ends[i]] (at most _MAX_NUMBER bytes), odd
    elements are null (the padding between the values, so one gather of fixed windows suffices)."""
    n = starts.size
    lengths = np.minimum(ends - starts, _MAX_NUMBER)
    width = max(int(lengths.max()) if n else 0, 1)
    raw = np.ascontiguousarray(_windows(buf, starts, width))
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
    import pyarrow.compute as pc

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


def _track_ids(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Entity id strings [n] → int64 track ids [n], as :func:`track_id_of` gives them."""
    n = starts.size
    lengths = ends - starts
    track = np.zeros(n, dtype=np.int64)
    # Plain decimal integers (an optional minus, at most 18 characters) by Horner's rule over the
    # characters [n, width], the rest one by one.
    width = min(max(int(lengths.max()) if n else 1, 1), 18)
    digit = _windows(buf, starts, width) - np.uint8(48)  # '-' wraps to 253
    neg = digit[:, 0] == 253
    inside = np.arange(width)[None, :] < lengths[:, None]
    ok = (digit < 10) | ~inside
    ok[:, 0] |= neg
    plain = ok.all(axis=1) & (lengths >= 1 + neg) & (lengths <= 18)
    for j in range(width):
        d = digit[:, j].astype(np.int64)
        if j == 0:
            d[neg] = 0
        track = np.where(inside[:, j], track * 10 + d, track)
    track = np.where(plain, np.where(neg, -track, track), 0)
    if not plain.all():
        bad = np.flatnonzero(~plain)
        uniq, inv = np.unique(_strings(buf, starts[bad], ends[bad]), return_inverse=True)
        track[bad] = np.array(
            [track_id_of(u.decode(errors="replace")) for u in uniq.tolist()], dtype=np.int64
        )[inv]
    return track


def _key_value_spans(buf: np.ndarray, f: _Fields) -> tuple[np.ndarray, ...]:
    """KeyValuePair sub-messages (entity field 6) → (entity, key start, key end, value start, value end).

    Fast path for the usual layout (key then value, both shorter than 128 bytes), the general scan
    for the rest.
    """
    m = f.pick(6, 2)
    entity, s, e = f.owner[m], f.start[m], f.end[m]
    # Reads stay inside the PAD after the messages.
    klen = buf[s + 1].astype(np.int64)
    vpos = s + 2 + klen
    vlen = buf[vpos + 1].astype(np.int64)
    fast = (buf[s] == 0x0A) & (klen < 0x80) & (buf[vpos] == 0x12) & (vlen < 0x80) & (vpos + 2 + vlen == e)
    ks, ke, vs, ve = s + 2, s + 2 + klen, vpos + 2, vpos + 2 + vlen
    if not fast.all():
        slow = np.flatnonzero(~fast)
        kv = _scan(buf, s[slow], e[slow], slow)
        ks[slow] = ke[slow] = vs[slow] = ve[slow] = 0
        for field_no, (a, b) in ((1, (ks, ke)), (2, (vs, ve))):
            sel = kv.pick(field_no, 2)
            a[kv.owner[sel]], b[kv.owner[sel]] = kv.start[sel], kv.end[sel]
    return entity, ks, ke, vs, ve


_LOW_BYTES = np.array([(1 << (8 * k)) - 1 for k in range(8)], dtype=np.uint64)


def _short_codes(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """uint64 [n]: strings buf[starts[i]:ends[i]] of at most 7 bytes packed with their length
    (bytes little-endian, length in the top byte): equal codes ⇔ equal strings. Longer ones: 0."""
    length = ends - starts
    short = (length >= 0) & (length <= 7)
    word = np.ascontiguousarray(_windows(buf, starts, 8)).view("<u8").ravel()
    code = (word & _LOW_BYTES[np.where(short, length, 0)]) | (length.astype(np.uint64) << np.uint64(56))
    return np.where(short, code, np.uint64(0))


def _key_slots(buf: np.ndarray, ks: np.ndarray, ke: np.ndarray, keys: list[bytes]) -> np.ndarray:
    """int64 [n]: the index in ``keys`` (each at most 7 bytes) of each key buf[ks[i]:ke[i]], -1 for
    any other key. One packed-code lookup for all keys (see :func:`_short_codes`)."""
    known = np.array([int.from_bytes(k, "little") | (len(k) << 56) for k in keys], dtype=np.uint64)
    order = np.argsort(known)
    code = _short_codes(buf, ks, ke)
    at = np.minimum(np.searchsorted(known[order], code), len(keys) - 1)
    return np.where(known[order][at] == code, order[at], -1)


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


def _categories(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Strings buf[starts[i]:ends[i]] [n] → (int32 codes [n], category strings)."""
    if not starts.size:
        return np.zeros(0, np.int32), []
    if int((ends - starts).max()) <= 7:  # class names, frame ids: one integer each
        codes, cats = _factorize(_short_codes(buf, starts, ends))
        names = [(c & ((1 << 56) - 1)).to_bytes(c >> 56, "little") for c in cats.tolist()]
    else:
        uniq, inverse = np.unique(_strings(buf, starts, ends), return_inverse=True)
        codes, names = inverse.astype(np.int32).ravel(), uniq.tolist()
    return codes, [c.decode(errors="replace") for c in names]


def _times(buf: np.ndarray, f: _Fields, sel: np.ndarray, n: int) -> np.ndarray:
    """int64 [n] ns of the Timestamp sub-messages (seconds = 1, nanos = 2) at indices sel of f; 0 if absent.

    Fast path for the usual layout (seconds then nanos, either omitted when zero).
    """
    start, end, owner = f.start[sel], f.end[sel], f.owner[sel]
    out = np.zeros(n, dtype=np.int64)
    sec = np.zeros(start.size, dtype=np.uint64)
    nsec = np.zeros(start.size, dtype=np.uint64)
    pos = start.copy()
    has = (pos < end) & (buf[pos] == 0x08)
    i = np.flatnonzero(has)
    sec[i], pos[i] = _varints(buf, pos[i] + 1)
    has = (pos < end) & (buf[pos] == 0x10)
    i = np.flatnonzero(has)
    nsec[i], pos[i] = _varints(buf, pos[i] + 1)
    fast = pos == end
    _check_stamps(sec, nsec)
    value = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64)
    out[owner[fast]] = value[fast]
    if not fast.all():
        g = _scan(buf, start[~fast], end[~fast], owner[~fast])
        parts = []
        for field_no in (1, 2):
            m = g.pick(field_no, 0)
            part = np.zeros(n, dtype=np.uint64)
            part[g.owner[m]] = _varints(buf, g.start[m])[0]
            parts.append(part)
        _check_stamps(*parts)
        slow = np.zeros(n, dtype=bool)
        slow[owner[~fast]] = True
        out[slow] = (parts[0].astype(np.int64) * 1_000_000_000 + parts[1].astype(np.int64))[slow]
    return out


def _check_stamps(sec: np.ndarray, nsec: np.ndarray) -> None:
    """Timestamps (uint64 [n] seconds and nanoseconds) that fit int64 nanoseconds, else ValueError."""
    if (sec > np.uint64(MAX_STAMP_SEC)).any() or (nsec > np.uint64(999_999_999)).any():
        raise ValueError(f"timestamp out of range (sec up to {MAX_STAMP_SEC}, nsec up to 999999999 expected)")


#: Largest SceneUpdate message decoded (some 50,000 cube entities): bounds the memory and time a
#: crafted message can claim (the decoder keeps a few integers per field, and a message of millions
#: of tiny fields is walked a field at a time).
MAX_MESSAGE_BYTES = 8 << 20
ENTITY_GROUP = 16384  # entities decoded together (a group's bytes and arrays stay in the CPU cache)

# Entity metadata parsed as numbers: column name → key.
_NUMERIC_KEYS = {"vx": b"vx", "vy": b"vy", "ax": b"ax", "ay": b"ay", "lane": b"lane_id"}


def scene_update_block(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, log_times: np.ndarray
) -> dict[str, Any]:
    """Decode protobuf ``foxglove.SceneUpdate`` messages buf[starts[i]:ends[i]] (i < m) at once.

    Returns the columns of their entities that have a cube (arrays [n], NaN = absent, first cube
    of an entity), as :meth:`ObjectColumns.add_block` takes them. ``buf`` is copied unless it
    holds :data:`PAD` bytes after the last message.
    """
    if starts.size and int((ends - starts).max()) > MAX_MESSAGE_BYTES:
        raise ValueError(
            f"a SceneUpdate message of {int((ends - starts).max()):,} bytes "
            f"(more than the {MAX_MESSAGE_BYTES:,} this reader accepts)"
        )
    if starts.size and int(ends.max()) + PAD > buf.size:
        buf = np.concatenate([buf, np.zeros(PAD, dtype=np.uint8)])
    msgs = _scan(buf, starts, ends, np.arange(starts.size))
    ent = msgs.pick(2, 2)
    if ent.size <= ENTITY_GROUP:
        return _entity_columns(buf, msgs.start[ent], msgs.end[ent], log_times[msgs.owner[ent]])
    # The entities of consecutive messages, a group at a time: the group's bytes and arrays stay in
    # the CPU cache.
    owner = msgs.owner[ent]
    total = np.cumsum(np.bincount(owner, minlength=starts.size))
    cuts = [0, *np.searchsorted(total, np.arange(ENTITY_GROUP, ent.size, ENTITY_GROUP)).tolist(), starts.size]
    groups = [ent[(owner >= a) & (owner < b)] for a, b in itertools.pairwise(cuts) if b > a]
    parts = [_entity_columns(buf, msgs.start[g], msgs.end[g], log_times[msgs.owner[g]]) for g in groups]
    block: dict[str, Any] = {
        k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k not in ("classes", "frame_ids")
    }
    block["classes"] = Categorical.concat([p["classes"] for p in parts])
    block["frame_ids"] = Categorical.concat([p["frame_ids"] for p in parts])
    return block


def _entity_columns(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, msg_time: np.ndarray
) -> dict[str, Any]:
    """The columns of :func:`scene_update_block` for the SceneEntity messages buf[starts[i]:ends[i]]
    [n] of messages logged at msg_time [n]."""
    n = starts.size
    f = _scan(buf, starts, ends, np.arange(n))
    # Timestamp (sec, nsec) of each entity; 0 → the message's log time.
    time_ns = _times(buf, f, f.pick(1, 2), n)
    time_ns = np.where(time_ns == 0, msg_time, time_ns)
    # The first cube of each entity.
    cube_sel = f.pick(8, 2)
    per_entity = np.bincount(f.owner[cube_sel], minlength=n)
    has_cube = np.flatnonzero(per_entity)
    if has_cube.size < cube_sel.size:  # some entity has several: the first in the scan's order
        _, first = np.unique(f.owner[cube_sel], return_index=True)
        cube_sel = cube_sel[first]
    position, quaternion, size = _double_messages(
        buf, _cube_parts(buf, f.start[cube_sel], f.end[cube_sel], f.owner[cube_sel]), n
    )
    vals = {
        "x": position[0],
        "y": position[1],
        "length": size[0],
        "width": size[1],
        "yaw": yaw_of(*quaternion),
    }
    # Metadata: class, lane_id and the kinematics lanecast writes.
    kv_entity, ks, ke, vs, ve = _key_value_spans(buf, f)
    slot = _key_slots(buf, ks, ke, [*_NUMERIC_KEYS.values(), b"class"])
    numeric = np.full((len(_NUMERIC_KEYS), n), NAN)
    sel = np.flatnonzero((slot >= 0) & (slot < len(_NUMERIC_KEYS)))
    numeric[slot[sel], kv_entity[sel]] = parse_floats(buf, vs[sel], ve[sel])
    vals.update(zip(_NUMERIC_KEYS, numeric, strict=True))
    cls_s, cls_e = np.zeros(n, np.int64), np.zeros(n, np.int64)
    m = np.flatnonzero(slot == len(_NUMERIC_KEYS))
    cls_s[kv_entity[m]], cls_e[kv_entity[m]] = vs[m], ve[m]
    # Ids and frame ids (absent = empty string).
    spans = {}
    for field_no in (2, 3):
        st, en = np.zeros(n, np.int64), np.zeros(n, np.int64)
        m = f.pick(field_no, 2)
        st[f.owner[m]], en[f.owner[m]] = f.start[m], f.end[m]
        spans[field_no] = (st[has_cube], en[has_cube])
    cls_codes, cls_names = _categories(buf, cls_s[has_cube], cls_e[has_cube])
    every = has_cube.size == n
    block: dict[str, Any] = {k: v if every else v[has_cube] for k, v in vals.items()}
    block.update(
        time_ns=time_ns[has_cube],
        msg_time=msg_time[has_cube],
        track_id=_track_ids(buf, *spans[3]),
        classes=Categorical(cls_codes, [c or "unknown" for c in cls_names]),
        frame_ids=Categorical(*_categories(buf, *spans[2])),
    )
    return block
