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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS, MANEUVERS, ROWS, TARGET_ROW
from lanecast.io_adapters.files import atomic_path

RMSE_CONVENTIONS = (
    "RMSE per window: the square root of the mean over windows of the squared Euclidean error at each "
    "horizon (conv-social-pooling's convention, the paper's tables), in metres. Per vehicle: squared errors "
    "averaged per vehicle first, then over vehicles (PiP's). Lane-change windows: those whose 5 s future "
    "holds a lane change."
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
    probs: np.ndarray | None = None  # float [5, 3] per-step maneuver probabilities (None: not drawn)
    alt_maneuvers: np.ndarray | None = None  # int [K, 5] the alternatives' maneuver sequences
    removed: tuple[int, ...] = ()  # rows removed in a what-if (drawn dashed where they were)
    removed_at: dict[int, tuple[float, float]] = field(default_factory=dict)  # their positions at t0
    kind: str = "example"  # "example" or "failure" (the report's failure gallery)


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
        ax.plot(range(1, len(values) + 1), values, marker="o", label=model_name(name))
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


def hex_colour(rgb: Sequence[float]) -> str:
    """An RGB triple (0–1) as '#rrggbb'."""
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgb)


#: Matplotlib colours of the maneuvers: the windows contract's, as in the Foxglove annotation.
MANEUVER_HEX: tuple[str, ...] = tuple(hex_colour(c) for c in MANEUVER_COLOURS)
TRUTH_COLOUR = "#d62728"  # the ground truth, dashed red as in the paper


def _sequence_words(maneuver: Sequence[int] | np.ndarray) -> str:
    """A maneuver sequence [5] in words, runs collapsed: "straight 1–2 s, left 3–5 s"."""
    parts: list[str] = []
    start = 0
    for step in range(1, len(maneuver) + 1):
        if step == len(maneuver) or maneuver[step] != maneuver[start]:
            span = f"{start + 1} s" if step - start == 1 else f"{start + 1}–{step} s"
            parts.append(f"{MANEUVERS[int(maneuver[start])]} {span}")
            start = step
    return ", ".join(parts)


