"""Evaluation reports: ``report.md`` (with PNG files beside it) and a self-contained ``report.html``.

Plots (matplotlib, Agg backend): RMSE by horizon per model, the ST-CNN's maneuver confusion matrix,
and example scenes drawn like the paper's figures: the target (black) and its neighbours (grey) at
t0 with velocity arrows (length = distance covered in 0.5 s), the history of the target, the ground
truth dashed red, and the forecast coloured by maneuver per step (straight black, left blue, right
orange), with the other top-K sequences thin and labelled by probability.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVERS, ROWS, TARGET_ROW
from lanecast.io_adapters.files import atomic_path

MANEUVER_COLOURS = ("black", "tab:blue", "tab:orange")
RMSE_CONVENTIONS = (
    "`rmse`: per window, sqrt(mean over windows of the squared Euclidean error at each horizon) "
    "(conv-social-pooling convention, the paper's tables); `rmse_per_vehicle`: squared errors "
    "averaged per vehicle first, then over vehicles (PiP); `rmse_lane_change`: per window, over "
    "windows whose 5 s future holds a lane change only."
)


@dataclass
class Scene:
    """One example window to draw (window frame, metres)."""

    title: str
    inputs: np.ndarray  # float32 [4, 8, 30] physical
    present: np.ndarray  # bool [8, 30]
    future: np.ndarray  # float32 [5, 2] ground truth
    offsets: np.ndarray  # float32 [5, 2] forecast (argmax maneuvers)
    maneuver: np.ndarray  # int [5] predicted per-step maneuver
    alternatives: np.ndarray  # float32 [K, 5, 2]
    alt_probs: np.ndarray  # float [K]


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png_bytes(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return buf.getvalue()


def rmse_plot(metrics: dict[str, Any]) -> bytes:
    """RMSE (per window) against the horizon for every model in ``metrics``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for name, m in metrics.items():
        values = [np.nan if v is None else v for v in m["rmse"]]
        ax.plot(range(1, len(values) + 1), values, marker="o", label=name)
    ax.set_xlabel("horizon (s)")
    ax.set_ylabel("RMSE per window (m)")
    ax.set_xticks(range(1, 6))
    ax.grid(alpha=0.3)
    ax.legend()
    return png_bytes(fig)


def confusion_plot(confusion: Sequence[Sequence[int]], title: str) -> bytes:
    """Confusion matrix (rows true, columns predicted), counts and row-normalised shading."""
    plt = pyplot()
    conf = np.asarray(confusion, dtype=np.float64)
    rows = conf / np.maximum(conf.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(4.2, 3.6))
    ax.imshow(rows, cmap="Blues", vmin=0, vmax=1)
    for i in range(conf.shape[0]):
        for j in range(conf.shape[1]):
            ax.text(
                j,
                i,
                f"{int(conf[i, j]):,}\n{rows[i, j]:.0%}",
                ha="center",
                va="center",
                color="white" if rows[i, j] > 0.5 else "black",
                fontsize=8,
            )
    ax.set_xticks(range(3), MANEUVERS)
    ax.set_yticks(range(3), MANEUVERS)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    return png_bytes(fig)


