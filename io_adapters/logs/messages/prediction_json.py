"""The /lanecast/prediction document: lanecast's own JSON of a frame's forecasts, as numbers.

One compact JSON document per frame (:data:`PREDICTION_SCHEMA`): recording, frame id, t0, the
horizon and, per target, positions, maneuvers, maneuver probabilities, the out-of-distribution flag
and the alternatives. The text equals ``json.dumps(document, separators=(",", ":"))`` but is built
from text templates filled column-wise, without a dict per target. In ROS 2 logs it travels as the
``data`` of a ``std_msgs/msg/String``.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.track_table import MAX_POSITION_M
from lanecast.io_adapters.contracts.windows import MANEUVERS
from lanecast.io_adapters.logs.forecast_batch import N_STEPS, ForecastBatch, ForecastFrame

PREDICTION_SCHEMA: dict[str, Any] = {
    "$schema": "http://json-schema.org/draft-07/schema#",
    "title": "lanecast.Prediction",
    "description": "lanecast forecasts at one time t0: per target, positions at t0 + horizon_s in frame_id "
    "(m) and maneuver probabilities (straight, left, right) per horizon step",
    "type": "object",
    "required": ["recording", "frame_id", "t0_ns", "horizon_s", "targets"],
    "properties": {
        "recording": {"type": "string"},
        "frame_id": {"type": "string"},
        "t0_ns": {"type": "integer"},
        "horizon_s": {"type": "array", "items": {"type": "number"}},
        "maneuver_names": {"type": "array", "items": {"type": "string"}},
        "targets": {
            "type": "array",
            "items": {
                "type": "object",
                "required": ["track_id", "x", "y", "maneuver", "maneuver_probs"],
                "properties": {
                    "track_id": {"type": "integer"},
                    "origin": {"type": ["array", "null"], "items": {"type": "number"}},
                    "x": {"type": "array", "items": {"type": "number"}},
                    "y": {"type": "array", "items": {"type": "number"}},
                    "maneuver": {"type": "array", "items": {"type": "integer", "minimum": -1, "maximum": 2}},
                    "maneuver_probs": {
                        "type": ["array", "null"],
                        "items": {"type": "array", "items": {"type": ["number", "null"]}},
                    },
                    "out_of_distribution": {
                        "type": ["boolean", "null"],
                        "description": "the target's state (speed, acceleration) lies outside the model's "
                        "training distribution: treat the forecast with caution (null: unknown)",
                    },
                    "alternatives": {
                        "type": "array",
                        "items": {
                            "type": "object",
                            "properties": {
                                "prob": {"type": ["number", "null"]},
                                "x": {"type": "array", "items": {"type": "number"}},
                                "y": {"type": "array", "items": {"type": "number"}},
                                "maneuver": {"type": "array", "items": {"type": "integer"}},
                            },
                        },
                    },
                },
            },
        },
    },
}


def prediction_texts(batch: ForecastBatch) -> list[bytes]:
    """The /lanecast/prediction JSON document of each frame (:data:`PREDICTION_SCHEMA`), compact.

    Text equal to ``json.dumps(document, separators=(",", ":"))``; NaN (baselines) is null, a
    target's probabilities that are all NaN are null. Built as text templates filled column-wise
    (:func:`_fill_rows`): the cost is CPython formatting the numbers, as in ``json.dumps``, without
    a dict per target.
    """
    n, k = batch.track_id.size, batch.alt_prob.shape[1]
    if n == 0:
        return []
    has_origin = ~np.isnan(batch.origin).any(axis=1)
    origin = np.asarray(_fill_rows(["[", ",", "]"], _number_texts(batch.origin)), dtype=object)
    origin[~has_origin] = "null"
    steps = _fill_rows(["[", ",", ",", "]"], _number_texts(batch.probs.reshape(n * N_STEPS, 3)))
    probs = np.asarray(
        _fill_rows(["[", *[","] * (N_STEPS - 1), "]"], np.asarray(steps, dtype=object).reshape(n, N_STEPS)),
        dtype=object,
    )
    probs[np.isnan(batch.probs.reshape(n, -1)).all(axis=1)] = "null"
    list5 = [*[","] * (N_STEPS - 1), "]"]
    literals = ['{"track_id":', ',"origin":', ',"x":[', *list5[:-1], '],"y":[', *list5[:-1]]
    literals += ['],"maneuver":[', *list5[:-1], '],"maneuver_probs":', ',"out_of_distribution":']
    literals += [',"alternatives":[']
    columns = [
        _int_texts(batch.track_id[:, None]),
        origin[:, None],
        _number_texts(batch.points[..., 0]),
        _number_texts(batch.points[..., 1]),
        _int_texts(batch.maneuver),
        probs[:, None],
        _flag_texts(batch.out_of_distribution, n)[:, None],
    ]
    for j in range(k):
        literals[-1] += ("," if j else "") + '{"prob":'
        literals += [',"x":[', *list5[:-1], '],"y":[', *list5[:-1], '],"maneuver":[', *list5[:-1]]
        columns += [
            _number_texts(batch.alt_prob[:, j : j + 1]),
            _number_texts(batch.alt_points[:, j, :, 0]),
            _number_texts(batch.alt_points[:, j, :, 1]),
            _int_texts(batch.alt_maneuver[:, j]),
        ]
        literals.append("]}")
    literals[-1] += "]}"
    targets = _fill_rows(literals, np.concatenate(columns, axis=1))
    horizon = json.dumps(batch.horizon_s.tolist(), separators=(",", ":"))
    names = json.dumps(list(MANEUVERS), separators=(",", ":"))
    return [
        (
            f'{{"recording":{json.dumps(r)},"frame_id":{json.dumps(i)},"t0_ns":{t},'
            f'"horizon_s":{horizon},"maneuver_names":{names},"targets":[' + ",".join(targets[lo:hi]) + "]}"
        ).encode()
        for r, i, t, lo, hi in zip(
            batch.recording,
            batch.frame_id,
            batch.t0_ns.tolist(),
            batch.bounds[:-1].tolist(),
            batch.bounds[1:].tolist(),
            strict=True,
        )
    ]


def _number_texts(values: np.ndarray) -> np.ndarray:
    """Python's ``repr`` of each float64 of values [N, M] (NaN → ``null``): object [N, M]."""
    flat = np.asarray(values, np.float64)
    texts = np.array(list(map(float.__repr__, flat.ravel().tolist())), dtype=object)
    texts[np.isnan(flat.ravel())] = "null"
    return texts.reshape(flat.shape)


