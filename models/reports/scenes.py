"""Example scenes of the evaluation report, drawn like the paper's figures.

The target (black) and its neighbours (grey) at t0 with velocity arrows (length = distance covered
in 0.5 s), the history of the target, the ground truth dashed red, and the forecast coloured by
maneuver per step (straight black, left blue, right orange: the windows contract's colours), with
the other top-K sequences thin and labelled by probability; what-if scenes draw removed
neighbours dashed where they were.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVERS, ROWS, TARGET_ROW
from lanecast.models.reports.plots import MANEUVER_HEX, TRUTH_COLOUR, png_bytes, pyplot


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
    plt = pyplot()  # first: matplotlib imported as pyplot() does
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

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
