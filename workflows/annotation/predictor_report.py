"""The report of the predictors recorded in drive logs: the library behind ``lanecast report --predictions``.

Per log, every recorded predictor (:mod:`lanecast.workflows.annotation.recorded_predictions`) is
matched to the log's own future (:mod:`lanecast.workflows.annotation.predictor_scores`) and
lanecast's ST-CNN and constant velocity forecast the same objects at the same times; over all logs
each predictor's rows are pooled. ``metrics.json``, ``report.md`` and ``report.html`` lead with the
answer (its RMSE at 5 s, as a multiple of constant velocity's, on how many objects), then the
matching (what could not be scored and why, the stamp offset), the metrics side by side, and rows
per object class and speed band. This module is not a command: it has no ``register``.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import staged_files
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.ownership import GENERATOR, HTML_MARK, MARKDOWN_MARK
from lanecast.io_adapters.progress import activity, progress
from lanecast.models.predictor_metrics import predictor_summary
from lanecast.models.runtime import load_forecaster
from lanecast.workflows.annotation.log_scores import annotated_logs, per_log_names, report_not_scored
from lanecast.workflows.annotation.predictor_scores import (
    NO_WINDOW,
    Scored,
    add_lanecast,
    pooled,
    score_predictor,
)
from lanecast.workflows.annotation.recorded_predictions import read_predictions

RECORDED = "recorded"
ALL_MATCHED = "recorded_all_matched"
NAMES = {
    RECORDED: "recorded predictor",
    "stcnn": "lanecast ST-CNN",
    "cv": "constant velocity",
    ALL_MATCHED: "recorded predictor, every matched prediction (lanecast's too short ones too)",
}


def predictor_metrics(parts: list[Scored], boots: int = 1000) -> dict[str, Any]:
    """The matching counts and the metrics of one predictor over ``parts`` (its logs), beside lanecast's."""
    data = pooled(parts)
    common = {"object_class": data["object_class"], "speed": data["speed"], "boots": boots}
    metrics = {RECORDED: predictor_summary(data["candidates"], data["confidence"], data["true"], **common)}
    for name, fc in data["lanecast"].items():
        metrics[name] = predictor_summary(fc["candidates"], fc["confidence"], fc["true"], **common)
    every = data["all_matched"]
    if every["true"].shape[0] > data["true"].shape[0]:  # rows lanecast could not forecast
        metrics[ALL_MATCHED] = predictor_summary(
            every["candidates"],
            every["confidence"],
            every["true"],
            object_class=every["object_class"],
            speed=every["speed"],
            boots=boots,
        )
    unmatched: dict[str, int] = {}
    refused: dict[str, int] = {}
    for p in parts:
        for reason, n in p.unmatched.items():
            unmatched[reason] = unmatched.get(reason, 0) + n
        for reason, n in p.refused_paths.items():
            refused[reason] = refused.get(reason, 0) + n
    return {
        "objects_predicted": sum(p.n_objects for p in parts),
        "scored": int(data["true"].shape[0]),
        "distinct_objects": len({(i, int(t)) for i, p in enumerate(parts) for t in p.track_id}),
        "unmatched": unmatched,
        "refused_paths": refused,
        "stamp_offset_ms": {p.log or p.recording: p.stamp_offset_ms for p in parts},
        "metrics": metrics,
    }


