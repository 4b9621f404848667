"""lanecast's csp sets against conv-social-pooling's own ``preprocess_data.m`` under GNU Octave,
element for element, on NGSIM-format input made from simulated traffic (benchmarks/csp_inputs.py).

    .venv/bin/python benchmarks/csp_equality.py --script PATH/preprocess_data.m --work /tmp/csp [--minutes 2.5]

runs both on the same six files and prints every difference in ``traj`` and ``tracks`` of the three
sets (none: "equal"). ``--fixture tests/data/csp`` instead makes the small test fixture: six cropped
files (twelve vehicles over 40 frames each, ids renumbered 1–12) and the Octave-made sets beside them.
The research script is not shipped with lanecast; without ``octave`` on the PATH the script says so
and exits 0.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import csp_inputs as ci

FIXTURE_FRAMES = 40
FIXTURE_VEHICLES = 12


def _renumbered(
    cols: dict[str, np.ndarray], frames: tuple[int, int], first_ft: float
) -> dict[str, np.ndarray] | None:
    """Twelve vehicles present over ``frames`` from ``first_ft`` on (ids 1–12 by position), or None."""
    frame, track = cols["frame"].astype(np.int64), cols["track_id"].astype(np.int64)
    inside = (frame >= frames[0]) & (frame < frames[1])
    full = np.bincount(track[inside], minlength=track.max() + 1) == frames[1] - frames[0]
    at_first = inside & (frame == frames[0]) & full[track]
    front = (cols["x"] - cols["x"].min()) / ci.FT  # the upper direction runs at negative x
    ahead = np.flatnonzero(at_first & (front >= first_ft))
    if ahead.size < FIXTURE_VEHICLES:
        return None
    chosen = track[ahead[np.argsort(front[ahead])[:FIXTURE_VEHICLES]]]
    new_id = np.zeros(track.max() + 1, np.int64)
    new_id[chosen] = np.arange(1, FIXTURE_VEHICLES + 1)
    keep = inside & (new_id[track] > 0)
    out = {k: v[keep] for k, v in cols.items()}
    out["track_id"] = new_id[track[keep]]
    return out


def _fits(path: Path, lane_change: bool) -> bool:
    """A fixture file in which some row has a neighbour in the last grid column (else the script's
    matrix of that file has fewer columns and its concatenation fails), and whose kept rows have a
    lane change if ``lane_change``."""
    from lanecast.io_adapters.datasets.csp import fields, inputs, sets

    ((_, _, ds),) = inputs.ngsim_datasets([path])
    every = fields.neighbour_grid(ds.vehicle, ds.frame, ds.y, ds.lane, np.arange(ds.vehicle.size))
    traj = np.concatenate([p.traj[0] for p in sets.dataset_parts(ds)])
    return bool(traj.size and every[:, -1].any() and (not lane_change or (traj[:, 6] > 1).any()))


def _crop(cols: dict[str, np.ndarray], frames: np.ndarray, path: Path, lane_base: int, change: bool) -> bool:
    """Write the first crop that fits (see :func:`_fits`) to ``path``; whether one did."""
    for f0 in frames[300 : frames.size - FIXTURE_FRAMES : 10]:
        for first_ft in np.arange(0.0, 2500.0, 50.0):
            crop = _renumbered(cols, (int(f0), int(f0) + FIXTURE_FRAMES), float(first_ft))
            if crop is None:
                break
            ci.write_ngsim_txt(crop, path, lane_base=lane_base)
            if _fits(path, change):
                return True
    return False


def make_fixture(out: Path, script: Path, work: Path) -> None:
    """Six small NGSIM files cropped from the 2.5-minute simulations, and Octave's sets of them."""
    out.mkdir(parents=True, exist_ok=True)
    directions = []
    for s, scenario in enumerate(ci.SCENARIOS, start=1):
        name = f"sim-2.5min-{scenario or 'highway'}-{s}"
        directions += ci.direction_rows(ci.simulate(work / name, 2.5, s, scenario))
    for i, (name, cols) in enumerate(zip(ci.NAMES, directions, strict=True)):
        path = out / name
        frames = np.unique(cols["frame"].astype(np.int64))
        lane_base = ci.US101_LANE_BASE if i < 3 else 1
        if not any(_crop(cols, frames, path, lane_base, change) for change in (True, False)):
            raise SystemExit(f"no crop of {name} reaches the last grid cell")
        print(f"{path}: {sum(1 for _ in path.open())} rows")
    wall, cpu = ci.run_octave(script, [out / n for n in ci.NAMES], out)
    print(f"octave: {wall:.1f} s ({cpu:.1f} s CPU); sets in {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--script", type=Path, required=True, help="conv-social-pooling's preprocess_data.m")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "lanecast-csp")
    ap.add_argument("--minutes", type=float, default=2.5, help="simulated minutes per simulation")
    ap.add_argument("--fixture", type=Path, help="make the small test fixture in this directory instead")
    args = ap.parse_args()
    if shutil.which("octave") is None:
        print("octave is not installed (Debian: apt-get install octave): nothing compared")
        return
    if args.fixture:
        make_fixture(args.fixture, args.script, args.work)
        return
    inputs = ci.make_inputs(args.work, args.minutes)
    theirs = args.work / f"octave-{args.minutes:g}min"
    if not all((theirs / f"{s}.mat").exists() for s in ci.SETS):
        print("octave: {:.1f} s ({:.1f} s CPU)".format(*ci.run_octave(args.script, inputs, theirs)))
    ours = args.work / f"lanecast-{args.minutes:g}min"
    print("lanecast: {:.1f} s ({:.1f} s CPU)".format(*ci.run_lanecast(inputs, ours)))
    problems = ci.compare_sets(ours, theirs)
    rows = {s: __import__("scipy.io").io.loadmat(ours / f"{s}.mat")["traj"].shape[0] for s in ci.SETS}
    print(f"{sum(1 for p in inputs for _ in p.open()):,} input rows; rows per set: {rows}")
    print("\n".join(problems) if problems else "equal: every element of traj and tracks in all three sets")
    if problems:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
