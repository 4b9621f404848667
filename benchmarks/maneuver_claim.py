"""Is the maneuver-based network better than its regression-only variant on lane-change windows, per scenario?

The paper's claim, tested with its noise: for every held-out scenario of one or more runs of
``benchmarks/train_shipped.py`` (each run's ``weights`` and ``regression-only`` models on its
``windows-test``), the RMSE at 5 s over the windows with a lane change in their future, of both
models, their difference, and a 95 % percentile-bootstrap interval of that difference. Windows of one
vehicle overlap and share their errors, so the bootstrap resamples *vehicles* (with all their windows),
the two models always together (a paired comparison). With several runs (seeds), the pooled line
averages each window's squared errors over the runs before the same bootstrap. The same lines for the
regressor given the *true* maneuvers say what the maneuver input is worth when it is right.

Three held-out minutes per scenario hold 16-221 lane changes; ``--held-out-minutes M`` simulates a
larger held-out set instead (seeds training seed + 1600, never trained on nor in ``windows-test``),
written into the first run's work directory and shared by all runs.

    .venv/bin/python benchmarks/maneuver_claim.py /tmp/lanecast-shipped [/tmp/lanecast-shipped-seed1 ...]
    .venv/bin/python benchmarks/maneuver_claim.py /tmp/lanecast-shipped --held-out-minutes 12
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

BOOTS = 4000
LARGE_HELD_OUT_SEED_OFFSET = 1600  # the larger held-out set's seeds: training seed + this


def per_vehicle_sums(sq_error: np.ndarray, vehicle: np.ndarray, n_vehicles: int) -> np.ndarray:
    """Sum of squared errors per vehicle: sq_error [N], vehicle [N] codes 0..V-1 → float64 [V]."""
    return np.bincount(vehicle, weights=sq_error, minlength=n_vehicles)


def paired_bootstrap(
    sq_a: np.ndarray, sq_b: np.ndarray, vehicle: np.ndarray, *, boots: int = BOOTS, seed: int = 0
) -> tuple[float, float, float, float]:
    """RMSE of a, of b, and the 2.5 / 97.5 percentiles of RMSE(a) − RMSE(b) over vehicle resamples.

    sq_a, sq_b float [N]: squared errors of the same windows; vehicle int [N]: any vehicle codes.
    """
    _, code = np.unique(vehicle, return_inverse=True)
    v = int(code.max()) + 1
    sum_a, sum_b = per_vehicle_sums(sq_a, code, v), per_vehicle_sums(sq_b, code, v)
    count = np.bincount(code, minlength=v).astype(np.float64)
    weights = np.random.default_rng(seed).multinomial(v, np.full(v, 1.0 / v), size=boots)  # [B, V]
    n = weights @ count
    diff = np.sqrt(weights @ sum_a / n) - np.sqrt(weights @ sum_b / n)
    low, high = np.percentile(diff, [2.5, 97.5])
    return float(np.sqrt(sq_a.mean())), float(np.sqrt(sq_b.mean())), float(low), float(high)


def large_held_out(work: Path, minutes: float) -> Path:
    """Windows of a held-out recording of ``minutes`` per scenario (seeds never used elsewhere),
    simulated and cut once into ``work/held-out-<minutes>min``; returns that directory."""
    from train_shipped import MIX, recordings, simulate_one, windows_for

    root = work / f"held-out-{minutes:g}min"
    _, test = recordings()
    sims = [
        simulate_one(root, name, rec_id, MIX[name][1] + LARGE_HELD_OUT_SEED_OFFSET, minutes)
        for name, rec_id, _, _ in test
    ]
    return windows_for(sims, root / "windows", "none", 10**9)


def squared_errors_at_5s(
    work: Path, windows_dir: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lane-change windows of one run's held-out set: (scenario [M], vehicle [M], squared errors at
    5 s along and across the road [3, M, 2] of the maneuver-based model, the regression-only model and
    the maneuver-based model given the true maneuvers, window index [M])."""
    from train_shipped import recordings, scenario_of_windows

    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.models.evaluation import vehicle_ids
    from lanecast.models.metrics import lane_change_windows
    from lanecast.models.predict import STCNNForecaster

    held_out = load_windows(windows_dir)
    _, test = recordings()
    maneuver = np.asarray(held_out.maneuver)
    lc = np.flatnonzero(lane_change_windows(maneuver))
    inputs, present = np.asarray(held_out.inputs[lc]), np.asarray(held_out.present[lc])
    future = np.asarray(held_out.future[lc])[:, -1]
    errors = []
    for model_dir in (work / "weights", work / "regression-only"):
        pred = STCNNForecaster.load(model_dir).predict(inputs, present, top_k=1).offsets[:, -1]
        errors.append(((pred - future) ** 2).astype(np.float64))  # [M, 2]: along, across the road
    oracle = with_true_maneuvers(STCNNForecaster.load(work / "weights"), inputs, present, maneuver[lc])
    errors.append(((oracle[:, -1] - future) ** 2).astype(np.float64))
    scenario = scenario_of_windows(held_out, test)[lc]
    vehicle = vehicle_ids(held_out.index.take(lc))
    return scenario, vehicle, np.stack(errors), lc