def _int_texts(values: np.ndarray) -> np.ndarray:
    """Decimal text of each integer of values [N, M]: object [N, M]."""
    flat = np.asarray(values, np.int64)
    return np.array(list(map(str, flat.ravel().tolist())), dtype=object).reshape(flat.shape)


def _fill_rows(literals: list[str], tokens: np.ndarray) -> list[str]:
    """One text per row: literals[0] tokens[i, 0] literals[1] … tokens[i, M-1] literals[M].

    tokens: object [N, M] of str, M + 1 literals. One ``str.join`` over all rows, cut at a
    separator byte that JSON text never holds unescaped (U+0001).
    """
    n, m = tokens.shape
    if len(literals) != m + 1:
        raise ValueError(f"{len(literals)} literals for {m} tokens")
    cells = np.empty((n, 2 * m + 2), dtype=object)
    cells[:, 0 : 2 * m : 2] = np.array(literals[:m], dtype=object)
    cells[:, 1 : 2 * m : 2] = tokens
    cells[:, 2 * m] = literals[m]
    cells[:, 2 * m + 1] = "\x01"
    return "".join(cells.ravel().tolist()).split("\x01")[:n]


def _flag_texts(flags: np.ndarray | None, n: int) -> np.ndarray:
    """JSON ``true`` / ``false`` / ``null`` per row from int8 flags [n] (1, 0, -1; None: all null): object [n]."""
    if flags is None:
        return np.full(n, "null", dtype=object)
    return np.array(["null", "false", "true"], dtype=object)[np.asarray(flags, np.int64) + 1]


