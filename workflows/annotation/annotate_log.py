"""One drive log annotated end to end (MCAP, ROS 2 bags, ROS 1 bags → MCAP): the library behind
``lanecast annotate`` and its bulk runs.

One log is annotated in two passes: pass 1 reads its tracks (``registry.read_any``) and the model
forecasts every vehicle with 3 s of history every ``--every`` seconds; pass 2 streams every original
record byte for byte into a new log, merging ``/lanecast/forecast`` (``foxglove.SceneUpdate``) and
``/lanecast/prediction`` (JSON) in log-time order (see ``lanecast.io_adapters.logs.mcap.copy``). The output is
written under a temporary name and renamed when complete; the input is only read. Many logs — a
directory, several paths, ``--workers N`` processes or ``--engine ray`` — go through
``lanecast.workflows.bulk.runner``, which keeps a manifest in OUT_DIR, resumes where a run stopped and
calls ``annotate_log`` for each log. This module is not a command: it has no ``register``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import heapq
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag2 import Reader as Reader2

from lanecast.io_adapters.contracts import forecasts as forecasts_contract
from lanecast.io_adapters.contracts.track_table import read_meta
from lanecast.io_adapters.errors import InputError, LogError
from lanecast.io_adapters.files import atomic_path, check_input, checksum
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import forecast_messages as fm
from lanecast.io_adapters.logs import topics as topic_lists
from lanecast.io_adapters.logs.autoware import predicted_objects_encode as autoware_encode
from lanecast.io_adapters.logs.conventions import BAG_FILES
from lanecast.io_adapters.logs.mcap import copy as mcap_copy
from lanecast.io_adapters.logs.mcap import salvage_copy as mcap_salvage_copy
from lanecast.io_adapters.logs.rosbag import copy as bag_copy
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.topics import MODEL_KEY_PREFIX
from lanecast.io_adapters.progress import activity
from lanecast.models.card import provenance
from lanecast.models.runtime import load_forecaster
from lanecast.workflows.annotation.track_forecasts import (
    forecast_table,
    forecast_windows,
    what_if_table,
    windows_to_forecast,
)

LOG_KINDS = ("mcap", "ros2", "ros1")
MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V"  # any version: the reader says which one it cannot read


@dataclass(frozen=True)
class AnnotateOptions:
    """Everything one log's annotation needs besides its path (picklable: sent to workers)."""

    model_dir: Path | None = None
    topic: str | None = None
    every_s: float = 1.0
    top_k: int = 3
    encoding: str = "auto"  # auto | protobuf | json (plain MCAP; ROS 2 logs are always CDR) | autoware
    forecasts: Path | None = None  # precomputed forecasts: a Parquet file, or a directory of <log>.parquet
    frame_id: str = "map"  # used only when the tracks are not read (precomputed forecasts with origins)
    explain: bool = False  # also /lanecast/explain: each target's forecast with each neighbour removed
    salvage: bool = False  # a damaged MCAP: annotate its intact chunks, the loss reported


#: ``--encoding``: the SceneUpdates ``auto`` picks, and Autoware PredictedObjects besides
AUTOWARE = "autoware"


