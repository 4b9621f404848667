"""Vectorised walk of protobuf wire-format messages: many messages decoded at once with numpy.

upb gives one Python object per field access (~15 µs per entity), so lanecast walks the wire
format itself: every level of nesting is one :func:`scan` that walks the fields of all its messages
in parallel (one iteration per field position, not per message) and returns flat arrays of
(owner, tag, value span); when only a few long messages are left, a scalar walk finishes them so
that the work stays a small constant per byte. Layouts the usual serialisers write take fast paths
(checked, element by element). Every malformed field raises ValueError; the buffer must hold
:data:`PAD` zero bytes after the last message so that fixed-width reads need no clamping. The
SceneUpdate field map on top of it is :mod:`lanecast.io_adapters.logs.foxglove.scene_update_decode`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Bytes a fixed-width field's value takes, by wire type (VARINT and LEN are measured).
_FIXED_WIDTH = np.array([0, 8, 0, 0, 0, 4, 0, 0], dtype=np.int64)


@dataclass
class Fields:
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
_SEVEN_BITS = np.uint64(0x7F7F7F7F7F7F7F7F)
# (low group mask, lane width): each stage moves every odd group down next to the even one below it.
_JOIN_STAGES = (
    (np.uint64(0x007F007F007F007F), np.uint64(8)),
    (np.uint64(0x00003FFF00003FFF), np.uint64(16)),
    (np.uint64(0x000000000FFFFFFF), np.uint64(32)),
)
_GAP = {np.uint64(8): np.uint64(7), np.uint64(16): np.uint64(14), np.uint64(32): np.uint64(28)}


def varints(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    x = word & _LOW_MASK[last] & _SEVEN_BITS
    # Join the 7-bit groups pairwise (SWAR): 14 bits per 16-bit lane, 28 per 32-bit lane, then 56.
    for keep, shift in _JOIN_STAGES:
        x = (x & keep) | ((x & (keep << shift)) >> (shift - _GAP[shift]))
    value[more] = x
    nxt[more] += last
    if not short.all():
        long = more[~short]
        window = windows(buf, pos[long], 10)
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
    tag_u, p = varints(buf, pos)
    tag = tag_u.astype(np.int64)
    wire = tag & 7
    vstart = p
    vend = p + _FIXED_WIDTH[wire]
    w = np.flatnonzero(wire == 2)
    if w.size:
        length, q = varints(buf, p[w])
        vstart = p.copy()
        vstart[w] = q
        vend[w] = q + length.astype(np.int64)
    w = np.flatnonzero(wire == 0)
    if w.size:
        vend[w] = varints(buf, p[w])[1]
    return tag, vstart, vend


PAD = 1024  # zero bytes the decoder wants after the last message (fixed-width reads need no clamping)


def _len_fields(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Fast path of :func:`scan`: (tag, value start, value end) [n] of the fields at pos [n] when all
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


def scan(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, owners: np.ndarray) -> Fields:
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
        left = end - vend
        if (left < 0).any() or (fast is None and (vend < vstart).any()):
            raise ValueError("malformed protobuf message (a field runs past its message)")
        out.append((owner, tag, vstart, vend))
        more = left > 0
        if more.all():
            pos = vend
        else:
            owner, pos, end = owner[more], vend[more], end[more]
    if not out:
        e = np.zeros(0, dtype=np.int64)
        return Fields(e, e, e, e)
    if len(out) == 1:
        return Fields(*out[0])
    return Fields(*(np.concatenate(c) for c in zip(*out, strict=True)))


_FEW = 4  # messages still being walked at or below which the scalar walk takes over …


_FEW_AFTER = 16  # … once this many vectorised passes have been made


def _scan_few(
    buf: np.ndarray, owners: np.ndarray, starts: np.ndarray, ends: np.ndarray
) -> tuple[np.ndarray, ...]:
    """The fields of a few messages buf[starts[i]:ends[i]], walked one field at a time in Python
    (well under a microsecond per field with one-byte tags and lengths, the common case):
    (owner, tag, value start, value end) arrays [m]."""
    base = int(starts.min())  # only the bytes of these messages are copied out (not the batch's)
    data = buf[base : int(ends.max())].tobytes()
    starts, ends = starts - base, ends - base
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
    owner, tag, start, end = (np.asarray(c, dtype=np.int64) for c in (owner_col, tag_col, start_col, end_col))
    return owner, tag, start + base, end + base


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


def sub_fields(buf: np.ndarray, f: Fields, sel: np.ndarray) -> Fields:
    """The fields of the sub-messages at indices ``sel`` of f (owners carried over)."""
    return scan(buf, f.start[sel], f.end[sel], f.owner[sel])


def f64_at(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """float64 [n] stored little-endian at byte offsets pos [n] of buf."""
    if buf.size < 8:
        raise ValueError("buffer too short for a double")
    # An overlapping view: element i is the 8 bytes from buf[i] (copied, then seen as float64).
    every_byte = np.ndarray((buf.size - 7,), dtype="V8", buffer=buf, strides=(1,))
    return every_byte[pos].view("<f8")


def double_messages(
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
        flat[cell[rows] + (field_no - 1) * n] = f64_at(buf, at + 1)
    if not ok.all():
        slow = np.flatnonzero(~ok)
        g = scan(buf, start[slow], end[slow], slow)
        field_no, wire = g.tag >> 3, g.tag & 7
        m = (wire == 1) & (field_no >= 1) & (field_no <= k_row[g.owner])
        flat[cell[g.owner[m]] + (field_no[m] - 1) * n] = f64_at(buf, g.start[m])
    return np.split(out, np.cumsum(ks)[:-1])


def windows(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """uint8 [n, width]: the ``width`` bytes from each offset starts[i] (past the end: zeros)."""
    if starts.size and int(starts.max()) + width <= buf.size:
        every_byte = np.ndarray((buf.size - width + 1,), dtype=f"V{width}", buffer=buf, strides=(1,))
        return every_byte[starts].view(np.uint8).reshape(-1, width)
    idx = starts[:, None] + np.arange(width)
    return np.where(idx < buf.size, buf[np.minimum(idx, buf.size - 1)], 0).astype(np.uint8)