def scene_plot(scene: Scene) -> bytes:
    """One window drawn like the paper's qualitative figures (x along the road, y to the left, so a
    vehicle on the right is drawn below the target), with the per-step maneuver probabilities below.

    Vehicles at t0 as boxes (target black, neighbours grey, removed ones dashed) with velocity arrows
    (distance covered in 0.5 s), the target's history with a dot per second, the ground truth dashed
    red, the forecast coloured by each step's maneuver with a marker and label per second, the other
    maneuver sequences dotted; every probability is in the legend beside the plot, not on the lines.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

    plt = pyplot()
    with_probs = scene.probs is not None and np.isfinite(scene.probs).all()
    fig = plt.figure(figsize=(11, 4.6 if with_probs else 3.4))
    grid = fig.add_gridspec(2 if with_probs else 1, 1, height_ratios=[3.2, 1.2] if with_probs else [1])
    ax = fig.add_subplot(grid[0])
    x, y, v = scene.inputs[0], scene.inputs[1], scene.inputs[2]
    removed = set(scene.removed)
    for row, label in enumerate(ROWS):
        if not scene.present[row, -1] and row not in removed:
            continue
        target = row == TARGET_ROW
        px, py = (
            (x[row, -1], y[row, -1])
            if scene.present[row, -1]
            else scene.removed_at.get(row, (np.nan, np.nan))
        )
        if not np.isfinite(px):
            continue
        if row in removed:
            ax.add_patch(Rectangle((px - 2.25, py - 0.9), 4.5, 1.8, fill=False, ls="--", ec="grey", zorder=3))
            ax.annotate(f"{label} removed", (px, py + 1.2), ha="center", fontsize=7, color="grey")
            continue
        colour = "black" if target else "grey"
        ax.add_patch(Rectangle((px - 2.25, py - 0.9), 4.5, 1.8, color=colour, alpha=0.85, zorder=3))
        ax.annotate(label, (px, py + 1.2), ha="center", fontsize=7, color=colour, zorder=6)
        if scene.present[row, -2]:
            d = np.array([x[row, -1] - x[row, -2], y[row, -1] - y[row, -2]])
            d = d / max(float(np.hypot(*d)), 1e-6) * v[row, -1] * 0.5
            ax.arrow(
                px, py, d[0], d[1], width=0.15, color="grey", alpha=0.6, length_includes_head=True, zorder=2
            )
    hist = scene.present[TARGET_ROW]
    ax.plot(x[TARGET_ROW, hist], y[TARGET_ROW, hist], color="black", lw=1, alpha=0.5)
    seconds_back = hist & (np.arange(hist.size) % 10 == (hist.size - 1) % 10)
    seconds_back[-1] = False
    ax.plot(x[TARGET_ROW, seconds_back], y[TARGET_ROW, seconds_back], "o", color="black", ms=2.5, alpha=0.6)
    handles: list[Any] = [
        Line2D([], [], color="black", lw=1, alpha=0.5, marker="o", ms=2.5, label="history (dot per second)")
    ]
    if np.isfinite(scene.future).all():
        gt = np.vstack([[0.0, 0.0], scene.future])
        ax.plot(gt[:, 0], gt[:, 1], "--", color=TRUTH_COLOUR, lw=1.5, zorder=4)
        ax.plot(gt[1:, 0], gt[1:, 1], "o", mfc="none", mec=TRUTH_COLOUR, ms=5, zorder=4)
        handles.append(
            Line2D([], [], color=TRUTH_COLOUR, ls="--", marker="o", mfc="none", label="ground truth")
        )
    for k in range(1, len(scene.alternatives)):
        alt = np.vstack([[0.0, 0.0], scene.alternatives[k]])
        words = "" if scene.alt_maneuvers is None else f": {_sequence_words(scene.alt_maneuvers[k])}"
        (line,) = ax.plot(alt[:, 0], alt[:, 1], ls=":", color="#7b5ea7", lw=1.1, alpha=0.8, zorder=4)
        line.set_label(f"alternative {k + 1}, p = {scene.alt_probs[k]:.2f}{words}")
        handles.append(line)
    pred = np.vstack([[0.0, 0.0], scene.offsets])
    for step in range(len(scene.offsets)):
        colour = MANEUVER_HEX[int(scene.maneuver[step])]
        ax.plot(pred[step : step + 2, 0], pred[step : step + 2, 1], color=colour, lw=2.4, zorder=5)
        ax.plot(*pred[step + 1], "o", color=colour, ms=5, zorder=6)
        ax.annotate(
            f"{step + 1} s",
            pred[step + 1],
            xytext=(0, -11),
            textcoords="offset points",
            ha="center",
            fontsize=7,
            color=colour,
            zorder=6,
        )
    top = (
        ""
        if not len(scene.alt_probs) or not np.isfinite(scene.alt_probs[0])
        else f", p = {scene.alt_probs[0]:.2f}"
    )
    handles.append(
        Line2D([], [], color="black", lw=0, label=f"forecast{top}: {_sequence_words(scene.maneuver)}")
    )
    handles += [
        Line2D([], [], color=MANEUVER_HEX[c], lw=2.4, marker="o", ms=4, label=f"  {name}")
        for c, name in enumerate(MANEUVERS)
    ]
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    hist_x = x[TARGET_ROW, scene.present[TARGET_ROW]]
    ahead = float(
        np.nanmax(
            [
                np.nanmax(scene.future[:, 0]) if np.isfinite(scene.future).any() else 0.0,
                scene.alternatives[..., 0].max(),
            ]
        )
    )
    x_lo, x_hi = min(-40.0, float(hist_x.min()) - 8.0), max(40.0, ahead + 20.0)
    near = scene.present & (x >= x_lo) & (x <= x_hi)
    finite_future = scene.future[np.isfinite(scene.future).all(axis=1), 1]
    ys = np.concatenate([y[near], finite_future, scene.alternatives[..., 1].ravel(), [0.0]])
    half = max(7.5, float(np.abs(ys).max()) + 2.5)
    ax.set_xlim(x_lo, x_hi)  # the target's history and future; far neighbours fall outside
    ax.set_ylim(-half, half)  # lanes stay visible: the y scale is stretched against x, as in the paper
    ax.set_xlabel("x (m, along the road; the target at t0 at 0)")
    ax.set_ylabel("y (m, + = left)")
    ax.set_title(scene.title, fontsize=9, loc="left")
    ax.grid(alpha=0.2)
    if with_probs:
        assert scene.probs is not None
        bars = fig.add_subplot(grid[1])
        steps = np.arange(1, len(scene.probs) + 1)
        bottom = np.zeros(len(steps))
        for c, name in enumerate(MANEUVERS):
            bars.bar(steps, scene.probs[:, c], bottom=bottom, color=MANEUVER_HEX[c], width=0.6, label=name)
            for step, p in zip(steps.tolist(), scene.probs[:, c].tolist(), strict=True):
                if p >= 0.12:
                    bars.text(
                        step,
                        bottom[step - 1] + p / 2,
                        f"{p:.2f}",
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="white",
                    )
            bottom += scene.probs[:, c]
        bars.set_xticks(steps, [f"{s} s" for s in steps])
        bars.set_xlim(0.4, len(steps) + 0.6)
        bars.set_ylim(0, 1)
        bars.set_ylabel("maneuver\nprobability", fontsize=8)
        bars.legend(
            handles=[Patch(color=MANEUVER_HEX[c], label=n) for c, n in enumerate(MANEUVERS)],
            fontsize=7,
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            frameon=False,
        )
    fig.tight_layout()
    return png_bytes(fig)


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


#: Model names in words, by metrics.json key.
MODEL_NAMES = {
    "stcnn": "ST-CNN (maneuver-based)",
    "stcnn_regression_only": "ST-CNN, regression only",
    "cv": "constant velocity",
    "ca": "constant acceleration",
}
MACRO_F1_NOTE = (
    "Maneuver figures count each of the 5 future steps. Macro-F1 is the mean F1 over the classes "
    "present in the ground truth or predicted: a lane change predicted where there is none counts with "
    "F1 = 0, and a class neither present nor predicted is left out. Always straight is the reference a "
    "classifier must beat. Brier score: mean over steps of the squared distance between the probabilities "
    "and the one-hot truth (0 is perfect, lower is better). Kinematic baselines predict no maneuver (–)."
)
MISS_NOTE = "Miss rate: share of windows whose error at 5 s exceeds 2 m (Argoverse 2's definition)."


def model_name(key: str) -> str:
    """A model's name in words (its metrics.json key when lanecast does not know it)."""
    return MODEL_NAMES.get(key, key)