def scene_plot(scene: Scene) -> bytes:
    """One window drawn like the paper's qualitative figures (x forward, y left)."""
    from matplotlib.patches import Rectangle

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 3.2))
    x, y, v = scene.inputs[0], scene.inputs[1], scene.inputs[2]
    for row, label in enumerate(ROWS):
        if not scene.present[row, -1]:
            continue
        target = row == TARGET_ROW
        colour = "black" if target else "grey"
        ax.add_patch(
            Rectangle((x[row, -1] - 2.25, y[row, -1] - 0.9), 4.5, 1.8, color=colour, alpha=0.8, zorder=3)
        )
        ax.annotate(label, (x[row, -1], y[row, -1] + 1.2), ha="center", fontsize=7, color=colour)
        if scene.present[row, -2]:
            d = np.array([x[row, -1] - x[row, -2], y[row, -1] - y[row, -2]])
            d = d / max(float(np.hypot(*d)), 1e-6) * v[row, -1] * 0.5
            ax.arrow(
                x[row, -1],
                y[row, -1],
                d[0],
                d[1],
                width=0.15,
                color="grey",
                alpha=0.6,
                length_includes_head=True,
                zorder=2,
            )
    hist = scene.present[TARGET_ROW]
    ax.plot(x[TARGET_ROW, hist], y[TARGET_ROW, hist], color="black", lw=1, alpha=0.5)
    gt = np.vstack([[0.0, 0.0], scene.future])
    ax.plot(gt[:, 0], gt[:, 1], "--", color="red", lw=1.5, label="ground truth", zorder=4)
    for k in range(1, len(scene.alternatives)):
        alt = np.vstack([[0.0, 0.0], scene.alternatives[k]])
        ax.plot(alt[:, 0], alt[:, 1], color="purple", lw=0.8, alpha=0.5, zorder=4)
        ax.annotate(
            f"p={scene.alt_probs[k]:.2f}",
            alt[-1],
            xytext=(3, 6 * k - 9),
            textcoords="offset points",
            fontsize=7,
            color="purple",
        )
    pred = np.vstack([[0.0, 0.0], scene.offsets])
    for step in range(len(scene.offsets)):
        ax.plot(
            pred[step : step + 2, 0],
            pred[step : step + 2, 1],
            color=MANEUVER_COLOURS[int(scene.maneuver[step])],
            lw=2.2,
            zorder=5,
            label=f"forecast: {MANEUVERS[int(scene.maneuver[step])]}",
        )
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax.legend(unique.values(), unique.keys(), fontsize=7, loc="upper left")
    hist_x = x[TARGET_ROW, scene.present[TARGET_ROW]]
    ahead = float(max(scene.future[:, 0].max(), scene.alternatives[..., 0].max()))
    x_lo, x_hi = min(-40.0, float(hist_x.min()) - 5.0), max(40.0, ahead + 20.0)
    near = scene.present & (x >= x_lo) & (x <= x_hi)
    ys = np.concatenate([y[near], scene.future[:, 1], scene.alternatives[..., 1].ravel()])
    half = max(7.5, float(np.abs(ys).max()) + 2.5)
    ax.set_xlim(x_lo, x_hi)  # the target's history and future; far neighbours fall outside
    ax.set_ylim(-half, half)  # lanes stay visible: the y scale is stretched against x, as in the paper
    ax.set_xlabel("x (m, along the road at t0)")
    ax.set_ylabel("y (m, left)")
    ax.set_title(scene.title, fontsize=9)
    ax.grid(alpha=0.2)
    return png_bytes(fig)


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def metric_rows(metrics: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Header and one row per model of the main table."""
    header = [
        "model",
        "windows",
        "RMSE 1 s",
        "2 s",
        "3 s",
        "4 s",
        "5 s",
        "ADE",
        "FDE",
        "minADE@K",
        "minFDE@K",
        "RMSE@5 s lane chg.",
        "RMSE@5 s per vehicle",
        "maneuver acc.",
        "macro-F1",
    ]
    rows = []
    for name, m in metrics.items():
        rows.append(
            [
                name,
                f"{m['n_windows']:,}",
                *(_fmt(v) for v in m["rmse"]),
                _fmt(m["ade"]),
                _fmt(m["fde"]),
                f"{_fmt(m['min_ade'])} (K={m['k']})",
                _fmt(m["min_fde"]),
                _fmt(m["rmse_lane_change"][-1]),
                _fmt(m["rmse_per_vehicle"][-1]),
                _fmt(m["maneuver_accuracy"], 3),
                _fmt(m["maneuver_macro_f1"], 3),
            ]
        )
    return header, rows


def write_report(
    directory: Path, metrics: dict[str, Any], meta: dict[str, Any], scenes: Sequence[Scene] = ()
) -> tuple[Path, Path]:
    """Write report.md (+ PNGs) and self-contained report.html into ``directory``; return their paths.

    ``metrics``: model name → ``lanecast.models.metrics.summary`` dict; ``meta``: what was evaluated (shown).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    images: list[tuple[str, str, bytes]] = [("rmse_by_horizon.png", "RMSE by horizon", rmse_plot(metrics))]
    for name, m in metrics.items():
        if m.get("confusion") is not None:
            images.append(
                (
                    f"confusion_{name}.png",
                    f"Maneuver confusion ({name}, per future step)",
                    confusion_plot(m["confusion"], f"{name}: maneuvers per future step"),
                )
            )
    for i, scene in enumerate(scenes):
        images.append((f"scene_{i + 1}.png", scene.title, scene_plot(scene)))
    for fname, _, data in images:
        with atomic_path(directory / fname) as tmp:
            tmp.write_bytes(data)

    header, rows = metric_rows(metrics)
    md = ["# lanecast evaluation", ""]
    md += [f"- {k}: {v if not isinstance(v, (dict, list)) else json.dumps(v)}" for k, v in meta.items()]
    md += [
        "",
        "## Trajectories and maneuvers",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    md += [
        "",
        RMSE_CONVENTIONS,
        "Errors in metres. Maneuver metrics count each of the 5 future steps; "
        "kinematic baselines predict no maneuver (–).",
        "",
    ]
    md += ["## Per class (straight, left, right)", "", "| model | precision | recall |", "|---|---|---|"]
    for name, m in metrics.items():
        if m.get("precision") is not None:
            md.append(
                f"| {name} | {', '.join(_fmt(v, 3) for v in m['precision'])} | "
                f"{', '.join(_fmt(v, 3) for v in m['recall'])} |"
            )
    md.append("")
    for fname, title, _ in images:
        md += [f"### {title}", "", f"![{title}]({fname})", ""]
    md_path = directory / "report.md"
    with atomic_path(md_path) as tmp:
        tmp.write_text("\n".join(md))

    esc = html.escape
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>lanecast evaluation</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}img{max-width:100%}</style></head><body>",
        "<h1>lanecast evaluation</h1><ul>",
    ]
    parts += [
        f"<li><b>{esc(str(k))}</b>: {esc(v if isinstance(v, str) else json.dumps(v))}</li>"
        for k, v in meta.items()
    ]
    parts += ["</ul><h2>Trajectories and maneuvers</h2><table><tr>"]
    parts += [f"<th>{esc(h)}</th>" for h in header] + ["</tr>"]
    parts += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows]
    parts += [f"</table><p>{esc(RMSE_CONVENTIONS)}</p>"]
    for _, title, data in images:
        parts.append(
            f"<h3>{esc(title)}</h3><img alt='{esc(title)}' src='data:image/png;base64,"
            f"{base64.b64encode(data).decode()}'>"
        )
    parts.append("</body></html>")
    html_path = directory / "report.html"
    with atomic_path(html_path) as tmp:
        tmp.write_text("".join(parts))
    return md_path, html_path
