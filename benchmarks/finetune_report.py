"""Markdown tables of benchmarks/finetune.py: per method the acceptance checks, per kind the figures."""

from __future__ import annotations

from typing import Any

#: acceptance: own test split within 3 % of the plain fine-tune; every other kind within 5 % of the
#: shipped model's RMSE at 5 s and lane-change macro-F1 within 0.03 of it
OWN_TOLERANCE, OTHER_TOLERANCE, F1_TOLERANCE = 0.03, 0.05, 0.03


def checks(table: dict[str, Any], own: str, name: str, plain: str) -> dict[str, Any]:
    """The acceptance figures of model ``name`` against ``plain`` (own kind) and the shipped model."""
    own_ratio = table[own][name]["rmse5"] / table[own][plain]["rmse5"]
    others = [k for k in table if k != own]
    worst = max(others, key=lambda k: table[k][name]["rmse5"] / table[k]["shipped"]["rmse5"])
    worst_ratio = table[worst][name]["rmse5"] / table[worst]["shipped"]["rmse5"]
    drops = {
        k: table[k]["shipped"]["f1"] - table[k][name]["f1"]
        for k in others
        if table[k][name]["f1"] is not None
    }
    f1_kind = max(drops, key=lambda k: drops[k]) if drops else None
    f1_drop = drops[f1_kind] if f1_kind else 0.0
    return {
        "own_vs_plain": own_ratio,
        "worst_other": (worst, worst_ratio),
        "worst_f1_drop": (f1_kind, f1_drop),
        "met": own_ratio <= 1 + OWN_TOLERANCE
        and worst_ratio <= 1 + OTHER_TOLERANCE
        and f1_drop <= F1_TOLERANCE,
    }


def render(
    table: dict[str, Any], own: str, names: list[str], out: dict[str, Any], columns: list[str] | None = None
) -> str:
    tuned = [n for n in names if n != "shipped"]
    plains = [n for n in tuned if n.startswith("none")]
    plain = min(plains, key=lambda n: table[own][n]["rmse5"]) if plains else "shipped"
    lines = [
        f"Fine-tuned on `{own.split(':')[0]}` ({out['finetune_windows']['train']:,} training and "
        f"{out['finetune_windows']['val']:,} validation windows, {out['epochs']} epochs, cosine schedule); "
        f"load average (1 min) up to {max(la[0] for la in out['load_average']):.1f} (2 shared cores); "
        f'{out["seconds"]:.0f} s in all. "plain" = `--keep-base none`, the best plain run on its own test '
        f"split (`{plain}`) is the reference there.",
        "",
        "| model | own test RMSE@5 s vs plain | worst other kind vs shipped (RMSE@5 s) | "
        "largest lane-change macro-F1 drop vs shipped | fine-tune s | acceptance |",
        "|---|---|---|---|---|---|",
    ]
    for n in tuned:
        c = checks(table, own, n, plain)
        kind, ratio = c["worst_other"]
        f1_kind, drop = c["worst_f1_drop"]
        lines.append(
            f"| {n} | {100 * (c['own_vs_plain'] - 1):+.1f} % | {100 * (ratio - 1):+.1f} % ({kind}) | "
            f"{drop:+.3f} ({f1_kind}) | {out['runs'][n]['seconds']:.0f} | {'met' if c['met'] else 'not met'} |"
        )
    shown = [n for n in tuned if columns is None or n in columns]
    lines += ["", "RMSE at 5 s in m (ratio to constant velocity) / lane-change macro-F1 per kind:", ""]
    lines.append("| kind | windows | CV | " + " | ".join(["shipped", *shown]) + " |")
    lines.append("|---" * (4 + len(shown)) + "|")
    for kind, row in table.items():
        cells = []
        for n in ["shipped", *shown]:
            r = row[n]
            f1 = "" if r["f1"] is None else f" / {r['f1']:.2f}"
            cells.append(f"{r['rmse5']:.2f} ({r['ratio']:.2f}×){f1}")
        lines.append(
            f"| {kind} | {row['cv']['n']:,} | {row['cv']['rmse5']:.2f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"