def _ci(ci: dict[str, Any] | None, h: int) -> str:
    if not ci or ci["low"][h] is None:
        return ""
    return f" [{ci['low'][h]:.2f}, {ci['high'][h]:.2f}]"


def metric_rows(metrics: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Header and one row per model of the trajectory table (RMSE per window, 95 % intervals at 5 s)."""
    header = [
        "model",
        "windows",
        "RMSE 1 s",
        "2 s",
        "3 s",
        "4 s",
        "5 s [95 % CI]",
        "ADE",
        "FDE",
        "miss rate",
        "minADE / minFDE @K",
        "RMSE 5 s, lane-change windows [95 % CI]",
        "RMSE 5 s per vehicle",
    ]
    rows = []
    for name, m in metrics.items():
        rows.append(
            [
                model_name(name),
                f"{m['n_windows']:,}",
                *(_fmt(v) for v in m["rmse"][:-1]),
                _fmt(m["rmse"][-1]) + _ci(m.get("rmse_ci"), -1),
                _fmt(m["ade"]),
                _fmt(m["fde"]),
                _pct(m.get("miss_rate")),
                f"{_fmt(m['min_ade'])} / {_fmt(m['min_fde'])} (K={m['k']})",
                _fmt(m["rmse_lane_change"][-1]) + _ci(m.get("rmse_lane_change_ci"), -1),
                _fmt(m["rmse_per_vehicle"][-1]),
            ]
        )
    return header, rows


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def lane_change_rows(metrics: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """RMSE by horizon on the lane-change windows alone, with 95 % bootstrap intervals."""
    header = ["model", "lane-change windows", *(f"{h} s" for h in range(1, 6))]
    rows = [
        [
            model_name(name),
            f"{m['n_lane_change_windows']:,}",
            *(_fmt(m["rmse_lane_change"][h]) + _ci(m.get("rmse_lane_change_ci"), h) for h in range(5)),
        ]
        for name, m in metrics.items()
    ]
    return header, rows


def maneuver_rows(metrics: dict[str, Any], meta: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Per classifying model, and always straight: accuracy, macro-F1, Brier, F1 per class (support)."""
    header = [
        "model",
        "accuracy",
        "macro-F1",
        "Brier",
        *(f"F1 {c}" for c in MANEUVERS),
        "predicted steps (s / l / r)",
    ]
    rows = []
    support: list[int] | None = None
    for name, m in metrics.items():
        if m.get("confusion") is None:
            continue
        support = m.get("support")
        rows.append(
            [
                model_name(name),
                _fmt(m["maneuver_accuracy"], 3),
                _fmt(m["maneuver_macro_f1"], 3),
                _fmt(m.get("brier"), 3),
                *(_fmt(f, 3) for f in (m.get("f1") or [None] * 3)),
                " / ".join(f"{n:,}" for n in (m.get("predicted") or [])),
            ]
        )
    straight = meta.get("always_straight")
    if straight:
        f1_straight: list[float | None] = [None] * 3
        if support and sum(support):
            f1_straight[0] = 2 * support[0] / (2 * support[0] + sum(support[1:]))
        rows.append(
            [
                "always straight (reference)",
                _fmt(straight["maneuver_accuracy"], 3),
                _fmt(straight["maneuver_macro_f1"], 3),
                "–",
                *(_fmt(f, 3) for f in f1_straight),
                f"{sum(support or []):,} / 0 / 0",
            ]
        )
    if support:
        rows.append(["true steps (support)", "", "", "", *(f"{n:,}" for n in support), ""])
    return header, rows


def recording_rows(metrics: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """One row per recording (or log): the ST-CNN beside constant velocity."""
    header = [
        "recording",
        "windows",
        "lane-change windows",
        "RMSE 5 s",
        "RMSE 5 s constant velocity",
        "RMSE 5 s lane-change windows",
        "miss rate",
        "accuracy (always straight)",
        "macro-F1",
    ]
    main = metrics.get("stcnn") or next(iter(metrics.values()))
    cv = (metrics.get("cv") or {}).get("per_recording") or {}
    rows = []
    for rec, r in (main.get("per_recording") or {}).items():
        rows.append(
            [
                rec,
                f"{r['n_windows']:,}",
                f"{r['n_lane_change_windows']:,}",
                _fmt(r["rmse"][-1]),
                _fmt((cv.get(rec) or {}).get("rmse", [None] * 5)[-1]),
                _fmt(r["rmse_lane_change"][-1]),
                _pct(r["miss_rate"]),
                f"{_fmt(r['maneuver_accuracy'], 3)} ({_fmt(r['always_straight_accuracy'], 3)})",
                _fmt(r["maneuver_macro_f1"], 3),
            ]
        )
    return header, rows


def reliability_plot(metrics: dict[str, Any]) -> bytes | None:
    """Calibration of the per-step probabilities (one-vs-rest per class) of the first classifying model."""
    name, rel = next(
        ((n, m["reliability"]) for n, m in metrics.items() if m.get("reliability")), (None, None)
    )
    if rel is None:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 4.0))
    ax.plot([0, 1], [0, 1], color="#bbbbbb", lw=1, ls="--", label="calibrated")
    for c, cls in enumerate(MANEUVERS):
        conf = np.array([np.nan if v is None else v for v in rel["confidence"][c]])
        freq = np.array([np.nan if v is None else v for v in rel["frequency"][c]])
        count = np.asarray(rel["count"][c], np.float64)
        ok = np.isfinite(conf) & np.isfinite(freq)
        ax.plot(conf[ok], freq[ok], color=MANEUVER_HEX[c], lw=1.5, label=cls)
        ax.scatter(
            conf[ok],
            freq[ok],
            s=8 + 40 * np.sqrt(count[ok] / max(count.max(), 1)),
            color=MANEUVER_HEX[c],
            zorder=3,
        )
    ax.set_xlabel("predicted probability of the class (bin mean)")
    ax.set_ylabel("observed frequency of the class")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(f"{model_name(str(name))}: reliability per class (dot size ~ steps)", fontsize=9)
    return png_bytes(fig)


