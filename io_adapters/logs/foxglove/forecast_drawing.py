"""The drawing of forecasts, the same in every encoding: lines, colours and entity metadata.

One entity per target (id = track id), a LINE_STRIP from the target's position at t0 through the 5
predicted points, coloured by the maneuver it predicts — the first lane change in the predicted
sequence, else straight: straight grey, left blue, right orange, unknown (baselines) purple, the
colours of the reports (``MANEUVER_COLOURS`` of the windows contract) — and the top-K alternatives
as fainter lines (alpha 0.35). Entity metadata holds the maneuver and the probabilities as JSON
text, built column-wise as :class:`~lanecast.io_adapters.logs.messages.byte_rows.ByteRows`.
:func:`drawing_of` computes it once per batch for the protobuf, JSON and CDR encoders.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS, MANEUVERS, UNKNOWN_COLOUR
from lanecast.io_adapters.logs.forecast_batch import N_STEPS, WHAT_IF_SLOTS, ForecastBatch
from lanecast.io_adapters.logs.messages import byte_rows as br
from lanecast.io_adapters.logs.messages.byte_rows import ByteRows

LABELS: tuple[str, ...] = (*MANEUVERS, "unknown")  # maneuver names by index; index -1: unknown


#: RGB per maneuver index (the windows contract's colours, as in the reports); index -1: unknown.
COLOURS: np.ndarray = np.array([*MANEUVER_COLOURS, UNKNOWN_COLOUR])


MAIN_ALPHA = 1.0


ALT_ALPHA = 0.35


LINE_THICKNESS_M = 0.3


def dominant_maneuver(maneuver: np.ndarray) -> np.ndarray:
    """The first non-straight maneuver of each predicted sequence, else 0 (straight). [..., 5] -> [...]."""
    lane_change = maneuver != 0
    first = np.argmax(lane_change, axis=-1)
    picked = np.take_along_axis(maneuver, first[..., None], axis=-1)[..., 0]
    return np.where(lane_change.any(axis=-1), picked, 0)


@dataclass(frozen=True)
class Drawing:
    """The drawing of a batch, independent of the encoding: N entities of L = 1 + K lines of 6 points.

    Line 0 is the main forecast, lines 1… the alternatives; point 0 of a line is the target's
    position at t0, dropped (``keep`` False) where it is unknown so that the line starts at the
    first predicted point. ``metadata``: (key, text per entity), in the entity's order.
    """

    row_frame: np.ndarray  # int64 [N]: frame of each entity
    ids: ByteRows  # [N] track ids as text
    xy: np.ndarray  # float64 [N, L, 6, 2]
    keep: np.ndarray  # bool [N, L, 6]
    rgba: np.ndarray  # float64 [N, L, 4]
    metadata: list[tuple[str, ByteRows]]


def drawing_of(batch: ForecastBatch) -> Drawing:
    n, k = batch.track_id.size, batch.alt_prob.shape[1]
    row_frame = np.repeat(np.arange(batch.n_frames), np.diff(batch.bounds))
    has_origin = ~np.isnan(batch.origin).any(axis=1)
    origin = np.where(has_origin[:, None], batch.origin, 0.0)
    lines = np.concatenate([batch.points[:, None], batch.alt_points], axis=1)  # [N, L, 5, 2]
    start = np.broadcast_to(origin[:, None, None, :], (n, k + 1, 1, 2))
    xy = np.concatenate([start, lines], axis=2)
    keep = np.ones((n, k + 1, N_STEPS + 1), bool)
    keep[:, :, 0] = has_origin[:, None]
    main = dominant_maneuver(batch.maneuver)  # [N]
    alt = dominant_maneuver(batch.alt_maneuver)  # [N, K]
    rgba = np.concatenate(
        [
            np.concatenate([COLOURS[main], np.full((n, 1), MAIN_ALPHA)], axis=-1)[:, None],
            np.concatenate([COLOURS[alt], np.full((n, k, 1), ALT_ALPHA)], axis=-1),
        ],
        axis=1,
    )
    # An alternative on the main line's path (the top sequence is the main forecast's) would draw it
    # twice, the fainter over the bolder: it is kept in the data but drawn transparent.
    same = np.all(np.abs(batch.alt_points - batch.points[:, None]) < 1e-3, axis=(2, 3))  # [N, K]
    rgba[:, 1:, 3] = np.where(same, 0.0, rgba[:, 1:, 3])
    ids = br.json_ints(batch.track_id)
    if batch.removed is not None:  # one entity per what-if: "<track id> without <slot>"
        suffix = np.array([f" without {slot}".encode() for slot in WHAT_IF_SLOTS], dtype="S")
        ids = ByteRows.from_strings(np.char.add(batch.track_id.astype("S"), suffix[batch.removed]))
    labels = ByteRows.from_strings(np.array(LABELS, dtype="S"))
    horizon = json.dumps(batch.horizon_s.tolist()).encode()
    metadata = [
        ("track_id", ids),
        ("maneuver", labels.take(main % len(LABELS))),
        ("maneuver_sequence", _sequence_texts(batch.maneuver)),
        ("maneuver_probs", _probability_texts(np.round(batch.probs, 4), batch.bounds, row_frame)),
        ("horizon_s", ByteRows.constant(horizon, n)),
        ("top_k_probs", _probability_texts(np.round(batch.alt_prob, 4), batch.bounds, row_frame)),
    ]
    if batch.removed is not None:
        slots = ByteRows.from_strings(np.array([s.encode() for s in WHAT_IF_SLOTS], dtype="S"))
        metadata += [
            ("target_track_id", br.json_ints(batch.track_id)),
            ("removed", slots.take(batch.removed)),
        ]
    return Drawing(row_frame, ids, xy, keep, rgba, metadata)


@functools.lru_cache(maxsize=1024)
def _sequence_json(code: int) -> bytes:
    """JSON of the maneuver names of a sequence coded base 4 (digit i = step i's maneuver, 3 = unknown)."""
    return json.dumps([LABELS[(code >> (2 * i)) & 3] for i in range(N_STEPS)]).encode()


def _sequence_texts(maneuver: np.ndarray) -> ByteRows:
    """``["straight", "left", …]`` per row of maneuver [N, 5] (-1: "unknown")."""
    codes = ((maneuver % len(LABELS)) << (2 * np.arange(N_STEPS))).sum(axis=1)
    unique, inverse = np.unique(codes, return_inverse=True)
    table = np.array([_sequence_json(int(c)) for c in unique.tolist()] or [b""], dtype="S")
    return ByteRows.from_strings(table).take(inverse.reshape(-1))


def _probability_texts(values: np.ndarray, bounds: np.ndarray, row_frame: np.ndarray) -> ByteRows:
    """Python's text of each row of ``values`` [N, ...] as a (nested) list, ``", "`` between items.

    As the metadata always wrote it: in a frame that holds a NaN, NaN is ``null`` and a row of
    NaN only (or no values) is ``null`` itself.
    """
    n = values.shape[0]
    flat = values.reshape(n, -1)
    text = _four_decimals(flat.reshape(-1))
    rows = flat.size
    for width in reversed(values.shape[1:]):
        rows //= max(width, 1)
        text = br.json_lists(text, rows if width else n, width, b", ")
    nan_rows = np.isnan(flat).all(axis=1)  # True for rows without values too
    if n and (frame_nan := np.add.reduceat(~np.isfinite(flat).all(axis=1), bounds[:-1]) > 0).any():
        null = nan_rows & frame_nan[row_frame]
        text = br.concat(n, text.blank(~null), ByteRows.constant(b"null", n).blank(null))
    return text


@functools.cache
def _four_decimal_table() -> ByteRows:
    """Python's text of k / 10,000 for k = 0 … 10,000 (the probabilities as the metadata rounds them)."""
    return br.json_numbers(np.arange(10_001) / 10_000)


def _four_decimals(values: np.ndarray) -> ByteRows:
    """Like ``br.json_numbers`` for values rounded to 4 decimals in [0, 1] (a table look-up), NaN → null."""
    k = np.rint(values * 10_000)
    exact = (k >= 0) & (k <= 10_000) & (k / 10_000 == values)
    if not (exact | np.isnan(values)).all():
        return br.json_numbers(values)
    text = _four_decimal_table().take(np.where(exact, k, 0).astype(np.int64))
    nan = ~exact
    if nan.any():
        text = br.concat(len(values), text.blank(exact), ByteRows.constant(b"null", len(values)).blank(nan))
    return text


def sec_nsec(ns: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    sec, nsec = np.divmod(np.asarray(ns, np.int64), 1_000_000_000)
    return np.atleast_1d(sec), np.atleast_1d(nsec)
