"""The tables of the evaluation report, as header and rows of text.

RMSE and miss rate per model and horizon (with confidence intervals where the metrics have them),
lane-change windows, maneuver classification, per recording, and the run's metadata, from
``metrics.json`` and its metadata; numbers are formatted once here for both ``report.md`` and
``report.html``.
"""

from __future__ import annotations

from typing import Any

from lanecast.io_adapters.contracts.windows import MANEUVERS


def fmt_number(value: Any, digits: int = 2) -> str:
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


MISS_NOTE = "Miss rate: share of windows whose error at 5 s exceeds 2 m (Argoverse 2's definition)."


def model_name(key: str) -> str:
    """A model's name in words (its metrics.json key when lanecast does not know it)."""
    return MODEL_NAMES.get(key, key)


def headline(metrics: dict[str, Any]) -> list[str]:
    """The answer first: the main model's RMSE at 5 s with its interval beside constant velocity's,
    on how many windows, and a flag for a classifier that never predicts a class the data holds or
    is less accurate than always predicting straight."""
    models = [k for k in metrics if k != "meta" and metrics[k]]
    main = "stcnn" if "stcnn" in models else next((k for k in models if k not in ("cv", "ca")), None)
    lines: list[str] = []
    m, cv = metrics.get(main or "") or {}, metrics.get("cv") or {}
    rmse5 = (m.get("rmse") or [None])[-1]
    if main is not None and rmse5 is not None:
        ci = m.get("rmse_ci") or {}
        interval = (
            f" (95 % interval {ci['low'][-1]:.2f}–{ci['high'][-1]:.2f})"
            if ci.get("low") and ci["low"][-1] is not None
            else ""
        )
        cv5 = (cv.get("rmse") or [None])[-1] if main != "cv" else None
        versus = f", {rmse5 / cv5:.2f}× constant velocity's {cv5:.2f} m" if cv5 else ""
        lines.append(
            f"{model_name(main)}: RMSE at 5 s {rmse5:.2f} m{interval}{versus}, on {m.get('n_windows', 0):,} windows."
        )
    for key in models:
        s = metrics[key]
        if s.get("predicted") is None or s.get("support") is None:
            continue
        never = [
            MANEUVERS[c]
            for c, (n, p) in enumerate(zip(s["support"], s["predicted"], strict=True))
            if n and not p
        ]
        if never:
            lines.append(
                f"{model_name(key)} never predicts {' or '.join(repr(c) for c in never)}, which the data holds."
            )
        acc, straight = s.get("maneuver_accuracy"), s.get("always_straight_accuracy")
        if acc is not None and straight is not None and acc < straight:
            lines.append(
                f"{model_name(key)}'s maneuver accuracy {acc:.3f} is below always predicting straight ({straight:.3f})."
            )
    return lines


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
                *(fmt_number(v) for v in m["rmse"][:-1]),
                fmt_number(m["rmse"][-1]) + _ci(m.get("rmse_ci"), -1),
                fmt_number(m["ade"]),
                fmt_number(m["fde"]),
                _pct(m.get("miss_rate")),
                f"{fmt_number(m['min_ade'])} / {fmt_number(m['min_fde'])} (K={m['k']})",
                fmt_number(m["rmse_lane_change"][-1]) + _ci(m.get("rmse_lane_change_ci"), -1),
                fmt_number(m["rmse_per_vehicle"][-1]),
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
            *(fmt_number(m["rmse_lane_change"][h]) + _ci(m.get("rmse_lane_change_ci"), h) for h in range(5)),
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
                fmt_number(m["maneuver_accuracy"], 3),
                fmt_number(m["maneuver_macro_f1"], 3),
                fmt_number(m.get("brier"), 3),
                *(fmt_number(f, 3) for f in (m.get("f1") or [None] * 3)),
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
                fmt_number(straight["maneuver_accuracy"], 3),
                fmt_number(straight["maneuver_macro_f1"], 3),
                "–",
                *(fmt_number(f, 3) for f in f1_straight),
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
                fmt_number(r["rmse"][-1]),
                fmt_number((cv.get(rec) or {}).get("rmse", [None] * 5)[-1]),
                fmt_number(r["rmse_lane_change"][-1]),
                _pct(r["miss_rate"]),
                f"{fmt_number(r['maneuver_accuracy'], 3)} ({fmt_number(r['always_straight_accuracy'], 3)})",
                fmt_number(r["maneuver_macro_f1"], 3),
            ]
        )
    return header, rows


def _ratio(value: Any, reference: Any) -> str:
    return "–" if value is None or not reference else f"{value / reference:.2f}"


def speed_band_rows(metrics: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """One row per band of the target's speed at t0: the ST-CNN beside constant velocity at 1 s and
    5 s, and their ratio (below 1: the model is better)."""
    header = ["target speed at t0", "windows", "RMSE 1 s", "constant velocity", "ratio"]
    header += ["RMSE 5 s", "constant velocity", "ratio"]
    main = metrics.get("stcnn") or next(iter(metrics.values()))
    cv = (metrics.get("cv") or {}).get("per_speed_band") or {}
    rows = []
    for band, r in (main.get("per_speed_band") or {}).items():
        ref = (cv.get(band) or {}).get("rmse") or [None] * len(r["rmse"])
        row = [band, f"{r['n_windows']:,}"]
        for h in (0, -1):
            row += [fmt_number(r["rmse"][h]), fmt_number(ref[h]), _ratio(r["rmse"][h], ref[h])]
        rows.append(row)
    return header, rows


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
        "model_sha256": "model's weights (sha256)",
        "model_trained_on": "model trained on",
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