def log_kind(path: Path) -> str:
    """``mcap``, ``ros2`` (a bag directory) or ``ros1`` (a .bag file), from the first bytes."""
    path = check_input(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        raise LogError(path, "a directory that is not a ROS 2 bag", expected="metadata.yaml inside")
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise InputError(path, f"cannot open: {exc.strerror}") from exc
    if not head:
        raise LogError(
            path, "the file is empty", offset=0, expected="an MCAP file, a ROS 1 bag or a ROS 2 bag directory"
        )
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    raise LogError(
        path, "not a drive log", offset=0, expected="an MCAP file, a ROS 1 bag or a ROS 2 bag directory"
    )


def output_name(src: Path) -> str:
    """The output's file name: ``<stem>.mcap`` for MCAP and ROS 1 bags, the bag's name for ROS 2."""
    src = Path(src)
    if src.is_dir():
        return src.name
    return f"{src.stem}.mcap"


def choose_encoding(
    kind: str, src: Path, requested: str = "auto", *, info: mcap_copy.McapSummaryInfo | None = None
) -> str:
    """The forecast encoding a log gets: CDR for ROS 2 (bag or ``ros2`` MCAP), else protobuf or JSON.

    ``auto`` picks JSON for an MCAP whose channels are all JSON, protobuf otherwise. ``info``: the
    MCAP's summary when the caller has read it already.
    """
    if kind == "ros2":
        return "cdr"
    if kind == "mcap":
        info = info or mcap_copy.summary_info(src)
        if info.profile == "ros2":
            return "cdr"
        if requested == "auto":
            return "json" if info.message_encodings == {"json"} else "protobuf"
    if requested == "auto":
        return "protobuf"
    if requested not in ("protobuf", "json"):
        raise InputError(src, f"unknown forecast encoding {requested!r}", expected="auto, protobuf or json")
    return requested


def log_topics(src: Path, kind: str, *, info: mcap_copy.McapSummaryInfo | None = None) -> frozenset[str]:
    """The topics of a log, from its summary (MCAP) or its connections (bags), without reading messages."""
    if kind == "mcap":
        return (info or mcap_copy.summary_info(src)).topics
    try:
        if kind == "ros2":
            with Reader2(src) as r2:
                return frozenset(c.topic for c in r2.connections)
        with Reader1(src) as r1:
            return frozenset(c.topic for c in r1.connections)
    except Exception as exc:  # rosbags raises its own types for every kind of damage
        # where the bag's structure shows the damage, the same error convert gives (offset)
        raise rosbag_reader.damage_of(src) or LogError(
            src, f"cannot open the bag: {exc}", expected="an intact ROS bag"
        ) from exc


def refuse_annotated(src: Path, kind: str, *, info: mcap_copy.McapSummaryInfo | None = None) -> None:
    """An already annotated log is refused before any work: annotate the original instead."""
    clash = sorted(log_topics(src, kind, info=info) & {fm.FORECAST_TOPIC, fm.PREDICTION_TOPIC})
    if clash:
        raise LogError(
            src, f"the log already has topic(s) {clash}", expected="a log that is not yet annotated"
        )


def read_tracks(
    src: Path, topic: str | None = None, *, salvage: bool = False, crcs_checked_later: bool = False
) -> pa.Table:
    """Pass 1: the log's track table (through the registry's MCAP / bag readers); ``salvage``: an
    MCAP's intact chunks only (the reader reports the loss); ``crcs_checked_later``: an MCAP's CRCs
    are left to pass 2, whose copy checks every one (chunks and data section) before the output
    is renamed into place."""
    options: dict[str, Any] = {"topic": topic} if topic else {}
    if salvage:
        options["salvage"] = True
    elif crcs_checked_later:
        options["crcs_checked_later"] = True
    return registry.read_any([src], **options)


def forecast_times(tracks: pa.Table, every_s: float) -> np.ndarray:
    """The log's forecast times: every multiple of ``every_s`` (rounded to the 10 Hz window grid)
    of log time within the tracks' time span, so that each SceneUpdate holds every vehicle. int64 [T] ns."""
    step = round(every_s * 10) * 100_000_000
    if step <= 0:
        raise InputError(None, f"--every {every_s}", expected="at least 0.1 s")
    if tracks.num_rows == 0:
        return np.zeros(0, dtype=np.int64)
    t = tracks.column("time_ns").to_numpy()
    first = -(-int(t.min()) // step) * step  # ceil to a multiple of step
    return np.arange(first, int(t.max()) + 1, step, dtype=np.int64)


def predict(tracks: pa.Table, options: AnnotateOptions, *, validated: bool = False) -> pa.Table:
    """Forecasts for every vehicle with 3 s of history at every forecast time (lanecast.workflows.annotation.track_forecasts).

    ``validated``: the tracks come from a reader (validated there, not checked again)."""
    return forecast_table(
        tracks,
        options.model_dir,
        every_s=options.every_s,
        top_k=options.top_k,
        t0_ns=forecast_times(tracks, options.every_s),
        validated=validated,
    )


def precomputed_forecasts_path(src: Path, source: Path) -> Path:
    """Where ``src``'s precomputed forecasts are: ``source`` itself, or ``source/<log stem>.parquet``."""
    return source / f"{Path(output_name(src)).stem}.parquet" if source.is_dir() else source


def precomputed_forecasts(src: Path, source: Path) -> pa.Table:
    """A precomputed forecasts table for ``src`` (see ``precomputed_forecasts_path``)."""
    path = precomputed_forecasts_path(src, source)
    if not path.is_file():
        raise InputError(path, "no precomputed forecasts for this log", expected=f"forecasts for {src.name}")
    return read_forecasts_table(path)


def read_forecasts_table(path: Path) -> pa.Table:
    """A precomputed forecasts table, checked (``contracts.forecasts.validate``): InputError naming
    ``path`` for a file that is not Parquet, a missing column, or a forecast point (``x``, ``y``)
    that is null, NaN or infinite, giving its row."""
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(
            path, f"unreadable forecasts table: {exc}", expected="a Parquet table of forecasts"
        ) from exc
    forecasts_contract.validate(table, path)
    return table


def _readable(path: Path) -> None:
    """Give an output the permissions of a normally created file (temporaries are private: 0600/0700)."""
    umask = os.umask(0)
    os.umask(umask)
    path.chmod((0o777 if path.is_dir() else 0o666) & ~umask)


def annotate_log(
    src: Path,
    out: Path,
    options: AnnotateOptions | None = None,
    *,
    forecasts: pa.Table | None = None,
    tracks: pa.Table | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Annotate one log into ``out`` (a file, or a directory for a ROS 2 bag); return its counts.

    ``forecasts`` (and ``tracks``) may be given; otherwise pass 1 reads the tracks and the model
    predicts. Counts: messages copied, forecast messages added, forecast frames and targets, bytes
    in/out, the seconds spent reading tracks, predicting and writing, and ``sha256``, the checksum
    of the input (for MCAP taken from the bytes the copy reads: no extra pass over the log).
    The MCAP summary is read once and shared by the checks, the encoding and the copy.
    """
    src, out = Path(src), Path(out)
    options = options or AnnotateOptions()
    if os.path.realpath(out) == os.path.realpath(check_input(src)):
        raise InputError(out, "the output would overwrite the input log", expected="another output path")
    kind = log_kind(src)
    info = mcap_copy.summary_info(src) if kind == "mcap" else None
    refuse_annotated(src, kind, info=info)
    started = time.perf_counter()
    if forecasts is None and options.forecasts is not None:
        forecasts = precomputed_forecasts(src, options.forecasts)
    need_tracks = (
        forecasts is None or options.explain or not {"origin_x", "origin_y"} <= set(forecasts.column_names)
    )
    read_here = tracks is None and need_tracks
    if read_here:
        with activity(f"annotate: {src.name}: reading its tracks"):
            tracks = read_tracks(
                src,
                options.topic,
                salvage=options.salvage and kind == "mcap",
                crcs_checked_later=kind == "mcap",
            )
    read_s = time.perf_counter() - started
    what_ifs: pa.Table | None = None
    if options.explain:
        assert tracks is not None
        forecaster = load_forecaster(options.model_dir)
        times = forecast_times(tracks, options.every_s)
        windows = windows_to_forecast(
            tracks, forecaster, every_s=options.every_s, t0_ns=times, validated=read_here
        )
        if forecasts is None:
            forecasts = forecast_windows(windows, top_k=options.top_k, forecaster=forecaster)
        what_ifs = what_if_table(windows, forecaster)
    if forecasts is None:
        assert tracks is not None
        with activity(f"annotate: {src.name}: forecasting"):
            forecasts = predict(tracks, options, validated=read_here)
    model_s = time.perf_counter() - started - read_s
    # forecasts and tracks count from the recordings' start; the log's clock adds its offset
    offset = conv.read_offset(tracks) if tracks is not None else topic_lists.time_offset(src)
    forecasts = conv.shifted(forecasts, offset, "t0_ns")
    what_ifs = conv.shifted(what_ifs, offset, "t0_ns") if what_ifs is not None else None
    tracks = conv.shifted(tracks, offset) if tracks is not None else None

    frame_ids: str | dict[str, str] = options.frame_id
    if tracks is not None:
        frame_ids = {name: rec.coordinate_frame for name, rec in read_meta(tracks).recordings.items()}
    autoware = options.encoding == AUTOWARE  # the SceneUpdates as auto picks them, and PredictedObjects
    encoding = choose_encoding(kind, src, "auto" if autoware else options.encoding, info=info)
    specs = fm.channel_specs(encoding) + ([fm.explain_channel_spec(encoding)] if what_ifs is not None else [])
    named: tuple[tuple[str, str], ...] = ()
    if options.forecasts is None:  # the log names the model that made its forecasts
        prov = provenance(options.model_dir)
        named = (
            ("model", prov["model"]),
            ("model_sha256", prov["sha256"]),
            ("model_trained_on", prov["trained_on"]),
        )
        specs = [dataclasses.replace(s, metadata=named) for s in specs]
    specs += [autoware_encode.channel_spec()] if autoware else []
    n_frames = 0

    def forecast_messages() -> Iterator[mcap_copy.ExtraMessage]:
        nonlocal n_frames
        assert forecasts is not None
        batch = fm.batch_from_table(forecasts, frame_id=frame_ids, tracks=tracks, lifetime_s=options.every_s)
        for t0_ns, scene, prediction in fm.encode_batch(batch, encoding):
            n_frames += 1
            yield t0_ns, 0, scene
            yield t0_ns, 1, prediction

    def explain_messages() -> Iterator[mcap_copy.ExtraMessage]:
        if what_ifs is None:
            return
        batch = fm.batch_from_table(what_ifs, frame_id=frame_ids, tracks=tracks, lifetime_s=options.every_s)
        for t0_ns, scene, _ in fm.encode_batch(batch, encoding):
            yield t0_ns, 2, scene

    def autoware_messages() -> Iterator[mcap_copy.ExtraMessage]:
        if not autoware:
            return
        assert forecasts is not None
        batch = fm.batch_from_table(forecasts, frame_id=frame_ids, tracks=tracks, lifetime_s=options.every_s)
        for t0_ns, payload in autoware_encode.encode_batch(batch):
            yield t0_ns, len(specs) - 1, payload

    def extra() -> Iterator[mcap_copy.ExtraMessage]:
        """Forecasts and what-ifs merged in log-time order (the forecast of a time before its what-ifs)."""
        messages = (forecast_messages(), explain_messages(), autoware_messages())
        yield from heapq.merge(*messages, key=lambda m: (m[0], m[1]))

    def merge() -> mcap_copy.Merge:
        return mcap_copy.Merge(channels=specs, extra=extra(), progress=progress)

    write_started = time.perf_counter()
    digest = hashlib.sha256()
    if kind == "ros2":
        with atomic_path(out, directory=True, replaces=BAG_FILES) as tmp:
            inner = tmp / out.name  # rosbags creates the bag directory and names its files after it
            store = autoware_encode.writer_typestore() if autoware else fm.ros2_typestore()
            custom = {f"{MODEL_KEY_PREFIX}{key}": value for key, value in named}  # in metadata.yaml
            stats = bag_copy.copy_ros2_bag(src, inner, merge(), typestore=store, custom_data=custom)
            for part in inner.iterdir():  # relative paths in metadata.yaml stay valid one level up
                part.rename(tmp / part.name)
                _readable(tmp / part.name)
                with open(tmp / part.name, "rb") as done:
                    os.fsync(done.fileno())
            inner.rmdir()
            _readable(tmp)
    else:
        with atomic_path(out) as tmp, open(tmp, "wb") as f:
            if kind == "mcap":
                copy = mcap_salvage_copy.copy_mcap_salvaged if options.salvage else mcap_copy.copy_mcap
                stats = copy(src, f, merge(), mcap_copy.CopyOptions(info=info, digest=digest))
            else:
                stats = bag_copy.copy_ros1_to_mcap(src, f, merge())
            f.flush()
            os.fsync(f.fileno())
            _readable(tmp)
    write_s = time.perf_counter() - write_started
    return {
        "kind": kind,
        "encoding": encoding,
        **stats.as_dict(),
        "forecast_frames": n_frames,
        "forecast_targets": forecasts.num_rows,
        "what_if_forecasts": 0 if what_ifs is None else what_ifs.num_rows,
        "out_of_distribution": (
            int(
                np.count_nonzero(
                    forecasts.column("out_of_distribution").fill_null(False).to_numpy(zero_copy_only=False)
                )
            )
            if "out_of_distribution" in forecasts.column_names
            else None
        ),
        "read_s": round(read_s, 3),
        "model_s": round(model_s, 3),
        "write_s": round(write_s, 3),
        "sha256": digest.hexdigest() if kind == "mcap" else checksum(src),
    }
