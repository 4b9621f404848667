"""Evaluation reports: ``report.md`` (with PNG files beside it) and a self-contained ``report.html``.

:func:`write_report` lays out the tables (:mod:`lanecast.models.reports.tables`), the plots — RMSE by
horizon per model, the ST-CNN's maneuver confusion matrix, reliability
(:mod:`lanecast.models.reports.plots`) — and example scenes drawn like the paper's figures
(:mod:`lanecast.models.reports.scenes`) in both documents; what other modules use of those is
re-exported here (``__all__``).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.ownership import HTML_MARK, MARKDOWN_MARK
from lanecast.models.reports.plots import (
    MANEUVER_HEX,
    confusion_plot,
    hex_colour,
    png_bytes,
    pyplot,
    reliability_plot,
    rmse_plot,
)
from lanecast.models.reports.scenes import Scene, scene_plot
from lanecast.models.reports.tables import (
    MISS_NOTE,
    headline,
    lane_change_rows,
    maneuver_rows,
    meta_items,
    metric_rows,
    model_name,
    recording_rows,
    speed_band_rows,
)

__all__ = [
    "MANEUVER_HEX",
    "RMSE_CONVENTIONS",
    "Scene",
    "hex_colour",
    "png_bytes",
    "pyplot",
    "scene_plot",
    "write_report",
]

RMSE_CONVENTIONS = (
    "RMSE per window: the square root of the mean over windows of the squared Euclidean error at each "
    "horizon (conv-social-pooling's convention, the paper's tables), in metres. Per vehicle: squared errors "
    "averaged per vehicle first, then over vehicles (PiP's). Lane-change windows: those whose 5 s future "
    "holds a lane change."
)


MACRO_F1_NOTE = (
    "Maneuver figures count each of the 5 future steps. Macro-F1 is the mean F1 over the classes "
    "present in the ground truth or predicted: a lane change predicted where there is none counts with "
    "F1 = 0, and a class neither present nor predicted is left out. Always straight is the reference a "
    "classifier must beat. Brier score: mean over steps of the squared distance between the probabilities "
    "and the one-hot truth (0 is perfect, lower is better). Kinematic baselines predict no maneuver (–)."
)

SPEED_BAND_NOTE = (
    "RMSE per window by the target's speed at t0 (m/s), the ST-CNN beside constant velocity; a ratio "
    "above 1 marks traffic where the model is worse than constant velocity on these data."
)


def write_report(
    directory: Path,
    metrics: dict[str, Any],
    meta: dict[str, Any],
    scenes: Sequence[Scene] = (),
    *,
    title: str = "lanecast evaluation",
    links: Sequence[tuple[str, str]] = (),
) -> tuple[Path, Path]:
    """Write report.md (+ PNGs) and self-contained report.html into ``directory``; return their paths.

    ``metrics``: model name → ``lanecast.models.metrics.summary`` dict; ``meta``: what was evaluated
    (shown in words); ``links``: (text, relative href) pairs listed near the top (e.g. one page per log).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    images: list[tuple[str, str, bytes, str]] = [
        ("rmse_by_horizon.png", "RMSE by horizon", rmse_plot(metrics), "plot")
    ]
    for name, m in metrics.items():
        if m.get("confusion") is not None:
            images.append(
                (
                    f"confusion_{name}.png",
                    f"Maneuver confusion ({model_name(name)}, per future step)",
                    confusion_plot(m["confusion"], f"{model_name(name)}: maneuvers per future step"),
                    "plot",
                )
            )
    reliability = reliability_plot(metrics)
    if reliability is not None:
        images.append(("reliability.png", "Calibration of the maneuver probabilities", reliability, "plot"))
    for i, scene in enumerate(scenes):
        images.append((f"scene_{i + 1}.png", scene.title, scene_plot(scene), scene.kind))
    for fname, _, data, _ in images:
        with atomic_path(directory / fname) as tmp:
            tmp.write_bytes(data)

    tables = [
        ("Trajectories", *metric_rows(metrics), [RMSE_CONVENTIONS, MISS_NOTE]),
        (
            "Lane-change windows",
            *lane_change_rows(metrics),
            ["95 % intervals: bootstrap over windows (seeded)."],
        ),
        ("Maneuvers", *maneuver_rows(metrics, meta), [MACRO_F1_NOTE]),
    ]
    per_rec = recording_rows(metrics)
    if len(per_rec[1]) > 1:
        tables.append(("Per recording", *per_rec, ["Accuracy with always straight's in brackets."]))
    by_speed = speed_band_rows(metrics)
    if by_speed[1]:
        tables.append(("By target speed", *by_speed, [SPEED_BAND_NOTE]))
    items = meta_items(meta)

    answer = headline(metrics)
    md = [f"# {title}", "", *(f"**{line}**" for line in answer), ""]
    md += [f"- {label}: {text}" for label, text in items]
    md += [f"- [{text}]({href})" for text, href in links]
    for heading, header, rows, notes in tables:
        md += ["", f"## {heading}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        md += ["| " + " | ".join(r) + " |" for r in rows]
        md += ["", *notes]
    md.append("")
    for section, kind in (("Plots", "plot"), ("Examples", "example"), ("Failure gallery", "failure")):
        chosen = [(f, t) for f, t, _, k in images if k == kind]
        if chosen:
            md += [f"## {section}", ""]
            for fname, caption in chosen:
                md += [f"### {caption}", "", f"![{caption}]({fname})", ""]
    md_path = directory / "report.md"
    with atomic_path(md_path) as tmp:
        tmp.write_text("\n".join([MARKDOWN_MARK, *md]), encoding="utf-8")

    esc = html.escape
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'>{HTML_MARK}<title>{esc(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 7px;"
        "text-align:right;font-size:13px}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}"
        "dl{display:grid;grid-template-columns:max-content auto;gap:2px 12px}dt{font-weight:bold}dd{margin:0}"
        "p.note{font-size:13px;color:#444}img{max-width:100%}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
        *(f"<p style='font-size:1.15em'><b>{esc(line)}</b></p>" for line in answer),
        "<dl>",
        *(f"<dt>{esc(label)}</dt><dd>{esc(text)}</dd>" for label, text in items),
        "</dl>",
    ]
    if links:
        parts.append(
            "<ul>"
            + "".join(f"<li><a href='{esc(href)}'>{esc(text)}</a></li>" for text, href in links)
            + "</ul>"
        )
    for heading, header, rows, notes in tables:
        parts += [f"<h2>{esc(heading)}</h2><table><tr>", *(f"<th>{esc(h)}</th>" for h in header), "</tr>"]
        parts += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows]
        parts += ["</table>", *(f"<p class='note'>{esc(n)}</p>" for n in notes)]
    for section, kind in (("Plots", "plot"), ("Examples", "example"), ("Failure gallery", "failure")):
        shown = [(t, d) for _, t, d, k in images if k == kind]
        if not shown:
            continue
        parts.append(f"<h2>{esc(section)}</h2>")
        if kind == "failure":
            parts.append(
                "<p class='note'>The largest errors at 5 s, false lane changes (predicted where the future is "
                "straight) and missed ones, one scene per vehicle.</p>"
            )
        for caption, data in shown:
            parts.append(
                f"<h3>{esc(caption)}</h3><img alt='{esc(caption)}' src='data:image/png;base64,"
                f"{base64.b64encode(data).decode()}'>"
            )
    parts.append("</body></html>")
    html_path = directory / "report.html"
    with atomic_path(html_path) as tmp:
        tmp.write_text("".join(parts), encoding="utf-8")
    return md_path, html_path
