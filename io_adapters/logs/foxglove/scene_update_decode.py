"""Protobuf ``foxglove.SceneUpdate`` messages → object columns, straight from the wire format.

The SceneUpdate field map on top of the vectorised wire walk
(:mod:`lanecast.io_adapters.logs.messages.protobuf_wire`): messages → entities → the first cube's pose and
size, the timestamp, id, frame id and the metadata lanecast reads (class, lane, kinematics), all
messages of a batch at once with numpy. Layouts the usual serialisers write take fast paths (cubes
matched at fixed offsets, key/value pairs of short strings, timestamps seconds-then-nanos), checked
element by element; anything else a valid SceneUpdate may hold takes the general scan. Entities are
decoded ~16k at a time so that the bytes and arrays of a group stay in the CPU cache. Text fields go
through :mod:`lanecast.io_adapters.logs.messages.wire_text`; numeric entity ids are read digit by digit.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any

import numpy as np

from lanecast.io_adapters.logs.messages.protobuf_wire import (
    PAD,
    Fields,
    double_messages,
    scan,
    sub_fields,
    varints,
    windows,
)
from lanecast.io_adapters.logs.messages.wire_text import (
    categories,
    check_text,
    parse_floats,
    short_codes,
    strings,
    text,
)
from lanecast.io_adapters.logs.object_columns import (
    MAX_STAMP_SEC,
    NAN,
    Categorical,
    ObjectColumns,
    check_quaternions,
    message_stamps,
    track_id_of,
    yaw_of,
)


def _cube_parts(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, owners: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """The (start, end, owner, k) spans of the position (k=3), orientation (4) and size (3)
    messages of the CubePrimitives buf[starts[i]:ends[i]] [m], for :func:`double_messages`.

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
    cube = scan(buf, starts[slow], ends[slow], owners[slow])
    pose = sub_fields(buf, cube, cube.pick(1, 2))
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


