"""The plots of the evaluation report: RMSE by horizon, maneuver confusion, reliability.

matplotlib (Agg backend, imported on first use by :func:`pyplot` so that ``lanecast --help`` stays
fast); every plot returns PNG bytes (:func:`png_bytes`), which ``report.md`` links and
``report.html`` embeds.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS, MANEUVERS
from lanecast.io_adapters.ownership import PNG_METADATA
from lanecast.models.reports.tables import model_name


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend. Its import's warnings that HOME has no writable
    config directory (HOME unset or read-only: a container, a batch job), so that it uses a
    temporary one, are not shown: the plots are the same, and the advice is for matplotlib users."""
    log = logging.getLogger("matplotlib")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    finally:
        log.setLevel(level)
    return plt


def png_bytes(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight", metadata=PNG_METADATA)
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