def prediction_dict(frame: ForecastFrame) -> dict[str, Any]:
    """The /lanecast/prediction document of a frame (follows :data:`PREDICTION_SCHEMA`)."""
    doc: dict[str, Any] = json.loads(prediction_texts(ForecastBatch.of(frame))[0])
    return doc


def document_problem(doc: Any) -> tuple[str, str] | None:
    """(field, what it should be) of the first field of a /lanecast/prediction document that
    :data:`PREDICTION_SCHEMA` (with ``N_STEPS`` points, finite coordinates, 3 probabilities a step)
    does not allow, or None: the check a reader of a log it did not write needs."""
    if not isinstance(doc, dict):
        return "", "a JSON object"
    if not isinstance(doc.get("recording"), str):
        return "recording", "a string"
    if not _is_int(doc.get("t0_ns")):
        return "t0_ns", "an integer (ns)"
    targets = doc.get("targets")
    if not isinstance(targets, list):
        return "targets", "a list"
    for j, t in enumerate(targets):
        where = f"targets[{j}]"
        if not isinstance(t, dict):
            return where, "an object"
        if not _is_int(t.get("track_id")):
            return f"{where}.track_id", "an integer"
        for key in ("x", "y"):
            if not _points(t.get(key)):
                return f"{where}.{key}", f"{N_STEPS} finite numbers within ±{MAX_POSITION_M:g} m"
        origin = t.get("origin")
        if origin is not None and not _points(origin, 2):
            return f"{where}.origin", f"null or 2 finite numbers within ±{MAX_POSITION_M:g} m"
        m = t.get("maneuver")
        if not (isinstance(m, list) and len(m) == N_STEPS and all(_is_int(v) and -1 <= v <= 2 for v in m)):
            return f"{where}.maneuver", f"{N_STEPS} integers from -1 to 2"
        p = t.get("maneuver_probs")
        if p is not None and not (
            isinstance(p, list)
            and len(p) == N_STEPS
            and all(
                isinstance(s, list) and len(s) == len(MANEUVERS) and all(_probability(v) for v in s)
                for s in p
            )
        ):
            return (
                f"{where}.maneuver_probs",
                f"null or {N_STEPS} lists of {len(MANEUVERS)} numbers from 0 to 1 or nulls",
            )
        alts = t.get("alternatives", [])
        if not isinstance(alts, list):
            return f"{where}.alternatives", "a list"
        for k, a in enumerate(alts):
            if not isinstance(a, dict) or not _points(a.get("x")) or not _points(a.get("y")):
                return (
                    f"{where}.alternatives[{k}]",
                    f"an object with x and y of {N_STEPS} finite numbers within ±{MAX_POSITION_M:g} m",
                )
            if not _probability(a.get("prob")):
                return f"{where}.alternatives[{k}].prob", "a number from 0 to 1 or null"
    return None


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and -(2**63) <= v < 2**63


def _probability(v: Any) -> bool:
    """null, or a number from 0 to 1 (1e308 or NaN made the report's reliability bins a traceback)."""
    return v is None or (isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0)


def _points(v: Any, n: int = N_STEPS) -> bool:
    """``n`` finite coordinates within the track table's ±MAX_POSITION_M (1e308 overflowed the
    report's RMSE to inf, and its table to a traceback)."""
    if not isinstance(v, list) or len(v) != n:
        return False
    try:
        return all(type(c) is not bool and math.isfinite(c) and abs(c) <= MAX_POSITION_M for c in v)
    except TypeError:  # not a number (a string, null, a list)
        return False