def _track_ids(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Entity id strings [n] → int64 track ids [n], as :func:`track_id_of` gives them."""
    n = starts.size
    lengths = ends - starts
    track = np.zeros(n, dtype=np.int64)
    # Plain decimal integers (an optional minus, at most 18 characters) by Horner's rule over the
    # characters [n, width], the rest one by one.
    width = min(max(int(lengths.max()) if n else 1, 1), 18)
    digit = windows(buf, starts, width) - np.uint8(48)  # '-' wraps to 253
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
        uniq, inv = np.unique(strings(buf, starts[bad], ends[bad]), return_inverse=True)
        ids = [track_id_of(text(u, "an entity id")) for u in uniq.tolist()]
        track[bad] = np.array(ids, dtype=np.int64)[inv]
    return track


def _key_value_spans(buf: np.ndarray, f: Fields) -> tuple[np.ndarray, ...]:
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
        kv = scan(buf, s[slow], e[slow], slow)
        ks[slow] = ke[slow] = vs[slow] = ve[slow] = 0
        for field_no, (a, b) in ((1, (ks, ke)), (2, (vs, ve))):
            sel = kv.pick(field_no, 2)
            a[kv.owner[sel]], b[kv.owner[sel]] = kv.start[sel], kv.end[sel]
    return entity, ks, ke, vs, ve


def _key_slots(buf: np.ndarray, ks: np.ndarray, ke: np.ndarray, keys: list[bytes]) -> np.ndarray:
    """int64 [n]: the index in ``keys`` (each at most 7 bytes) of each key buf[ks[i]:ke[i]], -1 for
    any other key. One packed-code lookup for all keys (see :func:`short_codes`)."""
    known = np.array([int.from_bytes(k, "little") | (len(k) << 56) for k in keys], dtype=np.uint64)
    order = np.argsort(known)
    code = short_codes(buf, ks, ke)
    at = np.minimum(np.searchsorted(known[order], code), len(keys) - 1)
    return np.where(known[order][at] == code, order[at], -1)


def _times(buf: np.ndarray, f: Fields, sel: np.ndarray, n: int) -> np.ndarray:
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
    sec[i], pos[i] = varints(buf, pos[i] + 1)
    has = (pos < end) & (buf[pos] == 0x10)
    i = np.flatnonzero(has)
    nsec[i], pos[i] = varints(buf, pos[i] + 1)
    fast = pos == end
    _check_stamps(sec, nsec)
    value = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64)
    out[owner[fast]] = value[fast]
    if not fast.all():
        g = scan(buf, start[~fast], end[~fast], owner[~fast])
        parts = []
        for field_no in (1, 2):
            m = g.pick(field_no, 0)
            part = np.zeros(n, dtype=np.uint64)
            part[g.owner[m]] = varints(buf, g.start[m])[0]
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
    of an entity), as :meth:`ObjectColumns.add_blocks` takes them. ``buf`` is copied unless it
    holds :data:`PAD` bytes after the last message.
    """
    parts = scene_update_groups(buf, starts, ends, log_times)
    if len(parts) == 1:
        return parts[0]
    block: dict[str, Any] = {
        k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k not in ("classes", "frame_ids")
    }
    block["classes"] = Categorical.concat([p["classes"] for p in parts])
    block["frame_ids"] = Categorical.concat([p["frame_ids"] for p in parts])
    return block


def scene_update_groups(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, log_times: np.ndarray
) -> list[dict[str, Any]]:
    """:func:`scene_update_block` as the blocks of consecutive entity groups (in order, not joined:
    the reader joins all of a topic's blocks once)."""
    if starts.size and int((ends - starts).max()) > MAX_MESSAGE_BYTES:
        raise ValueError(
            f"a SceneUpdate message of {int((ends - starts).max()):,} bytes "
            f"(more than the {MAX_MESSAGE_BYTES:,} this reader accepts)"
        )
    if starts.size and int(ends.max()) + PAD > buf.size:
        buf = np.concatenate([buf, np.zeros(PAD, dtype=np.uint8)])
    msgs = scan(buf, starts, ends, np.arange(starts.size))
    ent = msgs.pick(2, 2)
    if ent.size <= ENTITY_GROUP:
        return [_entity_columns(buf, msgs.start[ent], msgs.end[ent], log_times, msgs.owner[ent])]
    # The entities of consecutive messages, a group at a time: the group's bytes and arrays stay in
    # the CPU cache.
    owner = msgs.owner[ent]
    total = np.cumsum(np.bincount(owner, minlength=starts.size))
    cuts = [0, *np.searchsorted(total, np.arange(ENTITY_GROUP, ent.size, ENTITY_GROUP)).tolist(), starts.size]
    groups = [ent[(owner >= a) & (owner < b)] for a, b in itertools.pairwise(cuts) if b > a]
    return [_entity_columns(buf, msgs.start[g], msgs.end[g], log_times, msgs.owner[g]) for g in groups]


def _entity_columns(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, log_times: np.ndarray, message: np.ndarray
) -> dict[str, Any]:
    """The columns of :func:`scene_update_block` for the SceneEntity messages buf[starts[i]:ends[i]]
    [n] of messages ``message`` [n] logged at log_times[message]."""
    n = starts.size
    f = scan(buf, starts, ends, np.arange(n))
    # Timestamp (sec, nsec) of each entity; 0 → the message's log time.
    time_ns = _times(buf, f, f.pick(1, 2), n)
    time_ns = np.where(time_ns == 0, log_times[message], time_ns)
    # The first cube of each entity.
    cube_sel = f.pick(8, 2)
    per_entity = np.bincount(f.owner[cube_sel], minlength=n)
    has_cube = np.flatnonzero(per_entity)
    if has_cube.size < cube_sel.size:  # some entity has several: the first in the scan's order
        _, first = np.unique(f.owner[cube_sel], return_index=True)
        cube_sel = cube_sel[first]
    position, quaternion, size = double_messages(
        buf, _cube_parts(buf, f.start[cube_sel], f.end[cube_sel], f.owner[cube_sel]), n
    )
    check_quaternions(*quaternion)
    vals = {
        "x": position[0],
        "y": position[1],
        "length": size[0],
        "width": size[1],
        "yaw": yaw_of(*quaternion),
    }
    # Metadata: class, lane_id and the kinematics lanecast writes.
    kv_entity, ks, ke, vs, ve = _key_value_spans(buf, f)
    check_text(buf, ks, ke, "a metadata key")  # a damaged 'class' would silently be no class
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
    cls_codes, cls_names = categories(buf, cls_s[has_cube], cls_e[has_cube], "a class name")
    every = has_cube.size == n
    block: dict[str, Any] = {k: v if every else v[has_cube] for k, v in vals.items()}
    block.update(
        time_ns=time_ns[has_cube],
        msg_time=message_stamps(time_ns[has_cube], message[has_cube]),
        track_id=_track_ids(buf, *spans[3]),
        classes=Categorical(cls_codes, [c or "unknown" for c in cls_names]),
        frame_ids=Categorical(*categories(buf, *spans[2], "a frame id")),
    )
    return block


Piece = tuple[int, bytes, Any, Any, Any]  # (file offset of the record, data, starts, ends, log times)


class SceneUpdateBatch:
    """Protobuf SceneUpdate messages of one topic, decoded together (vectorised) per ~8 MB of data.

    Holds the decompressed bytes of the chunks it has spans in until they are decoded, never more
    than ``ahead`` + 1 batches. With a ``pool`` (threads), full batches are decoded on it, up to
    ``ahead`` + 1 at a time, while the reader goes on decompressing: numpy releases the GIL in its
    loops, so two cores decode 1.5× faster than one (BENCHMARKS.md); the decoded blocks reach the
    columns in the log's order.
    (Larger batches cost no less: the decoder works through them in cache-sized entity groups.)
    """

    LIMIT = 8 << 20

    def __init__(self, columns: ObjectColumns, pool: Executor | None = None, ahead: int = 1) -> None:
        self.columns = columns
        self.pool = pool
        self.ahead = ahead
        self.pieces: list[Piece] = []
        self.size = 0
        self.pending: deque[tuple[list[Piece], Future[list[dict[str, Any]]]]] = deque()

    def __call__(self, data: Any, log_time: int) -> None:
        """One message on its own (the walk hands over whole chunks through :meth:`add` instead)."""
        raw = bytes(data)
        self.add(-1, raw, ([0], [len(raw)], [log_time]))

    def add(self, offset: int, data: bytes, spans: tuple[Any, Any, Any]) -> None:
        """Messages data[starts[i]:ends[i]] at log times[i], from the record at file offset ``offset``."""
        self.pieces.append((offset, data, *spans))
        self.size += len(data)
        if self.size >= self.LIMIT:
            self._submit()

    def finish(self) -> None:
        """Decode everything still held; a ValueError raised carries the ``offset`` of the record at
        fault."""
        self._submit()
        while self.pending:
            self._collect()

    def _submit(self) -> None:
        if not self.pieces:
            return
        pieces, self.pieces, self.size = self.pieces, [], 0
        if self.pool is None:
            self._add(pieces, lambda: _decode(pieces))
            return
        self.pending.append((pieces, self.pool.submit(_decode, pieces)))
        while len(self.pending) > self.ahead:
            self._collect()

    def _collect(self) -> None:
        pieces, future = self.pending.popleft()
        self._add(pieces, future.result)

    def _add(self, pieces: list[Piece], decoded: Callable[[], list[dict[str, Any]]]) -> None:
        try:
            blocks = decoded()
        except (ValueError, IndexError) as exc:
            self.pending.clear()
            _name_piece(exc, pieces)
            raise
        self.columns.add_blocks(blocks, _messages(pieces))


def _decode(pieces: list[Piece]) -> list[dict[str, Any]]:
    return scene_update_groups(*piece_arrays(pieces))


def _messages(pieces: list[Piece]) -> int:
    return sum(len(p[2]) for p in pieces)


def _name_piece(exc: Exception, pieces: list[Piece]) -> None:
    """Set ``exc.offset`` to the file offset of the first piece that does not decode on its own."""
    for piece in pieces:
        try:
            scene_update_block(*piece_arrays([piece]))
        except (ValueError, IndexError):
            setattr(exc, "offset", piece[0])  # noqa: B010
            return


def piece_arrays(
    pieces: list[Piece],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One buffer and the message spans [m] and log times [m] of several pieces."""
    base = np.cumsum([0] + [len(p[1]) for p in pieces[:-1]])
    buf = np.frombuffer(b"".join([*(p[1] for p in pieces), bytes(PAD)]), dtype=np.uint8)
    starts = np.concatenate([np.asarray(p[2], dtype=np.int64) + b for p, b in zip(pieces, base, strict=True)])
    ends = np.concatenate([np.asarray(p[3], dtype=np.int64) + b for p, b in zip(pieces, base, strict=True)])
    times = np.concatenate([np.asarray(p[4], dtype=np.int64) for p in pieces])
    return buf, starts, ends, times