def _plain(value: Any) -> str:
    """A meta value in words: lists joined, mappings as "key value" pairs, None as –."""
    if value is None:
        return "–"
    if isinstance(value, dict):
        return "; ".join(f"{k.replace('_', ' ')} {_plain(v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return ", ".join(_plain(v) for v in value)
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:,}"
    return str(value)


def meta_items(meta: dict[str, Any]) -> list[tuple[str, str]]:
    """What was evaluated, as (label, text) pairs for the report's header (no raw JSON)."""
    labels = {
        "windows": "windows dataset",
        "split": "split",
        "model": "model",
        "regression_only_model": "regression-only model",
        "top_k": "alternatives per forecast (K)",
        "always_straight": "always straight",
        "out_of_distribution": "out of distribution",
    }
    items: list[tuple[str, str]] = []
    for key, value in meta.items():
        if value is None:
            continue
        if key == "sources" and isinstance(value, dict):
            recs = value.get("recordings") or {}
            files = value.get("inputs") or value.get("source_files") or []
            text = f"{len(recs)} recording(s): {', '.join(recs)}" if recs else ""
            text += f" from {_plain(files)}" if files else ""
            items.append(("sources", text or _plain(value)))
        elif key == "always_straight" and isinstance(value, dict):
            items.append(
                (
                    "always straight",
                    f"accuracy {value['maneuver_accuracy']:.3f}, macro-F1 {value['maneuver_macro_f1']:.3f}",
                )
            )
        else:
            items.append((labels.get(key, key.replace("_", " ")), _plain(value)))
    return items


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
    items = meta_items(meta)

    md = [f"# {title}", ""]
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
        tmp.write_text("\n".join(md))

    esc = html.escape
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 7px;"
        "text-align:right;font-size:13px}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}"
        "dl{display:grid;grid-template-columns:max-content auto;gap:2px 12px}dt{font-weight:bold}dd{margin:0}"
        "p.note{font-size:13px;color:#444}img{max-width:100%}</style></head><body>",
        f"<h1>{esc(title)}</h1><dl>",
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
        tmp.write_text("".join(parts))
    return md_path, html_path
