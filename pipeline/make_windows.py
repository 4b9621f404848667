"""Track table -> windows dataset: resample (10 Hz) -> neighbours -> tensors -> labels -> split.

:func:`make_windows`: a table in memory -> Windows in memory, for library users, annotation and
reports; with the stages' glue it shares with the streamed path of
:mod:`lanecast.pipeline.write_windows` (groups of recordings, splits, skipped recordings, the
manifest).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

import lanecast
from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_bounds
from lanecast.io_adapters.contracts.windows import (
    CHANNEL_UNITS,
    CHANNELS,
    FORMAT_NAME,
    FORMAT_VERSION,
    HISTORY,
    HORIZONS,
    INDEX_SCHEMA,
    MANEUVERS,
    ROWS,
    SPLITS,
    Windows,
)
from lanecast.io_adapters.errors import InputError
from lanecast.pipeline import labels as labels_mod
from lanecast.pipeline import neighbour_columns as nb_cols
from lanecast.pipeline import neighbours as nb_mod
from lanecast.pipeline import window_tensors as wt
from lanecast.pipeline.resample import GAP_FACTOR, RATE_HZ, resample_with_physics, step_ns
from lanecast.pipeline.splits import (
    SPLIT_METHODS,
    hash_unit_codes,
    pip_split_by_max,
    split_from_unit,
    track_splits,
)

MAX_ROWS = 4_000_000  # input rows per group of recordings processed together


def make_windows(
    table: pa.Table,
    *,
    stride: int = 10,
    require_future: bool = True,
    split: str = "pip",
    seed: int = 0,
    t0_ns: np.ndarray | None = None,
    neighbours: str = "auto",
    lane_width: float = nb_cols.LANE_WIDTH,
    neighbour_range: float = nb_cols.NEIGHBOUR_RANGE_M,
    allow_empty: bool = False,
    max_rows: int = MAX_ROWS,
    workers: int = wt.WORKERS,
    validated: bool = False,
) -> Windows:
    """Every window of ``table`` (a validated track table at any rate).

    ``stride``: frames at 10 Hz between window starts of a track; ``require_future``: windows need
    T's 5 s of future (else future NaN / maneuver -1 where it is missing); ``split``: pip, hash or
    none (seeded by ``seed``); ``t0_ns``: only windows at these times (rounded to 10 Hz frames),
    instead of every ``stride`` frames; ``neighbours``: auto, source, lanes or bands;
    ``neighbour_range``: metres ahead or behind beyond which a vehicle is no neighbour.
    Recordings are processed in groups of at most ``max_rows`` input rows (a loop over
    recordings, so that memory stays bounded on whole datasets), on ``workers`` threads; each
    group is vectorised. The stage times in the manifest are summed over groups (CPU-like).
    ``validated``: the caller vouches that ``table`` passed ``track_table.validate`` (every reader
    validates what it returns), so it is not checked twice; the metadata is parsed once here and
    handed to every stage.
    Raises InputError when no window results (unless ``allow_empty``), naming why.
    """
    if stride < 1:
        raise InputError(None, f"stride {stride}", expected="a stride of at least 1 frame")
    if not neighbour_range > 0:
        raise InputError(None, f"neighbour range {neighbour_range}", expected="a positive range in metres")
    if split not in SPLIT_METHODS:
        raise InputError(None, f"unknown split method {split!r}", expected=f"one of {SPLIT_METHODS}")
    timings = {"resample_s": 0.0, "neighbours_s": 0.0, "windows_s": 0.0}
    if not validated:
        track_table.validate(table)
    meta = track_table.read_meta(table)
    t0_frames = None
    if t0_ns is not None:
        step = step_ns(RATE_HZ)
        t0_frames = (np.asarray(t0_ns, dtype=np.int64) + step // 2) // step
    # Groups of whole recordings, at least ``workers`` of them where the table has that many
    # recordings (highD: the two directions), processed on ``workers`` threads (numpy and Arrow
    # release the GIL in the heavy operations).
    per_group = min(max_rows, -(-table.num_rows // max(workers, 1)))
    groups = recording_groups(table, max(per_group, 1))

    parallel = workers > 1 and len(groups) > 1
    parts: list[_Part] = []
    batch_inputs: list[np.ndarray] = []
    batch_present: list[np.ndarray] = []

    def prepare(group: tuple[int, int]) -> _Prep:
        lo, hi = group
        return prepare_group(
            table.slice(lo, hi - lo),
            meta,
            stride,
            require_future,
            t0_frames,
            neighbours,
            lane_width,
            neighbour_range,
        )

    with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
        # Batches of `workers` groups: prepared in parallel (resampling and neighbours are CPU
        # bound), then gathered into one allocation.
        for b in range(0, len(groups), max(workers, 1)):
            chunk = groups[b : b + max(workers, 1)]
            preps = list(pool.map(prepare, chunk)) if parallel else [prepare(g) for g in chunk]
            filled_inputs, filled_present, filled = _fill(preps)
            batch_inputs.append(filled_inputs)
            batch_present.append(filled_present)
            parts.extend(filled)
    for p in parts:
        for k, v in p.timings.items():
            timings[k] += v
    # Splits are per track of the whole input, then inherited by every window of the track.
    all_names, all_codes = track_table.recording_codes(table)
    inputs = concat_arrays(batch_inputs, (0, 4, len(ROWS), HISTORY), np.float32)  # no copy for one batch
    present = concat_arrays(batch_present, (0, len(ROWS), HISTORY), np.bool_)
    future = concat_arrays([p.arrays.future for p in parts], (0, HORIZONS, 2), np.float32)
    maneuver = concat_arrays([p.arrays.maneuver for p in parts], (0, HORIZONS), np.int64)
    origin = concat_arrays([p.arrays.origin for p in parts], (0, 3), np.float64)
    rec_codes = (
        np.concatenate([np.searchsorted(all_names, p.names)[p.rec_code] for p in parts])
        if parts
        else np.zeros(0, dtype=np.int64)
    )
    rec_names = all_names[rec_codes]
    track_ids = np.concatenate([p.track for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    t0_times = np.concatenate([p.t0_ns for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    win_split = window_splits(table, meta, all_names, all_codes, rec_codes, track_ids, split, seed)
    index = window_index(rec_names, track_ids, t0_times, win_split, origin)
    windows = Windows(inputs, present, future, maneuver, index)
    skipped = {k: v for p in parts for k, v in p.skipped.items()}
    for name in meta.recordings:
        if not any(name in p.methods for p in parts):
            skipped[name] = "no rows at 10 Hz (no sample on a multiple of 0.1 s within any track)"
    methods = {k: v for p in parts for k, v in p.methods.items()}
    windows.manifest = build_manifest(
        windows,
        meta,
        parameters=window_parameters(
            stride=stride,
            require_future=require_future,
            split=split,
            seed=seed,
            t0_ns_given=t0_ns is not None,
            neighbours=neighbours,
            lane_width=lane_width,
            neighbour_range=neighbour_range,
        ),
        neighbour_methods=methods,
        skipped=skipped,
        timings=timings,
    )
    if len(windows) == 0 and not allow_empty:
        reasons = "; ".join(f"{name}: {why}" for name, why in skipped.items()) or "no tracks"
        raise InputError(
            ", ".join(meta.source_files) or None,
            f"no windows: {reasons}",
            expected=f"tracks with {HISTORY / RATE_HZ:g} s of gap-free history"
            + (f" and {wt.FUTURE / RATE_HZ:g} s of future" if require_future else ""),
        )
    return windows


@dataclass
class _Part:
    """The windows of one group of recordings."""

    arrays: wt.WindowArrays
    names: np.ndarray  # str [R]: recordings of the group
    rec_code: np.ndarray  # int64 [W]: index into names
    track: np.ndarray  # int64 [W]
    t0_ns: np.ndarray  # int64 [W]
    methods: dict[str, str]
    skipped: dict[str, str]
    timings: dict[str, float]  # seconds per stage (summed over groups in the manifest)


def recording_groups(table: pa.Table, max_rows: int) -> list[tuple[int, int]]:
    """Contiguous row ranges [lo, hi) of whole recordings, each at most ``max_rows`` rows unless
    one recording alone is larger. The table is sorted by recording."""
    _, codes = track_table.recording_codes(table)
    if codes.size == 0:
        return []
    bounds = run_bounds(codes)
    groups: list[tuple[int, int]] = []
    lo = prev = 0
    for end in bounds[1:].tolist():
        if end - lo > max_rows and prev > lo:
            groups.append((lo, prev))
            lo = prev
        prev = end
    groups.append((lo, prev))
    return groups


@dataclass
class _Prep:
    """One group of recordings resampled, with neighbours, labels and window rows."""

    cols: nb_cols.Columns
    neighbour_rows: np.ndarray
    labels: np.ndarray
    t0_rows: np.ndarray
    fwd: np.ndarray
    methods: dict[str, str]
    skipped: dict[str, str]
    timings: dict[str, float]


def prepare_group(
    table: pa.Table,
    meta: track_table.TableMeta,
    stride: int,
    require_future: bool,
    t0_frames: np.ndarray | None,
    neighbours: str,
    lane_width: float,
    neighbour_range: float,
    targets: tuple[int, int] | None = None,
) -> _Prep:
    """resample -> neighbours -> labels -> window rows for one group of recordings (``targets``:
    only the windows of track ids first…last, the other tracks being their context)."""
    timings: dict[str, float] = {}
    t = time.perf_counter()
    table10, physics = resample_with_physics(table, RATE_HZ, GAP_FACTOR, meta=meta)
    timings["resample_s"] = time.perf_counter() - t
    t = time.perf_counter()
    # resampling changes rates, not coordinate frames; its float64 results are used as computed
    cols = nb_cols.columns(table10, meta=meta, physics=physics)
    nb = nb_mod.neighbour_rows(
        table10, cols, method=neighbours, lane_width=lane_width, max_range_m=neighbour_range
    )
    timings["neighbours_s"] = time.perf_counter() - t
    t = time.perf_counter()
    row_labels = labels_mod.row_labels(cols, RATE_HZ)
    back, fwd = wt.runs(cols)
    t0_rows = wt.window_rows(
        cols, stride=stride, require_future=require_future, t0_frames=t0_frames, back=back, fwd=fwd
    )
    if targets is not None:
        is_target = (cols.track >= targets[0]) & (cols.track <= targets[1])
        t0_rows = t0_rows[is_target[t0_rows]]
        back = np.where(is_target, back, 0)  # context tracks are cut: not the recording's longest
    timings["windows_s"] = time.perf_counter() - t
    skipped = _skipped(cols, t0_rows, back, require_future)
    return _Prep(cols, nb.rows, row_labels, t0_rows, fwd, nb.methods, skipped, timings)


def _fill(preps: list[_Prep]) -> tuple[np.ndarray, np.ndarray, list[_Part]]:
    """Gather the windows of prepared groups into one allocation, each group its own slice:
    (inputs [W, 4, 8, 30], present [W, 8, 30], the groups' parts). One thread: the gather is
    bound by faulting in the output memory, which parallel threads only contend for."""
    counts = [p.t0_rows.size for p in preps]
    offsets = np.r_[0, np.cumsum(counts)].astype(int)
    total = int(offsets[-1])
    inputs = np.empty((total, 4, len(ROWS), HISTORY), dtype=np.float32)
    present = np.empty((total, len(ROWS), HISTORY), dtype=bool)

    def fill(i: int) -> _Part:
        p, lo, hi = preps[i], offsets[i], offsets[i + 1]
        t = time.perf_counter()
        arrays = wt.gather(
            p.cols,
            p.neighbour_rows,
            p.labels,
            p.t0_rows,
            p.fwd,
            out=(inputs[lo:hi], present[lo:hi]),
        )
        p.timings["windows_s"] += time.perf_counter() - t
        cols = p.cols
        return _Part(
            arrays,
            cols.names,
            cols.rec[p.t0_rows],
            cols.track[p.t0_rows],
            cols.time_ns[p.t0_rows],
            p.methods,
            p.skipped,
            p.timings,
        )

    return inputs, present, [fill(i) for i in range(len(preps))]


def concat_arrays(arrays: list[np.ndarray], empty_shape: tuple[int, ...], dtype: type) -> np.ndarray:
    if not arrays:
        return np.zeros(empty_shape, dtype=dtype)
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def window_splits(
    table: pa.Table,
    meta: track_table.TableMeta,
    names: np.ndarray,
    row_codes: np.ndarray,
    window_codes: np.ndarray,
    track_ids: np.ndarray,
    split: str,
    seed: int,
) -> np.ndarray:
    """The split of every window (str [W]) from its track (see :func:`splits_of_windows`); the
    largest track id of each recording is taken over the rows of ``table``."""
    max_of_rec = np.full(names.size, np.iinfo(np.int64).min, dtype=np.int64)
    if split == "pip":
        np.maximum.at(max_of_rec, row_codes, table.column("track_id").to_numpy())
    return splits_of_windows(meta, names, max_of_rec, window_codes, track_ids, split, seed)


def splits_of_windows(
    meta: track_table.TableMeta,
    names: np.ndarray,
    max_track_of_rec: np.ndarray,
    window_codes: np.ndarray,
    track_ids: np.ndarray,
    split: str,
    seed: int,
) -> np.ndarray:
    """The split of every window (str [W]) from its track: ``names`` str [R] the recordings,
    ``max_track_of_rec`` int64 [R] their largest track id (over input rows), ``window_codes`` int
    [W] index into names. For ``pip`` the max id is taken over every track of the input's source
    recording (recordings sharing source files, e.g. highD's two directions, are one source
    recording)."""
    if split == "hash":
        return split_from_unit(hash_unit_codes(names, window_codes, track_ids, seed))
    if split != "pip":
        return track_splits(names[window_codes], track_ids, split, seed)
    groups = np.array(
        ["|".join(sorted(meta.recordings[str(n)].source_files)) or str(n) for n in names], dtype=object
    )
    max_of_group = {g: int(max_track_of_rec[groups == g].max()) for g in set(groups.tolist())}
    max_id = np.array([max_of_group[g] for g in groups], dtype=np.int64)[window_codes]
    return pip_split_by_max(track_ids, max_id)


def _skipped(
    cols: nb_cols.Columns, t0_rows: np.ndarray, back: np.ndarray, require_future: bool
) -> dict[str, str]:
    """Recordings without a single window and why (for the manifest and error messages)."""
    n_rec = cols.names.size
    per_rec = np.bincount(cols.rec[t0_rows], minlength=n_rec)
    longest = np.zeros(n_rec, dtype=np.int64)
    if cols.n:
        np.maximum.at(longest, cols.rec, back)
    need = HISTORY + (wt.FUTURE if require_future else 0)
    return {
        str(name): f"longest gap-free track is {longest[r]} frame(s) at 10 Hz, a window needs {need}"
        for r, name in enumerate(cols.names)
        if per_rec[r] == 0
    }


def window_parameters(
    *,
    stride: int,
    require_future: bool,
    split: str,
    seed: int,
    t0_ns_given: bool,
    neighbours: str,
    lane_width: float,
    neighbour_range: float,
) -> dict[str, Any]:
    """The ``parameters`` section of a windows manifest."""
    return {
        "stride": stride,
        "require_future": require_future,
        "split": split,
        "seed": seed,
        "t0_ns_given": t0_ns_given,
        "neighbours": neighbours,
        "lane_width_m": lane_width,
        "neighbour_range_m": neighbour_range,
        "rate_hz": RATE_HZ,
        "gap_factor": GAP_FACTOR,
        "history_frames": HISTORY,
        "future_frames": wt.FUTURE,
        "horizons_s": [1, 2, 3, 4, 5],
        "lane_change_window_s": labels_mod.WINDOW_S,
    }


def label_distribution(maneuver: np.ndarray) -> dict[str, int]:
    """Counts of each maneuver label over all windows and steps."""
    counts = {name: int(np.count_nonzero(maneuver == i)) for i, name in enumerate(MANEUVERS)}
    counts["unknown"] = int(np.count_nonzero(maneuver < 0))
    return counts


def build_manifest(
    windows: Windows,
    meta: track_table.TableMeta,
    *,
    parameters: dict[str, Any],
    neighbour_methods: dict[str, str],
    skipped: dict[str, str],
    timings: dict[str, float] | None = None,
) -> dict[str, Any]:
    """The manifest.json document of a windows dataset (``windows.index`` filled in)."""
    split_col = windows.index.column("split").to_numpy(zero_copy_only=False).astype(str)
    counts = {s: int(np.count_nonzero(split_col == s)) for s in SPLITS}
    labels_by_split = {s: label_distribution(windows.maneuver[split_col == s]) for s in SPLITS if counts[s]}
    tracks_by_split = {}
    if len(windows):
        rec = pc.dictionary_encode(windows.index.column("recording")).combine_chunks().indices.to_numpy()
        tid = windows.index.column("track_id").to_numpy()
        for s in SPLITS:
            m = split_col == s
            if m.any():
                order = np.lexsort((tid[m], rec[m]))
                r, t = rec[m][order], tid[m][order]
                tracks_by_split[s] = int(1 + np.count_nonzero((r[1:] != r[:-1]) | (t[1:] != t[:-1])))
    return {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "lanecast_version": lanecast.__version__,
        "parameters": parameters,
        "sources": {
            "source_format": meta.source_format,
            "source_files": meta.source_files,
            "recordings": {
                name: {
                    "native_frame_rate": rec.frame_rate,
                    "coordinate_frame": rec.coordinate_frame,
                    "source_files": rec.source_files,
                    "neighbour_method": neighbour_methods.get(name),
                }
                for name, rec in meta.recordings.items()
            },
        },
        "n_windows": len(windows),
        "counts": counts,
        "tracks": tracks_by_split,
        "label_distribution": label_distribution(windows.maneuver),
        "label_distribution_by_split": labels_by_split,
        "skipped_recordings": skipped,
        "arrays": {
            "inputs": "float32 [N, 4, 8, 30]",
            "present": "bool [N, 8, 30]",
            "future": "float32 [N, 5, 2]",
            "maneuver": "int64 [N, 5]",
        },
        "rows": list(ROWS),
        "channels": list(CHANNELS),
        "maneuvers": list(MANEUVERS),
        "units": {
            **dict(zip(CHANNELS, CHANNEL_UNITS, strict=True)),
            "future": "m",
            "t0_ns": "ns",
            "origin_heading": "rad",
        },
        "window_frame": "origin at the target centre at t0, x along the road (road-frame recordings: "
        "the recording's x axis; others: the target's direction of travel over its history), y to its left; "
        "source_xy = origin + R(origin_heading) @ window_xy",
        "horizons": HORIZONS,
        "timings": timings or {},
    }


def window_index(
    recordings: np.ndarray, track_ids: np.ndarray, t0_ns: np.ndarray, split: np.ndarray, origin: np.ndarray
) -> pa.Table:
    """The windows' index table (INDEX_SCHEMA): recording [N], track_id [N], t0_ns [N], split [N]
    and origin [N, 3] (x, y, heading of the window frame in the source frame)."""
    return pa.Table.from_arrays(
        [
            pa.array(recordings.astype(object), pa.string()),
            pa.array(track_ids, pa.int64()),
            pa.array(t0_ns, pa.int64()),
            pa.array(split.astype(object), pa.string()),
            pa.array(origin[:, 0], pa.float64()),
            pa.array(origin[:, 1], pa.float64()),
            pa.array(origin[:, 2], pa.float64()),
        ],
        schema=INDEX_SCHEMA,
    )