def headline(topic: str, entry: dict[str, Any]) -> str:
    """One sentence: the predictor's RMSE at 5 s, against constant velocity and the ST-CNN, on N."""
    m = entry["metrics"]
    r5, cv5 = m[RECORDED]["rmse"][-1], m.get("cv", {}).get("rmse", [None])[-1]
    st5 = m.get("stcnn", {}).get("rmse", [None])[-1]
    lost = sum(n for reason, n in entry["unmatched"].items() if reason != NO_WINDOW)
    if r5 is None:
        return f"{topic}: nothing to score ({entry['objects_predicted']} predicted objects, {lost} without a future)"
    ratio = f", {r5 / cv5:.2f}× constant velocity ({cv5:.2f} m)" if cv5 else ""
    stcnn = f", lanecast ST-CNN {st5:.2f} m" if st5 is not None else ""
    return (
        f"{topic}: RMSE@5 s {r5:.2f} m{ratio}{stcnn}, on {entry['scored']:,} predictions of "
        f"{entry['distinct_objects']:,} objects ({entry['objects_predicted']:,} predicted: {lost:,} without a "
        f"future in the log, {entry['unmatched'].get(NO_WINDOW, 0):,} without a lanecast window)"
    )


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3f}"
    return f"{v:,}" if isinstance(v, int) and not isinstance(v, bool) else str(v)


