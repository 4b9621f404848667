"""The ablation's report: the paper's Table II layout (mean ± std over seeds beside the paper) and a plot.

``report.html`` is self-contained (the plot inlined); ``report.md`` and ``ablation.png`` sit beside
it for diffs and slides. Input: the ``ablation.json`` document of ``lanecast.models.ablation``.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.ownership import HTML_MARK, MARKDOWN_MARK
from lanecast.models.reports.document import png_bytes, pyplot

HORIZONS_S = (1, 2, 3, 4, 5)


def _cell(mean: float | None, std: float | None, n_seeds: int) -> str:
    if mean is None or not np.isfinite(mean):
        return "–"
    return f"{mean:.2f} ± {std:.2f}" if n_seeds > 1 and std is not None else f"{mean:.2f}"


def table_rows(result: dict[str, Any]) -> tuple[list[str], list[list[str]], list[list[int]]]:
    """The paper's layout: header (Time + one column per variant), rows (1–5 s, then extra figures),
    and per row the columns holding that row's lowest mean (bold in the report)."""
    variants = result["variants"]
    names = list(variants)
    n = len(result["seeds"])
    header = ["Time", *(variants[v]["label"] for v in names)]
    rows: list[list[str]] = []
    best: list[list[int]] = []

    def add(
        label: str, means: list[float | None], stds: list[float | None], lower_better: bool = True
    ) -> None:
        rows.append([label, *(_cell(m, s, n) for m, s in zip(means, stds, strict=True))])
        finite = [
            (m if lower_better else -m, i) for i, m in enumerate(means) if m is not None and np.isfinite(m)
        ]
        low = min(finite)[0] if finite else None
        best.append([i + 1 for v, i in finite if low is not None and round(v, 2) == round(low, 2)])

    for h in range(len(HORIZONS_S)):
        add(
            f"{HORIZONS_S[h]} s",
            [variants[v]["mean"]["rmse"][h] for v in names],
            [variants[v]["std"]["rmse"][h] for v in names],
        )
    add(
        "5 s, lane-change windows",
        [variants[v]["mean"]["rmse_lane_change"][-1] for v in names],
        [variants[v]["std"]["rmse_lane_change"][-1] for v in names],
    )
    add(
        "miss rate (FDE > 2 m)",
        [variants[v]["mean"]["miss_rate"] for v in names],
        [variants[v]["std"]["miss_rate"] for v in names],
    )
    add(
        "maneuver macro-F1",
        [variants[v]["mean"]["maneuver_macro_f1"] for v in names],
        [variants[v]["std"]["maneuver_macro_f1"] for v in names],
        lower_better=False,
    )
    rows.append(["parameters", *(f"{variants[v]['parameters']:,}" for v in names)])
    best.append([])
    return header, rows, best


def paper_rows(result: dict[str, Any]) -> list[list[str]]:
    """The paper's Table II (highD) in the same columns."""
    variants = result["variants"]
    return [
        [f"{HORIZONS_S[h]} s", *(f"{variants[v]['paper_rmse'][h]:.2f}" for v in variants)]
        for h in range(len(HORIZONS_S))
    ]


def ablation_plot(result: dict[str, Any]) -> bytes:
    """RMSE by horizon per variant (mean, error bars ± std over seeds) beside the paper's values."""
    plt = pyplot()
    fig, (ours, paper) = plt.subplots(1, 2, figsize=(11, 4), sharey=False)
    for i, (name, v) in enumerate(result["variants"].items()):
        colour = f"C{i}"
        style = {"lw": 2.4} if name == "full" else {"lw": 1.2}
        ours.errorbar(
            HORIZONS_S,
            v["mean"]["rmse"],
            yerr=v["std"]["rmse"],
            marker="o",
            ms=3,
            capsize=3,
            color=colour,
            label=v["label"],
            **style,
        )
        paper.plot(HORIZONS_S, v["paper_rmse"], marker="o", ms=3, color=colour, label=v["label"], **style)
    n = len(result["seeds"])
    ours.set_title(
        f"this run ({result['scored_on']['windows']:,} test windows, {n} seed{'s' * (n > 1)})", fontsize=9
    )
    paper.set_title("the paper's Table II (highD)", fontsize=9)
    for ax in (ours, paper):
        ax.set_xlabel("horizon (s)")
        ax.set_ylabel("RMSE (m)")
        ax.set_xticks(HORIZONS_S)
        ax.grid(alpha=0.3)
    paper.legend(fontsize=7, loc="upper left")
    return png_bytes(fig)


def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(r) + " |" for r in rows),
    ]


def headline_text(result: dict[str, Any]) -> str:
    """The answer first: which variant wins at 5 s and whether that is significant (ablation.json's
    ``headline``); a quick run's sentence says that its figures compare nothing."""
    text = str((result.get("headline") or {}).get("text") or "")
    if text and result.get("quick_warning"):
        text += " A quick run: these figures do not compare the variants."
    return text


