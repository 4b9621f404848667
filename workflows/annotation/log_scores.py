"""Metrics of annotated logs, from the forecasts in them and the future they record: the library behind
``lanecast report`` and ``lanecast demo``.

An annotated log holds the original tracks and, on ``/lanecast/prediction``, every forecast lanecast
made. The future of each forecast target is in the log too, so the forecasts can be scored without
the model: the windows at the forecast times give the ground truth (future offsets in the window
frame, maneuver labels from the lane ids), the forecasts are mapped into the same window frames,
and the kinematic baselines run on the same windows. The output has the evaluation's format
(``metrics.json``, ``report.md``, ``report.html``), overall and per log. This module is not a
command: it has no ``register``.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from mcap.reader import NonSeekingReader
from rosbags.highlevel import AnyReader

from lanecast.io_adapters.contracts.window_frame import to_window_frame
from lanecast.io_adapters.contracts.windows import MANEUVERS
from lanecast.io_adapters.errors import InputError, LanecastError, LogError
from lanecast.io_adapters.files import staged_files
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import topics
from lanecast.io_adapters.logs.forecast_batch import N_STEPS
from lanecast.io_adapters.logs.forecast_messages import PREDICTION_TOPIC
from lanecast.io_adapters.logs.messages.prediction_json import document_problem
from lanecast.io_adapters.progress import activity, progress
from lanecast.models.baselines import constant_acceleration, constant_velocity
from lanecast.models.evaluation import speed_band_note, write_metrics
from lanecast.models.metrics import accuracy, confusion_matrix, macro_f1, summary
from lanecast.models.ood import target_speed
from lanecast.models.reports.document import Scene, write_report
from lanecast.pipeline.make_windows import make_windows
from lanecast.workflows.bulk.discovery import discover
from lanecast.workflows.bulk.manifest import MANIFEST, Manifest

STEP_NS = 100_000_000  # windows live on the 10 Hz grid; forecast times are matched on it


@dataclass
class LogForecasts:
    """The forecasts of one annotated log (M targets over all forecast times)."""

    recording: np.ndarray  # str [M]
    track_id: np.ndarray  # int64 [M]
    t0_ns: np.ndarray  # int64 [M]
    points: np.ndarray  # float64 [M, 5, 2], log frame
    maneuver: np.ndarray  # int64 [M, 5], -1 where the forecaster has no classifier
    probs: np.ndarray  # float64 [M, 5, 3], NaN where unknown
    alt_points: np.ndarray  # float64 [M, K, 5, 2]
    alt_probs: np.ndarray  # float64 [M, K]


def report_not_scored(failed: list[str]) -> None:
    """Name the logs a report could not score ("log: why"), last, on stderr, as every command
    reports an error (the report itself lists them all)."""
    if failed:
        more = f"{len(failed)} logs not scored, the first: " if len(failed) > 1 else "not scored: "
        print(f"lanecast report: error: {more}{failed[0]}", file=sys.stderr)


def annotated_logs(paths: list[Path]) -> list[Path]:
    """The annotated logs named by ``paths``: files, directories, or a bulk run's output directory."""
    found: list[Path] = []
    for path in paths:
        if path.is_dir() and (path / MANIFEST).is_file():
            manifest = Manifest(path)
            done = [e for e in manifest.finished().values() if e.get("status") == "done" and e.get("output")]
            if done:
                found += [manifest.output_path(e) for e in done]
                continue
            print(  # a manifest damaged or edited by hand: the logs beside it are still there
                f"lanecast: {manifest.path}: lists no annotated log; reading the logs in {path}",
                file=sys.stderr,
            )
        found += discover([path], exclude=None)
    missing = [p for p in found if not p.exists()]
    if missing:
        raise InputError(missing[0], "an annotated log named by the manifest is missing")
    if not found:
        raise InputError(paths[0], "no annotated logs found", expected="the output of lanecast annotate")
    return sorted(dict.fromkeys(found))