def sections(topic: str, entry: dict[str, Any]) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of the tables of one predictor."""
    m = entry["metrics"]
    names = list(m)
    keys = ("ade", "fde", "min_ade", "min_fde", "k", "miss_rate", "brier", "nll")
    side = [
        [NAMES.get(n, n)]
        + [_fmt(v) for v in m[n]["rmse"]]
        + [f"{_fmt(lo)}–{_fmt(hi)}" for lo, hi in [(m[n]["rmse_ci"]["low"][-1], m[n]["rmse_ci"]["high"][-1])]]
        + [_fmt(m[n][k]) for k in keys]
        for n in names
    ]
    header = ["predictor", *(f"RMSE@{h} s" for h in range(1, 6)), "95 % CI @5 s", *keys]
    matching = [[reason, _fmt(n)] for reason, n in entry["unmatched"].items()]
    matching += [[f"path refused: {reason}", _fmt(n)] for reason, n in entry["refused_paths"].items()]
    matching += [
        [
            f"stamp − nearest tracked sample ({name}), ms",
            f"median {_fmt(o['median'])}, {_fmt(o['min'])}…{_fmt(o['max'])}",
        ]
        for name, o in entry["stamp_offset_ms"].items()
    ]
    by_class = [
        [NAMES.get(n, n), c, _fmt(row["n"]), _fmt((row["rmse"] or [None])[-1])]
        for n in names
        for c, row in m[n]["per_class"].items()
    ]
    by_speed = [
        [NAMES.get(n, n), band, _fmt(row["n_windows"]), _fmt((row["rmse"] or [None])[-1])]
        for n in names
        for band, row in m[n]["per_speed_band"].items()
    ]
    return [
        (
            f"{topic}: side by side on the same {entry['scored']} predictions (m; the last row: n = {m[names[-1]]['n']})"
            if ALL_MATCHED in m
            else f"{topic}: side by side on the same {entry['scored']} predictions (m)",
            header,
            side,
        ),
        (f"{topic}: predictions not scored, and why", ["reason", "count"], matching),
        (f"{topic}: by object class", ["predictor", "class", "n", "RMSE@5 s"], by_class),
        (f"{topic}: by speed at the stamp", ["predictor", "band", "n", "RMSE@5 s"], by_speed),
    ]


def write_documents(directory: Path, report: dict[str, Any], title: str) -> Path:
    """metrics.json, report.md and report.html of ``report``; returns the HTML's path."""
    directory.mkdir(parents=True, exist_ok=True)
    doc = {**report, "generator": GENERATOR}  # lanecast's own: a rerun replaces it
    (directory / "metrics.json").write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    lines = [report[t]["headline"] for t in report["predictor_topics"]]
    tables = [s for t in report["predictor_topics"] for s in sections(t, report[t])]
    if report.get("logs_not_scored"):
        tables.append(("logs not scored", ["log and why"], [[line] for line in report["logs_not_scored"]]))
    md = [MARKDOWN_MARK, f"# {title}", "", *(f"**{line}**" for line in lines), ""]
    page = [f"<h1>{html.escape(title)}</h1>", *(f"<p><b>{html.escape(line)}</b></p>" for line in lines)]
    for name, header, rows in tables:
        md += [f"## {name}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        md += ["| " + " | ".join(r) + " |" for r in rows] + [""]
        cells = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
        page += [f"<h2>{html.escape(name)}</h2>", f"<table><tr>{cells}</tr>{body}</table>"]
    (directory / "report.md").write_text("\n".join(md))
    head = (
        f"<!doctype html><html><head><meta charset='utf-8'>{HTML_MARK}<title>{html.escape(title)}</title>"
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 7px;"
        "text-align:right;font-size:13px}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}"
        "</style></head><body>"
    )
    (directory / "report.html").write_text(head + "\n".join(page) + "\n</body></html>\n")
    return directory / "report.html"


def _report(parts: dict[str, list[Scored]], logs: list[str], boots: int) -> dict[str, Any]:
    out: dict[str, Any] = {"logs": logs, "predictor_topics": sorted(parts)}
    for topic, scored in sorted(parts.items()):
        entry = predictor_metrics(scored, boots)
        entry["headline"] = headline(topic, entry)
        out[topic] = entry
    return out


def report_predictors(
    paths: list[Path],
    out: Path,
    *,
    predictions: list[str],
    topic: str | None = None,
    model: Path | None = None,
    boots: int = 1000,
    force: bool = False,
) -> int:
    """Score the predictors recorded in the logs of ``paths`` (topics ``predictions``, else every
    topic found by schema) and write the report into ``out``, overall and per log; print the answer.
    Returns 0, or 1 when some log could not be scored (named; the others are reported). ``force``:
    replace files of the report's names that lanecast did not write."""
    try:
        logs = annotated_logs(paths)
    except InputError as exc:  # its words are for annotated logs; any drive log may hold a predictor
        if exc.reason != "no annotated logs found":
            raise
        raise InputError(
            paths[0], "no drive logs found", expected="MCAP files, ROS 2 bags or folders of them"
        ) from exc
    names = per_log_names(logs)
    forecaster = load_forecaster(model, quiet=True)
    pooled_parts: dict[str, list[Scored]] = {}
    failed: list[str] = []
    scored_logs, last = 0, {}
    with staged_files(out, force=force) as stage:
        for log in progress(logs, desc="report", total=len(logs), unit="log"):
            try:
                with activity(f"report: {log.name}: reading its tracks"):
                    tracks = registry.read_any([log], topic=topic) if topic else registry.read_any([log])
                    tracks = conv.shifted(tracks, conv.read_offset(tracks))  # on the predictions' clock
                per_log: dict[str, list[Scored]] = {}
                with activity(f"report: {log.name}: scoring its recorded predictions"):
                    for pred in read_predictions(log, predictions, checked=True):
                        scored = score_predictor(pred, tracks)
                        scored.log = names[log]
                        no_window = add_lanecast(scored, tracks, [forecaster])
                        if no_window:
                            scored.unmatched[NO_WINDOW] = no_window
                        per_log[pred.topic] = [scored]
            except InputError as exc:
                if len(logs) == 1:
                    raise
                failed.append(f"{log}: {exc}")
                continue
            for t, s in per_log.items():
                pooled_parts.setdefault(t, []).extend(s)
            last = _report(per_log, [str(log)], boots)
            write_documents(stage / "logs" / names[log], last, f"{log.name}")
            scored_logs += 1
        for line in failed:
            print(f"skipped {line}")
        if not pooled_parts:
            raise InputError(paths[0], "no log could be scored", expected="logs with recorded predictions")
        # one log: its own report is the overall one (the bootstrap is the costly part: not twice)
        report = last if scored_logs == 1 else _report(pooled_parts, [str(p) for p in logs], boots)
        report = {**report, "logs_not_scored": failed}
        page = write_documents(stage, report, "recorded predictors against the future in the logs")
    for t in report["predictor_topics"]:
        print(report[t]["headline"])
    print(f"report: {out / page.relative_to(stage)}")
    report_not_scored(failed)
    return 1 if failed else 0
