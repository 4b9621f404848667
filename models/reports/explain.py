"""The page of ``lanecast explain``: the full scene and each what-if drawn as the paper's scenes, and a
table of how much each removal moved the forecast (most influential first).

Writes ``explain.html`` (self-contained), ``explain.json`` and one PNG per scene.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVERS, ROWS
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.ownership import GENERATOR, HTML_MARK
from lanecast.models.explain import WhatIf
from lanecast.models.reports.document import Scene, scene_plot


def scenes(whatif: WhatIf, title: str, future: np.ndarray) -> list[Scene]:
    """One Scene per scenario: the full scene first, then the what-ifs in the ranking table's order
    (most influential first); removed neighbours drawn dashed where they were at t0.

    future float [5, 2]: the ground truth (NaN where unknown: not drawn).
    """
    p = whatif.predictions
    full_inputs, full_present = whatif.inputs[0], whatif.present[0]
    out = []
    for s in [0, *whatif.rank()]:
        name = whatif.names[s]
        rows = tuple(ROWS.index(n) for n in whatif.removed[s])
        at = {
            r: (float(full_inputs[0, r, -1]), float(full_inputs[1, r, -1]))
            for r in rows
            if full_present[r, -1]
        }
        out.append(
            Scene(
                title=f"{title}: {name}",
                inputs=whatif.inputs[s],
                present=whatif.present[s],
                future=future,
                offsets=p.offsets[s],
                maneuver=p.maneuver[s] if p.maneuver is not None else np.zeros(5, np.int64),
                alternatives=p.top_offsets[s],
                alt_probs=p.top_probs[s],
                probs=None if p.probs is None else p.probs[s],
                alt_maneuvers=None if p.top_sequences is None else p.top_sequences[s],
                removed=rows,
                removed_at=at,
            )
        )
    return out


def document(whatif: WhatIf, window: dict[str, Any], model: str) -> dict[str, Any]:
    """explain.json: the window, the model, every scenario's forecast, the effects and the ranking."""
    p = whatif.predictions
    return {
        "window": window,
        "model": model,
        "frame": "window frame: origin at the target at t0, x along the road, y to the left (m)",
        "scenarios": [
            {
                "name": name,
                "removed": list(whatif.removed[s]),
                "offsets": np.round(p.offsets[s], 4).tolist(),
                "maneuver_probs": None if p.probs is None else np.round(p.probs[s], 4).tolist(),
                "maneuver": None if p.maneuver is None else [MANEUVERS[int(m)] for m in p.maneuver[s]],
            }
            for s, name in enumerate(whatif.names)
        ],
        "effects": whatif.effects(),
        "ranking": [whatif.names[i] for i in whatif.rank()],
    }


def _steps(maneuvers: list[str] | None) -> str:
    return "–" if maneuvers is None else " → ".join(maneuvers)


def write_explain(
    directory: Path, whatif: WhatIf, window: dict[str, Any], model: str, future: np.ndarray
) -> Path:
    """Write explain.json, scene PNGs and explain.html into ``directory``; return the HTML's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    doc = document(whatif, window, model)
    with atomic_path(directory / "explain.json") as tmp:
        tmp.write_text(
            json.dumps({**doc, "generator": GENERATOR}, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
    title = f"{window['recording']} track {window['track_id']} at t0 = {window['t0_s']:.1f} s"
    images = []
    for i, scene in enumerate(scenes(whatif, title, future)):
        data = scene_plot(scene)
        with atomic_path(directory / f"scene_{i}.png") as tmp:
            tmp.write_bytes(data)
        images.append((scene.title, data))
    esc = html.escape
    full = doc["scenarios"][0]
    effects = {e["scenario"]: e for e in doc["effects"]}
    rows = []
    for name in doc["ranking"]:
        e = effects[name]
        change = e["probability_change"]
        per_class = "–"
        if change is not None:
            steps = np.asarray(change)  # [5, 3]
            largest = steps[np.argmax(np.abs(steps), axis=0), np.arange(steps.shape[1])]
            per_class = ", ".join(f"{c} {v:+.2f}" for c, v in zip(MANEUVERS, largest, strict=True))
        rows.append(
            "<tr>"
            + "".join(
                f"<td>{esc(str(v))}</td>"
                for v in (
                    name,
                    f"{e['mean_shift_m']:.2f}",
                    f"{e['shift_5s_m']:.2f}",
                    "–" if e["max_probability_change"] is None else f"{e['max_probability_change']:.2f}",
                    per_class,
                    _steps(e["maneuver"]),
                )
            )
            + "</tr>"
        )
    top = doc["ranking"][0] if doc["ranking"] else None
    headline = (
        f"Removing {', '.join(effects[top]['removed'])} moved the forecast most: by {effects[top]['mean_shift_m']:.2f} m "
        f"on average and {effects[top]['shift_5s_m']:.2f} m at 5 s."
        if top
        else ""
    )
    page = [
        f"<!doctype html><html><head><meta charset='utf-8'>{HTML_MARK}<title>lanecast explain</title><style>"
        "body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 7px;font-size:13px;text-align:right}th{background:#f3f3f3}"
        "td:first-child,td:last-child{text-align:left}img{max-width:100%}p.note{font-size:13px;color:#444}"
        "</style></head><body>",
        f"<h1>What if a neighbour were not there?</h1><p>{esc(title)} ({esc(str(window.get('source', '')))}), "
        f"model {esc(model)}.</p>",
        f"<p>Full scene forecast: {esc(_steps(full['maneuver']))}. {esc(headline)}</p>",
        "<table><tr><th>what-if (most influential first)</th><th>mean shift (m)</th><th>shift at 5 s (m)</th>"
        "<th>largest probability change</th><th>largest change per class (what-if − full)</th>"
        "<th>maneuvers 1–5 s</th></tr>",
        *rows,
        "</table>",
        "<p class='note'>A neighbour is removed as in the paper: its slot of the input is zeroed (absent) in every "
        "history frame; everything else stays. Shift: distance between the what-if's forecast and the full "
        "scene's at each second (mean over 1–5 s, and at 5 s).</p>",
    ]
    for caption, data in images:
        page.append(
            f"<h3>{esc(caption)}</h3><img alt='{esc(caption)}' src='data:image/png;base64,{base64.b64encode(data).decode()}'>"
        )
    page.append("</body></html>")
    path = directory / "explain.html"
    with atomic_path(path) as tmp:
        tmp.write_text("".join(page), encoding="utf-8")
    return path
