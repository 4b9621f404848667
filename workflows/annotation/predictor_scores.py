"""A recorded predictor against the future its log holds, beside lanecast on the same objects and times.

Each predicted object is matched to the tracked object of the same id (Autoware UUIDs become track
ids as the track reader makes them) and scored at its own stamp: the truth at stamp + 1…5 s is
the track interpolated linearly between its samples, so predictions stamped ahead of or behind
their tracked objects are aligned by stamp, and the offset to the nearest tracked sample is
measured and reported. Paths are resampled to 1…5 s from their own time step; a path that does not
reach 5 s (or has no positive time step) is refused with the reason. A prediction with no matching
future is counted under its reason (no path left, no track of its id, not tracked at its stamp,
the horizon past the end of the log, the object gone before 5 s, a gap in its track), never dropped
silently. lanecast's ST-CNN and constant velocity then forecast the same tracks at the same times
(the 10 Hz frame of each stamp) and all three are scored on the rows every one of them covers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.logs.autoware.predicted_objects import RecordedPredictions, resample
from lanecast.io_adapters.logs.forecast_batch import N_STEPS
from lanecast.models.baselines import constant_velocity
from lanecast.models.forecasts_from_predictions import forecasts_table
from lanecast.models.predictions import Forecaster
from lanecast.workflows.annotation.track_forecasts import windows_to_forecast

HORIZONS_S = np.arange(1.0, N_STEPS + 1.0)
#: The largest gap (s) between two samples of a track that the truth is interpolated across.
MAX_GAP_S = 0.5
STEP_NS = 100_000_000  # lanecast forecasts on the 10 Hz grid

NO_PATH = "no predicted path"
REFUSED = "every path refused"
NO_TRACK = "no tracked object with its id (an id switch, or never tracked)"
NOT_AT_STAMP = "not tracked at its stamp"
PAST_END = "horizon past the end of the log"
LEFT = "object gone before the last horizon (it left, or its id switched)"
GAP = f"a gap over {MAX_GAP_S:g} s in its track"
NO_WINDOW = "no lanecast window (under 3 s of history at the stamp)"
REASONS = (NO_PATH, REFUSED, NO_TRACK, NOT_AT_STAMP, PAST_END, LEFT, GAP)


@dataclass
class Scored:
    """The N matched predictions of one predictor in one log, and the count of the rest by reason."""

    topic: str
    n_objects: int
    unmatched: dict[str, int]
    refused_paths: dict[str, int]
    stamp_offset_ms: dict[str, float | None]
    recording: str  # the recording most of the predicted objects are in (a label)
    track_id: np.ndarray  # int64 [N]
    t0_ns: np.ndarray  # int64 [N]
    object_class: np.ndarray  # str [N]
    speed: np.ndarray  # float64 [N], m/s at the stamp
    candidates: np.ndarray  # float64 [N, K, 5, 2]
    confidence: np.ndarray  # float64 [N, K], NaN where no path
    true: np.ndarray  # float64 [N, 5, 2]
    row_recording: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))  # str [N]
    log: str = ""  # the log's name in the report
    lanecast: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # on the common rows
    #: the recorded predictor on every matched row, before the rows lanecast cannot forecast are left out
    all_matched: dict[str, np.ndarray] = field(default_factory=dict)


class Tracks:
    """One recording of a track table, sorted by (track, time), for truth lookups at any time."""

    def __init__(self, table: pa.Table) -> None:
        col = {c: table.column(c).to_numpy(zero_copy_only=False) for c in ("track_id", "time_ns", "x", "y")}
        order = np.lexsort((col["time_ns"], col["track_id"]))
        self.track = col["track_id"][order].astype(np.int64)
        self.time = col["time_ns"][order].astype(np.int64)
        self.xy = np.stack([col["x"][order], col["y"][order]], axis=1).astype(np.float64)
        vx, vy = (table.column(c).to_numpy().astype(np.float64)[order] for c in ("vx", "vy"))
        self.speed = np.hypot(vx, vy)
        self.object_class = table.column("object_class").to_numpy(zero_copy_only=False).astype(str)[order]
        self.ids, self.first = np.unique(self.track, return_index=True)
        self.last = np.append(self.first[1:], self.track.size) - 1
        self.log_end = int(self.time.max()) if self.time.size else 0
        # one increasing key over all rows: each track's times shifted past the previous track's end
        # (sums of track durations, never ids × the log's span: no int64 overflow on long logs)
        span = self.time[self.last] - self.time[self.first] + 1
        self.base = np.concatenate([[0], np.cumsum(span)[:-1]]).astype(np.int64)
        rank = np.repeat(np.arange(self.ids.size), self.last - self.first + 1)
        self.key = self.base[rank] + (self.time - self.time[self.first][rank])

    def locate(self, track_id: np.ndarray, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each track id [N] at times [N, T]: (rank of the track [N], -1 if unknown; the sample at or
        before each time [N, T], clipped to the track; the interpolation fraction to the next one [N, T])."""
        rank = np.searchsorted(self.ids, track_id)
        known = (rank < self.ids.size) & (self.ids[np.minimum(rank, self.ids.size - 1)] == track_id)
        rank = np.where(known, rank, -1)
        r = np.maximum(rank, 0)[:, None]
        first, last = self.first[r], self.last[r]
        rel = np.clip(t_ns - self.time[first], 0, self.time[last] - self.time[first])
        row = np.searchsorted(self.key, self.base[r] + rel, side="right") - 1
        row = np.clip(row, first, last)
        nxt = np.minimum(row + 1, last)
        dt = (self.time[nxt] - self.time[row]).astype(np.float64)
        frac = np.where(dt > 0, (t_ns - self.time[row]) / np.where(dt > 0, dt, 1.0), 0.0)
        return rank, row, np.clip(frac, 0.0, 1.0)

    def truth(self, track_id: np.ndarray, t0_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions at t0 + 1…5 s [N, 5, 2], the reason each row has none: "" where it has)."""
        times = t0_ns[:, None] + np.concatenate([[0], (HORIZONS_S * 1e9).astype(np.int64)])[None, :]
        rank, row, frac = self.locate(track_id, times)
        r = np.maximum(rank, 0)
        first_t, last_t = self.time[self.first[r]], self.time[self.last[r]]
        nxt = np.minimum(row + 1, self.last[r][:, None])
        gap = (self.time[nxt] - self.time[row]) > MAX_GAP_S * 1e9
        reason = np.full(track_id.size, "", dtype=object)
        checks = (
            (gap[:, 1:].any(axis=1) | gap[:, :1].any(axis=1), GAP),
            (times[:, -1] > last_t, LEFT),
            (times[:, -1] > self.log_end, PAST_END),
            ((t0_ns < first_t) | (t0_ns > last_t), NOT_AT_STAMP),
            (rank < 0, NO_TRACK),
        )
        for bad, why in checks:  # the last that applies wins: the most basic reason is named
            reason[bad] = why
        xy = self.xy[row] * (1.0 - frac[..., None]) + self.xy[nxt] * frac[..., None]
        return xy[:, 1:], reason.astype(str)

    def nearest(self, track_id: np.ndarray, t0_ns: np.ndarray) -> np.ndarray:
        """The row of each track nearest in time to t0 [N] (track ids must be known)."""
        _, row, frac = self.locate(track_id, t0_ns[:, None])
        return np.minimum(row[:, 0] + (frac[:, 0] > 0.5), self.last[np.searchsorted(self.ids, track_id)])


def recordings_by_hits(tracks: pa.Table, track_ids: np.ndarray) -> list[str]:
    """The recordings of ``tracks``, those holding more of the predicted ``track_ids`` first (a
    log's topics each make one; a predictor may predict the objects of several: lanecast's own
    forecasts of a log of both highD directions)."""
    rec = tracks.column("recording").to_numpy(zero_copy_only=False).astype(str)
    names = np.unique(rec)
    ids = tracks.column("track_id").to_numpy()
    hits = [int(np.isin(np.unique(track_ids), ids[rec == n]).sum()) for n in names]
    return [str(names[i]) for i in np.argsort(hits, kind="stable")[::-1]]


def recording_tracks(tracks: pa.Table) -> dict[str, Tracks]:
    """:class:`Tracks` of each recording of ``tracks``."""
    rec = tracks.column("recording").to_numpy(zero_copy_only=False).astype(str)
    return {str(n): Tracks(tracks.filter(pa.array(rec == n))) for n in np.unique(rec)}


def score_predictor(pred: RecordedPredictions, tracks: pa.Table) -> Scored:
    """Match ``pred`` to the future in ``tracks`` (a track table of the same log, on the log's
    clock: ``conventions.shifted(tracks, conventions.read_offset(tracks))``): each predicted
    object to the recording where its track is known at its stamp (the recording holding most of
    the predicted ids first, where an id is in several)."""
    order = recordings_by_hits(tracks, pred.track_id)
    per_recording = recording_tracks(tracks)
    true = np.full((len(pred), N_STEPS, 2), np.nan)
    reason = np.full(len(pred), NO_TRACK, dtype=object)
    row_recording = np.full(len(pred), "", dtype=object)
    for name in order:
        t, r = per_recording[name].truth(pred.track_id, pred.stamp_ns)
        better = (reason != "") & ((r == "") | ((reason == NO_TRACK) & (r != NO_TRACK)))
        true[better], reason[better], row_recording[better] = t[better], r[better], name
    recording = order[0]
    points, path_reason = resample(pred, HORIZONS_S)
    obj = pred.path_object
    usable = path_reason == ""
    n_usable = np.bincount(obj[usable], minlength=len(pred))
    n_paths = np.diff(pred.path_bounds)
    reason[(n_usable == 0) & (n_paths > 0)] = REFUSED
    reason[n_paths == 0] = NO_PATH
    ok = np.flatnonzero(reason == "")
    k = int(n_usable[ok].max()) if ok.size else 0
    candidates = np.full((ok.size, k, N_STEPS, 2), np.nan)
    confidence = np.full((ok.size, k), np.nan)
    slot_of = np.full(len(pred), -1)
    slot_of[ok] = np.arange(ok.size)
    keep = usable & (slot_of[obj] >= 0)
    rows = slot_of[obj[keep]]
    col = np.arange(keep.sum()) - np.searchsorted(rows, rows)  # rows are sorted: rank within the object
    candidates[rows, col] = points[keep]
    confidence[rows, col] = pred.confidence[keep]
    offset_ms = np.zeros(ok.size)
    object_class = np.empty(ok.size, dtype=object)
    speed = np.zeros(ok.size)
    for name in np.unique(row_recording[ok]):
        tr, rows = per_recording[name], np.flatnonzero(row_recording[ok] == name)
        near = tr.nearest(pred.track_id[ok][rows], pred.stamp_ns[ok][rows])
        offset_ms[rows] = (pred.stamp_ns[ok][rows] - tr.time[near]) / 1e6
        object_class[rows], speed[rows] = tr.object_class[near], tr.speed[near]
    refused, refused_count = np.unique(path_reason[~usable], return_counts=True)
    return Scored(
        topic=pred.topic,
        n_objects=len(pred),
        unmatched={r: int((reason == r).sum()) for r in REASONS if (reason == r).any()},
        refused_paths=dict(zip(refused.tolist(), refused_count.tolist(), strict=True)),
        stamp_offset_ms={
            "median": float(np.median(offset_ms)) if ok.size else None,
            "min": float(offset_ms.min()) if ok.size else None,
            "max": float(offset_ms.max()) if ok.size else None,
        },
        recording=recording,
        track_id=pred.track_id[ok],
        t0_ns=pred.stamp_ns[ok],
        object_class=object_class.astype(str),
        speed=speed,
        candidates=candidates,
        confidence=confidence,
        true=true[ok],
        row_recording=row_recording[ok].astype(str),
    )


def add_lanecast(scored: Scored, tracks: pa.Table, forecasters: list[Forecaster]) -> int:
    """Forecast the scored objects at their stamps with each of ``forecasters`` (and constant
    velocity), keep the rows all of them cover in ``scored`` (the others are counted and returned),
    and put each one's candidates, confidences and truth into ``scored.lanecast``. Each row is
    forecast from the windows of its own recording."""
    rec = tracks.column("recording").to_numpy(zero_copy_only=False).astype(str)
    models = [*forecasters, constant_velocity()]
    n = scored.track_id.size
    keep = np.zeros(n, dtype=bool)
    found: dict[str, dict[str, list[np.ndarray]]] = {
        m.name: {"alt": [], "conf": [], "true": []} for m in models
    }
    rows_done: list[np.ndarray] = []
    for name in np.unique(scored.row_recording):
        rows = np.flatnonzero(scored.row_recording == name)
        table = tracks.filter(pa.array(rec == name))
        tr = Tracks(table)
        windows = windows_to_forecast(table, models[0], t0_ns=np.unique(scored.t0_ns[rows]), validated=True)
        index = windows.index
        w_track, w_t0 = index.column("track_id").to_numpy(), index.column("t0_ns").to_numpy()
        w_true, w_reason = tr.truth(w_track, w_t0)
        window = _same_frame(scored.track_id[rows], scored.t0_ns[rows], w_track, w_t0)
        ok = window >= 0
        ok[ok] = w_reason[window[ok]] == ""
        rows, window = rows[ok], window[ok]
        keep[rows] = True
        rows_done.append(rows)
        for model in models:
            preds = model.predict(windows.inputs[window], windows.present[window], top_k=3)
            t = forecasts_table(index.take(pa.array(window)), preds)
            alt = np.stack([_lists(t, "alt_x"), _lists(t, "alt_y")], axis=-1)
            found[model.name]["alt"].append(alt)
            found[model.name]["conf"].append(
                _lists(t, "alt_probs") if alt.shape[1] > 1 else np.ones(alt.shape[:2])
            )
            found[model.name]["true"].append(w_true[window])
    scored.all_matched = {name: getattr(scored, name) for name in _ROWS}
    done = np.concatenate(rows_done) if rows_done else np.zeros(0, np.int64)
    order = np.argsort(done, kind="stable")  # back to the rows' order in scored
    _subset(scored, keep)
    for model in models:
        parts = found[model.name]
        k = max((a.shape[1] for a in parts["alt"]), default=1)
        alt = (
            np.concatenate([_pad(a, k) for a in parts["alt"]])
            if parts["alt"]
            else np.zeros((0, k, N_STEPS, 2))
        )
        conf = np.concatenate([_pad(c, k) for c in parts["conf"]]) if parts["conf"] else np.zeros((0, k))
        true = np.concatenate(parts["true"]) if parts["true"] else np.zeros((0, N_STEPS, 2))
        scored.lanecast[model.name] = {
            "candidates": alt[order],
            "confidence": conf[order],
            "true": true[order],
        }
    return int(n - keep.sum())


def _pad(a: np.ndarray, k: int) -> np.ndarray:
    """``a`` [M, K', …] widened to K candidates with NaN (recordings and logs may give different K)."""
    if a.shape[1] >= k:
        return a
    out = np.full((a.shape[0], k, *a.shape[2:]), np.nan)
    out[:, : a.shape[1]] = a
    return out


def _same_frame(track: np.ndarray, t0: np.ndarray, w_track: np.ndarray, w_t0: np.ndarray) -> np.ndarray:
    """int64 [N]: the window of the same track at the same 10 Hz frame as each (track, t0), or -1."""
    a = np.stack([track, (t0 + STEP_NS // 2) // STEP_NS], axis=1).astype(np.int64)
    b = np.stack([w_track, (w_t0 + STEP_NS // 2) // STEP_NS], axis=1).astype(np.int64)
    _, inverse = np.unique(np.concatenate([a, b]), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    window_of = np.full(int(inverse.max()) + 1 if inverse.size else 0, -1, dtype=np.int64)
    window_of[inverse[len(a) :]] = np.arange(len(b))
    return window_of[inverse[: len(a)]]


def _lists(table: pa.Table, name: str) -> np.ndarray:
    """A fixed-shape nested list column as a float64 array."""
    col = table.column(name).combine_chunks()
    shape = [table.num_rows]
    while pa.types.is_list(col.type) or pa.types.is_large_list(col.type):
        n = shape[0] * int(np.prod(shape[1:])) if len(shape) > 1 else shape[0]
        flat = col.flatten()
        shape.append(len(flat) // n if n else 0)
        col = flat
    return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(shape)


_ROWS = ("track_id", "t0_ns", "object_class", "speed", "candidates", "confidence", "true", "row_recording")


def _subset(scored: Scored, keep: np.ndarray) -> None:
    for name in _ROWS:
        setattr(scored, name, getattr(scored, name)[keep])


def pooled(parts: list[Scored]) -> dict[str, Any]:
    """The arrays of several logs' ``Scored`` (one predictor) concatenated, lanecast's too."""
    k = max((p.candidates.shape[1] for p in parts), default=0)

    out: dict[str, Any] = {
        name: np.concatenate([getattr(p, name) for p in parts])
        for name in ("track_id", "t0_ns", "object_class", "speed", "true")
    }
    out["candidates"] = np.concatenate([_pad(p.candidates, k) for p in parts])
    out["confidence"] = np.concatenate([_pad(p.confidence, k) for p in parts])
    every = [p.all_matched or {n: getattr(p, n) for n in _ROWS} for p in parts]
    k_all = max((e["candidates"].shape[1] for e in every), default=0)
    out["all_matched"] = {n: np.concatenate([e[n] for e in every]) for n in ("object_class", "speed", "true")}
    for n in ("candidates", "confidence"):
        out["all_matched"][n] = np.concatenate([_pad(e[n], k_all) for e in every])
    names = parts[0].lanecast.keys() if parts else []
    out["lanecast"] = {
        n: {
            key: np.concatenate([p.lanecast[n][key] for p in parts])
            for key in ("candidates", "confidence", "true")
        }
        for n in names
    }
    return out