def checked_forecast_times(log: Path, docs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``docs`` if each document's t0_ns is its message's log time (``_log_time``), as lanecast
    annotate writes them: a forecast scored at another time than it was made is scored wrongly."""
    for index, doc in enumerate(docs):
        if doc["t0_ns"] != doc["_log_time"]:
            raise LogError(
                log,
                f"{PREDICTION_TOPIC} message {index + 1} (log time {doc['_log_time']} ns): t0_ns "
                f"{doc['t0_ns']} is not the message's log time",
                column="t0_ns",
                expected="the forecast time, at which lanecast annotate logs it",
            )
    return docs


def prediction_documents(log: Path) -> list[dict[str, Any]]:
    """Every JSON document on /lanecast/prediction of an annotated MCAP or ROS 2 bag, in log order."""
    try:
        docs = _prediction_documents(log)
    except LanecastError:
        raise
    except Exception as exc:  # the mcap and rosbags libraries' own types, a JSON document cut short
        raise LogError(
            log,
            f"cannot read {PREDICTION_TOPIC}: {type(exc).__name__}: {exc}",
            expected="an intact log written by lanecast annotate",
        ) from exc
    if not docs:
        raise InputError(
            log, f"no forecasts on {PREDICTION_TOPIC}", expected="a log written by lanecast annotate"
        )
    if not any(doc["targets"] for doc in docs):
        raise InputError(
            log,
            f"the {len(docs)} forecasts on {PREDICTION_TOPIC} have no targets (no vehicle had 3 s of history)",
            expected="forecasts of at least one vehicle",
        )
    return docs


def _prediction_documents(log: Path) -> list[dict[str, Any]]:
    docs: list[dict[str, Any]] = []
    if log.is_dir():  # a ROS 2 bag: std_msgs/msg/String holding the JSON
        with AnyReader([log]) as reader:
            conns = [c for c in reader.connections if c.topic == PREDICTION_TOPIC]
            for conn, log_time, raw in reader.messages(connections=conns):
                message: Any = reader.deserialize(raw, conn.msgtype)
                docs.append(_document(log, len(docs), log_time, message.data))
    else:
        with log.open("rb") as fh:
            # the data section in file order, not by the summary's chunk indexes: an index that
            # disagrees with the data would skip or repeat chunks (the reader names it in the tracks)
            mcap_reader = NonSeekingReader(fh, validate_crcs=True)
            messages = mcap_reader.iter_messages(topics=[PREDICTION_TOPIC], log_time_order=False)
            for _, channel, message in messages:
                data = bytes(message.data)
                if channel.message_encoding == "cdr":  # std_msgs/String: header, length, text, NUL
                    length = int.from_bytes(data[4:8], "little")
                    data = data[8 : 8 + length - 1]
                docs.append(_document(log, len(docs), message.log_time, data))
    return docs


def _document(log: Path, index: int, log_time: int, text: str | bytes) -> dict[str, Any]:
    """One /lanecast/prediction message's document, checked field by field (a log edited or
    written by another tool): LogError naming the message, its log time and the field."""
    where = f"{PREDICTION_TOPIC} message {index + 1} (log time {log_time} ns)"
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise LogError(
            log, f"{where}: not JSON: {exc}", expected="a lanecast.Prediction JSON document"
        ) from exc
    problem = document_problem(doc)
    if problem is not None:
        field, expected = problem
        what = f"field {field}" if field else "the document"
        raise LogError(
            log, f"{where}: {what} has the wrong type or shape", column=field or None, expected=expected
        )
    layout = {"horizon_s": [float(h) for h in range(1, N_STEPS + 1)], "maneuver_names": list(MANEUVERS)}
    for key, want in layout.items():  # what the scores assume: another layout would be scored wrongly
        if key in doc and doc[key] != want:
            raise LogError(
                log,
                f"{where}: {key} is {doc[key]}",
                column=key,
                expected=f"{want} (what lanecast annotate writes)",
            )
    return {**doc, "_log_time": log_time}


def log_forecasts(docs: list[dict[str, Any]]) -> LogForecasts:
    """Flatten /lanecast/prediction documents into arrays (one row per target and forecast time)."""
    targets = [(d, t) for d in docs for t in d["targets"]]
    k = max((len(t.get("alternatives", [])) for _, t in targets), default=0)

    def probs_of(t: dict[str, Any]) -> list[list[float]]:
        p = t.get("maneuver_probs")
        return [[np.nan] * 3] * 5 if p is None else [[np.nan if v is None else v for v in step] for step in p]

    def alternatives(t: dict[str, Any]) -> tuple[list[Any], list[float]]:
        alts = t.get("alternatives", [])
        pts = [[a["x"], a["y"]] for a in alts] + [[t["x"], t["y"]]] * (k - len(alts))
        prob = [np.nan if a["prob"] is None else a["prob"] for a in alts] + [np.nan] * (k - len(alts))
        return pts, prob

    alts = [alternatives(t) for _, t in targets]
    return LogForecasts(
        recording=np.array([d["recording"] for d, _ in targets], dtype=object),
        track_id=np.array([t["track_id"] for _, t in targets], dtype=np.int64),
        t0_ns=np.array([d["t0_ns"] for d, _ in targets], dtype=np.int64),
        points=np.array([[t["x"], t["y"]] for _, t in targets], dtype=np.float64).transpose(0, 2, 1),
        maneuver=np.array([t["maneuver"] for _, t in targets], dtype=np.int64),
        probs=np.array([probs_of(t) for _, t in targets], dtype=np.float64),
        alt_points=np.array([a[0] for a in alts], dtype=np.float64)
        .reshape(len(alts), k, 2, 5)
        .transpose(0, 1, 3, 2),
        alt_probs=np.array([a[1] for a in alts], dtype=np.float64).reshape(len(alts), k),
    )


def match(fc: LogForecasts, index: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (forecast row, window row) with the same recording, track and 10 Hz forecast time."""
    win_rec = index.column("recording").to_numpy(zero_copy_only=False).astype(str)
    fc_rec = fc.recording.astype(str)
    fc_names, win_names = np.unique(fc_rec), np.unique(win_rec)
    if not np.isin(fc_names, win_names).all() and fc_names.size == win_names.size == 1:
        fc_rec = np.full(fc_rec.size, win_names[0])  # one recording, named after another file stem
    names = np.union1d(fc_names, win_names)

    def keys(rec: np.ndarray, track: np.ndarray, t0: np.ndarray) -> np.ndarray:
        frame = (t0 + STEP_NS // 2) // STEP_NS
        return np.stack([np.searchsorted(names, rec).astype(np.int64), track, frame], axis=1)

    a = keys(fc_rec, fc.track_id, fc.t0_ns)
    b = keys(win_rec, index.column("track_id").to_numpy(), index.column("t0_ns").to_numpy())
    both = np.concatenate([a, b])
    _, inverse = np.unique(both, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    slot_of_window = np.full(inverse.max() + 1 if inverse.size else 0, -1, dtype=np.int64)
    slot_of_window[inverse[len(a) :]] = np.arange(len(b))
    window = slot_of_window[inverse[: len(a)]]
    keep = window >= 0
    return np.flatnonzero(keep), window[keep]


def score_log(log: Path, topic: str | None) -> dict[str, Any]:
    """Arrays needed for the metrics of one annotated log (model forecasts, baselines, ground truth)."""
    # the tracks first: lanecast's own reader checks the log's records and names the offset of a
    # damage (a truncated log was a traceback from the mcap library reading the predictions)
    tracks = registry.read_any([log], topic=topic) if topic else registry.read_any([log])
    fc = log_forecasts(checked_forecast_times(log, prediction_documents(log)))
    fc.t0_ns = fc.t0_ns - conv.read_offset(tracks)  # the log's clock → the tracks' (conventions)
    windows = make_windows(
        tracks,
        require_future=True,
        split="none",
        t0_ns=np.unique(fc.t0_ns),
        allow_empty=True,
        validated=True,  # the readers validate
    )
    fc_rows, win_rows = match(fc, windows.index)
    future = np.asarray(windows.future)[win_rows]
    known = np.isfinite(future).all(axis=(1, 2))
    fc_rows, win_rows, future = fc_rows[known], win_rows[known], future[known]
    index = windows.index.take(pa.array(win_rows))
    origin = (
        index.column("origin_x").to_numpy(),
        index.column("origin_y").to_numpy(),
        index.column("origin_heading").to_numpy(),
    )
    inputs, present = np.asarray(windows.inputs)[win_rows], np.asarray(windows.present)[win_rows]
    baselines = {
        f.name: f.predict(inputs, present, top_k=1, batch_size=4096)
        for f in (constant_velocity(), constant_acceleration())
    }
    return {
        "log": log,
        "model": topics.forecast_model(log),
        "n_forecasts": int(fc.track_id.size),
        "offsets": to_window_frame(fc.points[fc_rows], *origin),
        "candidates": to_window_frame(fc.alt_points[fc_rows], *origin) if fc.alt_points.shape[1] else None,
        "maneuver_pred": fc.maneuver[fc_rows] if (fc.maneuver[fc_rows] >= 0).all() else None,
        "future": future,
        "maneuver": np.asarray(windows.maneuver)[win_rows],
        "recording": index.column("recording").to_numpy(zero_copy_only=False).astype(str),
        "track_id": index.column("track_id").to_numpy(),
        "t0_ns": index.column("t0_ns").to_numpy(),
        "baselines": {name: p.offsets for name, p in baselines.items()},
        "inputs": inputs,
        "present": present,
        "probs": fc.probs[fc_rows],
        "alt_probs": fc.alt_probs[fc_rows],
    }


def metrics_of(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """lanecast.models.metrics.summary for the logged forecasts (``stcnn``) and the baselines over ``parts``."""

    def cat(key: str) -> np.ndarray:
        return np.concatenate([p[key] for p in parts])

    future, maneuver = cat("future"), cat("maneuver")
    log_no = np.concatenate([np.full(len(p["future"]), i) for i, p in enumerate(parts)])
    _, rec_code = np.unique(cat("recording"), return_inverse=True)
    keys = np.stack([log_no, rec_code.reshape(-1), cat("track_id")], axis=1)
    _, vehicle = np.unique(keys, axis=0, return_inverse=True)
    vehicle = vehicle.reshape(-1).astype(np.int64)
    has_candidates = all(p["candidates"] is not None for p in parts)
    has_maneuver = all(p["maneuver_pred"] is not None for p in parts)
    probs = cat("probs")
    log_name = np.concatenate([np.full(len(p["future"]), p["log"].stem, dtype=object) for p in parts])
    speed = target_speed(cat("inputs"))
    out = {
        "stcnn": summary(
            cat("offsets"),
            future,
            maneuver,
            vehicle,
            candidates=cat("candidates") if has_candidates else None,
            predicted_maneuver=cat("maneuver_pred") if has_maneuver else None,
            probs=probs if has_maneuver and np.isfinite(probs).all() else None,
            recording=log_name,
            speed=speed,
        )
    }
    for name in parts[0]["baselines"]:
        out[name] = summary(
            np.concatenate([p["baselines"][name] for p in parts]),
            future,
            maneuver,
            vehicle,
            recording=log_name,
            speed=speed,
        )
    return out


def always_straight_of(parts: list[dict[str, Any]]) -> dict[str, float]:
    """Accuracy and macro-F1 of always predicting straight on the scored forecasts of ``parts``."""
    true = np.concatenate([p["maneuver"] for p in parts])
    conf = confusion_matrix(true, np.zeros_like(true))
    return {"maneuver_accuracy": accuracy(conf), "maneuver_macro_f1": macro_f1(conf)}


def example_scenes(parts: list[dict[str, Any]], count: int) -> list[Scene]:
    """Up to ``count`` scenes: predicted lane changes as examples, then a failure gallery: the largest
    error at 5 s and the most confident lane change that did not happen (per log, in order)."""
    scenes: list[Scene] = []
    for p in parts:
        if p["maneuver_pred"] is None or len(p["future"]) == 0:
            continue
        err5 = np.hypot(*(p["offsets"][:, -1] - p["future"][:, -1]).T)
        changing = np.flatnonzero((p["maneuver_pred"] > 0).any(axis=1) & (p["maneuver"] > 0).any(axis=1))
        _, first_of_track = np.unique(p["track_id"][changing], return_index=True)  # distinct vehicles
        false_change = np.flatnonzero((p["maneuver_pred"] > 0).any(axis=1) & (p["maneuver"] == 0).all(axis=1))
        kinds = {i: ("example", "lane change") for i in changing[np.sort(first_of_track)][:2].tolist()}
        kinds.setdefault(int(np.argmax(err5)), ("failure", "largest error at 5 s"))
        if false_change.size:  # the most confident lane change that did not happen
            confidence = 1.0 - np.nan_to_num(p["probs"][false_change, :, 0], nan=1.0).min(axis=1)
            kinds.setdefault(int(false_change[np.argmax(confidence)]), ("failure", "false lane change"))
        for i, (kind, label) in kinds.items():
            cand = p["candidates"][i] if p["candidates"] is not None else p["offsets"][i][None]
            scenes.append(
                Scene(
                    title=(
                        f"{label}: {p['log'].name} track {p['track_id'][i]} at t0 = {p['t0_ns'][i] / 1e9:.1f} s "
                        f"(error at 5 s {err5[i]:.2f} m)"
                    ),
                    inputs=p["inputs"][i],
                    present=p["present"][i],
                    future=p["future"][i],
                    offsets=p["offsets"][i],
                    maneuver=p["maneuver_pred"][i],
                    alternatives=cand,
                    alt_probs=p["alt_probs"][i] if p["candidates"] is not None else np.full(1, np.nan),
                    probs=p["probs"][i] if np.isfinite(p["probs"][i]).all() else None,
                    kind=kind,
                )
            )
        if len(scenes) >= count:
            break
    return scenes[:count]


def write(
    directory: Path,
    metrics: dict[str, Any],
    meta: dict[str, Any],
    scenes: list[Scene],
    *,
    title: str = "lanecast report of annotated logs",
    links: list[tuple[str, str]] | None = None,
) -> Path:
    """metrics.json, report.md and report.html in ``directory``; returns the HTML's path."""
    directory.mkdir(parents=True, exist_ok=True)
    write_metrics(directory / "metrics.json", metrics, meta)
    _, html = write_report(directory, metrics, meta, scenes, title=title, links=links or [])
    return html


def per_log_names(logs: list[Path]) -> dict[Path, str]:
    """A folder name per log for its own report: its path below the logs' common folder, without the
    suffix (``day1/drive``, ``day2/drive``), so that two logs of the same name never share one."""
    root = Path(os.path.commonpath([str(p.absolute().parent) for p in logs]))
    rel = {p: p.absolute().relative_to(root) for p in logs}
    return {p: (r.with_suffix("") if p.is_file() else r).as_posix() for p, r in rel.items()}


def report_logs(
    paths: list[Path], out: Path, *, topic: str | None = None, examples: int = 4, force: bool = False
) -> int:
    """Score every annotated log in ``paths`` and write the reports into ``out``; print a summary.

    Returns 0, or 1 when some log could not be scored (it is named; the others are reported). The
    files appear in ``out`` all at once at the end: an interrupted run leaves none of them.
    """
    with staged_files(out, force=force) as stage:
        status, html = _write_reports(paths, stage, topic, examples)
    print(f"report: {out / html.relative_to(stage)}")
    return status


def _write_reports(paths: list[Path], out: Path, topic: str | None, examples: int) -> tuple[int, Path]:
    """:func:`report_logs` into the directory ``out``: (status, the overall report.html)."""
    logs = annotated_logs(paths)
    names = per_log_names(logs)
    parts: list[dict[str, Any]] = []
    failed: list[str] = []
    links: list[tuple[str, str]] = []
    for log in progress(logs, desc="report", total=len(logs), unit="log"):
        try:
            with activity(f"report: {log.name}: reading its tracks and forecasts, scoring"):
                part = score_log(log, topic)
        except InputError as exc:
            if len(logs) == 1:  # the one log's own error, with its place, is the command's
                raise
            failed.append(f"{log}: {exc}")
            continue
        if len(part["future"]) == 0:
            failed.append(f"{log}: no forecast has its 5 s future in the log")
            continue
        parts.append(part)
        meta = {
            "log": str(log),
            **part["model"],
            "forecasts": part["n_forecasts"],
            "scored": len(part["future"]),
            "always_straight": always_straight_of([part]),
        }
        with activity(f"report: {log.name}: writing its page"):
            page = write(
                out / "logs" / names[log],
                metrics_of([part]),
                meta,
                example_scenes([part], examples),
                title=f"lanecast report: {log.name}",
                links=[("all logs", os.path.relpath(out / "report.html", out / "logs" / names[log]))],
            )
        links.append(
            (f"{log.name}: {len(part['future']):,} forecasts scored", page.relative_to(out).as_posix())
        )
    for line in failed:
        print(f"skipped {line}")
    if not parts:
        raise InputError(paths[0], "no log could be scored", expected="annotated logs with recorded futures")
    with activity("report: the metrics of all logs, with their intervals"):
        metrics = metrics_of(parts)
    models = {json.dumps(p["model"], sort_keys=True) for p in parts if p["model"]}
    meta = {
        "logs": len(parts),
        "logs_not_scored": failed or None,  # named in the report, not only on the terminal
        **(json.loads(models.pop()) if len(models) == 1 else {}),
        "forecasts_scored": int(sum(len(p["future"]) for p in parts)),
        "forecasts_in_logs": int(sum(p["n_forecasts"] for p in parts)),
        "ground_truth": "each target's recorded position at t0 + 1..5 s, in its window frame",
        "always_straight": always_straight_of(parts),
    }
    with activity("report: writing the page of all logs"):
        html = write(out, metrics, meta, example_scenes(parts, examples), links=links)
    m = metrics["stcnn"]
    rmse = " ".join(f"{v:.2f}" if v is not None else "-" for v in m["rmse"])
    cv = " ".join(f"{v:.2f}" if v is not None else "-" for v in metrics["cv"]["rmse"])
    n_logs = f"{len(parts)} log" + ("s" if len(parts) > 1 else "")
    print(
        f"scored {meta['forecasts_scored']:,} of {meta['forecasts_in_logs']:,} forecasts in {n_logs} "
        "(those whose 5 s future is in the log)"
    )
    print(f"  RMSE 1-5 s (m): forecasts {rmse} | constant velocity {cv}")
    if meta.get("model"):
        print(
            f"  forecasts by model: {meta['model']} (sha256 {meta['model_sha256'][:12]}), trained on {meta['model_trained_on']}"
        )
    band_note = speed_band_note(metrics)
    if band_note is not None:
        print(f"  by target speed, the forecasts: {band_note}")
    report_not_scored(failed)
    return 1 if failed else 0, html