def with_true_maneuvers(
    model: Any, inputs: np.ndarray, present: np.ndarray, maneuver: np.ndarray
) -> np.ndarray:
    """The maneuver-based network's forecast [M, 5, 2] when its regressor gets the *true* maneuvers
    [M, 5] instead of the classifier's (an oracle: what the maneuver input is worth when it is right)."""
    import torch

    from lanecast.io_adapters.contracts.normalisation import normalise
    from lanecast.models.baselines import kinematic_limits, reference_offsets

    x = torch.from_numpy(normalise(inputs, present, model.input_stats))
    with torch.inference_mode():
        out = model.model.regressor(x, torch.from_numpy(maneuver)).numpy()
    out = out * model.future_std + model.future_mean
    base = reference_offsets(inputs, model.relative_to)
    return kinematic_limits(out if base is None else out + base)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("works", type=Path, nargs="+", help="work directories of train_shipped.py runs")
    ap.add_argument("--held-out-minutes", type=float, default=0.0, help="0: each run's windows-test")
    ap.add_argument(
        "--per-scenario",
        action="store_true",
        help="also every run's RMSE, CV ratio and macro-F1 per scenario",
    )
    args = ap.parse_args()

    first = args.works[0]
    shared = large_held_out(first, args.held_out_minutes) if args.held_out_minutes > 0 else None
    runs = [squared_errors_at_5s(w, shared or w / "windows-test") for w in args.works]
    if any(not np.array_equal(r[3], runs[0][3]) for r in runs):
        raise SystemExit("the runs' held-out windows differ: pool only runs of the same held-out data")
    scenario, vehicle = runs[0][0], runs[0][1]
    labels = [w.name for w in args.works] + (["pooled"] if len(runs) > 1 else [])
    series = [r[2] for r in runs] + ([np.mean([r[2] for r in runs], axis=0)] if len(runs) > 1 else [])
    for title, (a, b) in (
        ("maneuver-based / regression-only", (0, 1)),
        ("true maneuvers / regression-only", (2, 1)),
    ):
        print(f"lane-change windows, RMSE at 5 s (m): {title}, difference [95 % CI]")
        for name in [*dict.fromkeys(scenario.tolist()), "all"]:
            mask = np.ones(scenario.size, bool) if name == "all" else scenario == name
            cells = []
            for label, sq in zip(labels, series, strict=True):
                total = sq.sum(axis=-1)
                ra, rb, low, high = paired_bootstrap(total[a][mask], total[b][mask], vehicle[mask])
                verdict = "better" if high < 0 else "worse" if low > 0 else "tie"
                across = sq[a][mask, 1].sum() / total[a][mask].sum()
                cells.append(
                    f"{label}: {ra:.2f}/{rb:.2f} {ra - rb:+.2f} [{low:+.2f}, {high:+.2f}] {verdict}, across {across:.0%}"
                )
            print(f"{name:12s} n={int(mask.sum()):5d}  " + "  |  ".join(cells))
    if args.per_scenario:
        for work in args.works:
            per_scenario_table(work, shared or work / "windows-test")
    return 0


def per_scenario_table(work: Path, windows_dir: Path) -> None:
    """One run's models on the held-out windows, per scenario: RMSE at 1 s and 5 s of the
    maneuver-based model and of CV, their ratio at 5 s, lane-change RMSE at 5 s of the model, its
    regression-only variant and CV, and the maneuver macro-F1."""
    from train_shipped import recordings, scenario_of_windows

    from lanecast.io_adapters.contracts.windows import subset
    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.models.baselines import constant_velocity
    from lanecast.models.evaluation import evaluate
    from lanecast.models.predict import STCNNForecaster

    held_out = load_windows(windows_dir)
    _, test = recordings()
    scenario = scenario_of_windows(held_out, test)
    models = [
        STCNNForecaster.load(work / "weights", "stcnn"),
        STCNNForecaster.load(work / "regression-only", "reg"),
        constant_velocity(),
    ]
    print(
        f"{work.name}: scenario, windows, RMSE 1 s / 5 s model (CV), ratio at 5 s, LC@5 s model / reg.-only / CV, macro-F1"
    )
    for name in [*dict.fromkeys(scenario.tolist()), "all"]:
        part = held_out if name == "all" else subset(held_out, scenario == name)
        m = evaluate(part, models, splits=("none",), top_k=1)[0]
        st, reg, cv = m["stcnn"], m["reg"], m["cv"]
        print(
            f"  {name:12s} {st['n_windows']:7,d}  {st['rmse'][0]:.2f} / {st['rmse'][-1]:.2f} "
            f"({cv['rmse'][0]:.2f} / {cv['rmse'][-1]:.2f})  {st['rmse'][-1] / cv['rmse'][-1]:.2f}  "
            f"{st['rmse_lane_change'][-1]:.2f} / {reg['rmse_lane_change'][-1]:.2f} / "
            f"{cv['rmse_lane_change'][-1]:.2f}  {st['maneuver_macro_f1']:.3f}"
        )


if __name__ == "__main__":
    raise SystemExit(main())