def write_ablation_report(directory: Path, result: dict[str, Any]) -> Path:
    """Write report.md, ablation.png and a self-contained report.html into ``directory``; return the HTML."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    plot = ablation_plot(result)
    with atomic_path(directory / "ablation.png") as tmp:
        tmp.write_bytes(plot)
    header, rows, best = table_rows(result)
    n = len(result["seeds"])
    where = result["scored_on"]
    cfg = result["train_config"]
    intro = (
        f"Each variant was trained with seeds {', '.join(map(str, result['seeds']))} "
        f"({cfg['epochs']} epochs, batch {cfg['batch_size']}, Adam lr {cfg['lr']:g}) and scored on the same "
        f"{where['windows']:,} {where['split']} windows ({where['lane_change_windows']:,} with a lane change in "
        f"their 5 s future). RMSE per window in metres"
        + (", mean ± standard deviation over the seeds." if n > 1 else " (one seed: no spread).")
    )
    notes = [
        "Only input x and y: conv1 reads the position channels alone.",
        "Without neighbourhood: every row but the target's is zero (absent) in training and testing.",
        "Shuffled neighbourhood: the eight rows in one fixed order (F, L, FL, FR, R, RR, T, RL).",
        "Without dilation: dilation 1 everywhere, the dense layers widened to the 408 conv features "
        "(90,681 parameters, the paper's figure).",
        "Without maneuver: the regressor alone, no maneuver input.",
        "Sampled maneuver: the full model's regressor fed maneuver sequences drawn at random from the "
        "training windows (no classifier).",
        "Macro-F1 averages F1 over the maneuver classes present in the ground truth or predicted "
        "(a predicted but absent class counts with F1 = 0).",
    ]
    quick = result.get("quick_warning")  # a check that the ablation runs: no winner to name
    warning = [f"**Quick run: {quick}**", ""] if quick else []
    answer = headline_text(result)
    md = [
        "# Ablation study (Table II of Mersch et al., IROS 2021)",
        "",
        *warning,
        *([answer if quick else f"**{answer}**", ""] if answer else []),  # a quick run: nothing bold
        intro,
        "",
        *_md_table(header, rows),
    ]
    md += ["", "The paper's Table II (highD, RMSE in m):", "", *_md_table(header, paper_rows(result)), ""]
    md += [f"- {line}" for line in notes] + ["", "![RMSE by horizon](ablation.png)", ""]
    with atomic_path(directory / "report.md") as tmp:
        tmp.write_text("\n".join([MARKDOWN_MARK, *md]), encoding="utf-8")

    esc = html.escape

    def table(rows_: list[list[str]], bold: list[list[int]] | None) -> str:
        parts = ["<table><tr>", *(f"<th>{esc(h)}</th>" for h in header), "</tr>"]
        for r, row in enumerate(rows_):
            cells = []
            for c, value in enumerate(row):
                text = esc(value)
                cells.append(f"<td><b>{text}</b></td>" if bold and c in bold[r] else f"<td>{text}</td>")
            parts.append("<tr>" + "".join(cells) + "</tr>")
        return "".join(parts) + "</table>"

    page = [
        f"<!doctype html><html><head><meta charset='utf-8'>{HTML_MARK}<title>lanecast ablation</title><style>"
        "body{font-family:sans-serif;max-width:1150px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.6em 0}td,th{border:1px solid #ccc;padding:3px 7px;"
        "text-align:right;font-size:13px}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}"
        "img{max-width:100%}</style></head><body>",
        "<h1>Ablation study</h1>",
        "<p>The seven variants of Table II of Mersch et al. (IROS 2021), retrained on the same windows.</p>",
        *([f"<p style='background:#fff3cd;padding:6px'><b>Quick run: {esc(quick)}</b></p>"] if quick else []),
        *([f"<p>{esc(answer)}</p>" if quick else f"<p><b>{esc(answer)}</b></p>"] if answer else []),
        f"<p>{esc(intro)}{'' if quick else ' The lowest mean of each row is bold.'}</p>",
        table(rows, None if quick else best),
        "<h2>The paper's Table II (highD)</h2>",
        table(paper_rows(result), None),
        f"<img alt='RMSE by horizon per variant' src='data:image/png;base64,{base64.b64encode(plot).decode()}'>",
        "<h2>What each variant changes</h2><ul>",
        *(f"<li>{esc(line)}</li>" for line in notes),
        "</ul></body></html>",
    ]
    html_path = directory / "report.html"
    with atomic_path(html_path) as tmp:
        tmp.write_text("".join(page), encoding="utf-8")
    return html_path
