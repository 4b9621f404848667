"""Shared parts of the csp benchmarks: NGSIM-format input made from simulated traffic, the
research script run under GNU Octave, and an element-for-element comparison of two output sets.

Input: ``lanecast simulate`` writes a highD-format recording (25 Hz); it is read with lanecast's
highD reader, resampled to NGSIM's 10 Hz, and each driving direction is written as one raw NGSIM
``.txt`` (18 whitespace-separated columns, feet, front-bumper Local_Y, lanes numbered from 1 at the
left). Six files come from three simulations × two directions (the default highway, ``waves``: stop-and-go
waves and a lane drop, ``on_ramp``: a merge; seeds seed…seed+2), so that every label occurs; the first three are named as US-101 files
and their lanes numbered from 5 (so that the script's "US-101 lanes ≥ 6 become 6" merges two
lanes), the others as I-80 files. Vehicles of fewer than 31 rows are left out: the research script
stops with an index error on them (real NGSIM files have none).

The research script is not part of lanecast: pass its path (``--script``, conv-social-pooling's
``preprocess_data.m``). It runs in a temporary copy in which only its file paths are changed (the six
inputs, and the three outputs to ``<dir>/TrainSet.mat`` …), with ``save_default_options('-v7')``
set before it runs (Octave's default save format is text; MATLAB's is -v7) and a ``parpool`` that
returns nothing for versions of the script that open a pool (Octave runs ``parfor`` serially).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_proxy import save_ngsim_txt  # noqa: E402

from lanecast.io_adapters.datasets.highd import reader as highd  # noqa: E402
from lanecast.pipeline.resample import resample  # noqa: E402

FT = 0.3048
MIN_ROWS = 31
US101_LANE_BASE = 5
NAMES = (
    "us-101-0750-0805.txt",
    "us-101-0805-0820.txt",
    "us-101-0820-0835.txt",
    "i-80-1600-1615.txt",
    "i-80-1700-1715.txt",
    "i-80-1715-1730.txt",
)
SCRIPT_INPUTS = ("us101_1", "us101_2", "us101_3", "i80_1", "i80_2", "i80_3")
SETS = ("TrainSet", "ValSet", "TestSet")


def lanecast_cmd(*argv: str) -> list[str]:
    return [sys.executable, "-m", "lanecast", *argv]


SCENARIOS = (None, "waves", "on_ramp")


def simulate(out: Path, minutes: float, seed: int, scenario: str | None = None) -> Path:
    """A highD-format recording of ``minutes`` simulated minutes (reused if ``out`` holds one)."""
    if not (out / "01_tracks.csv").exists():
        cmd = lanecast_cmd("simulate", "--out", str(out), "--minutes", str(minutes), "--seed", str(seed))
        cmd += ["--scenario", scenario] if scenario else []
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=_env())
    return out / "01_tracks.csv"


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def direction_rows(tracks_csv: Path) -> list[dict[str, np.ndarray]]:
    """Each driving direction of a recording at 10 Hz, rows sorted by (vehicle, frame)."""
    table = resample(highd.read([tracks_csv]))
    names = table.column("recording").to_numpy(zero_copy_only=False).astype(str)
    out = []
    for name in sorted(set(names)):
        rows = names == name
        cols = {
            c: table.column(c).to_numpy(zero_copy_only=False)[rows]
            for c in (
                "track_id",
                "frame",
                "x",
                "y",
                "vx",
                "vy",
                "ax",
                "length",
                "width",
                "lane_id",
                "object_class",
            )
        }
        cols["object_class"] = cols["object_class"].astype(str)
        out.append(cols)
    return out


def write_ngsim_txt(
    cols: dict[str, np.ndarray],
    path: Path,
    lane_base: int = 1,
    frames: tuple[int, int] | None = None,
    stretch_ft: tuple[float, float] | None = None,
) -> int:
    """One direction as a raw NGSIM .txt; ``frames``/``stretch_ft`` crop to vehicles present in
    every frame of [first, last) and (at the first) within the stretch of Local_Y. Rows written."""
    track, frame = cols["track_id"].astype(np.int64), cols["frame"].astype(np.int64)
    lateral_ft = -cols["y"] / FT
    front_ft = (cols["x"] + cols["length"] / 2) / FT
    lateral_ft, front_ft = lateral_ft - lateral_ft.min() + 3.0, front_ft - front_ft.min() + 10.0
    lane_id = np.nan_to_num(cols["lane_id"].astype(float), nan=0).astype(np.int64)
    known = np.unique(lane_id[lane_id > 0])
    order_left = known[np.argsort([-cols["y"][lane_id == k].mean() for k in known])]
    lane = np.zeros(lane_id.size, np.int64)
    for rank, k in enumerate(order_left):
        lane[lane_id == k] = lane_base + rank
    keep = np.ones(track.size, bool)
    if frames is not None:
        inside = (frame >= frames[0]) & (frame < frames[1])
        full = np.bincount(track[inside], minlength=track.max() + 1) == frames[1] - frames[0]
        keep = inside & full[track]
        if stretch_ft is not None:
            at_first = keep & (frame == frames[0]) & (front_ft >= stretch_ft[0]) & (front_ft < stretch_ft[1])
            chosen = np.zeros(track.max() + 1, bool)
            chosen[track[at_first]] = True
            keep &= chosen[track]
    counts = np.bincount(track[keep], minlength=track.max() + 1)
    keep &= counts[track] >= MIN_ROWS
    order = np.flatnonzero(keep)[np.lexsort((frame[keep], track[keep]))]
    n = order.size
    total = np.bincount(track[order], minlength=track.max() + 1)[track[order]]
    speed = np.hypot(cols["vx"], cols["vy"])[order] / FT
    columns = [
        track[order],
        frame[order],
        total,
        1113433136100 + 100 * frame[order],
        lateral_ft[order],
        front_ft[order],
        6042842.0 + lateral_ft[order],
        2133117.0 + front_ft[order],
        cols["length"][order] / FT,
        cols["width"][order] / FT,
        np.where(cols["object_class"][order] == "truck", 3, 2),
        speed,
        np.clip(cols["ax"][order] / FT, -11.2, 11.2),
        lane[order],
        np.zeros(n),
        np.zeros(n),
        np.zeros(n),
        np.zeros(n),
    ]
    save_ngsim_txt(path, columns)
    return n


def make_inputs(work: Path, minutes: float, seed: int = 1) -> list[Path]:
    """Six NGSIM .txt files from the three simulations of ``minutes`` each (reused when made)."""
    out = work / f"ngsim-{minutes:g}min-{seed}"
    paths = [out / name for name in NAMES]
    if all(p.exists() for p in paths):
        return paths
    out.mkdir(parents=True, exist_ok=True)
    directions = []
    for s, scenario in enumerate(SCENARIOS, start=seed):
        name = f"sim-{minutes:g}min-{scenario or 'highway'}-{s}"
        directions += direction_rows(simulate(work / name, minutes, s, scenario))
    for i, (path, cols) in enumerate(zip(paths, directions, strict=True)):
        write_ngsim_txt(cols, path, lane_base=US101_LANE_BASE if i < 3 else 1)
    return paths


def octave_script(original: Path, inputs: list[Path], out: Path) -> str:
    """The research script with only its file paths changed."""
    text = original.read_text()
    for var, path in zip(SCRIPT_INPUTS, inputs, strict=True):
        text, n = re.subn(rf"^{var}\s*=\s*'[^']*';", f"{var} = '{path}';", text, flags=re.M)
        if n != 1:
            raise SystemExit(f"{original}: no line '{var} = ...;' to point at the input")
    for name in SETS:
        text, n = re.subn(rf"save\('{name}'", f"save('{out / name}.mat'", text)
        if n != 1:
            raise SystemExit(f"{original}: no save('{name}', ...) to point at {out}")
    return text


def _cpu() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_octave(original: Path, inputs: list[Path], out: Path) -> tuple[float, float]:
    """Run the research script under Octave (niced); (wall seconds, CPU seconds) it took."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="csp-octave-") as tmp:
        script = Path(tmp) / "preprocess_data_paths.m"
        script.write_text(octave_script(original, [p.resolve() for p in inputs], out.resolve()))
        (Path(tmp) / "parpool.m").write_text("function p = parpool(varargin)\n  p = [];\nend\n")
        started, cpu = time.perf_counter(), _cpu()
        done = subprocess.run(
            [
                "nice",
                "-n",
                "10",
                "octave",
                "--no-gui",
                "--quiet",
                "--no-window-system",
                "--eval",
                f"addpath('{tmp}'); save_default_options('-v7'); run('{script}');",
            ],
            cwd=tmp,
            capture_output=True,
            text=True,
        )
        took = time.perf_counter() - started, _cpu() - cpu
    if not all((out / f"{s}.mat").exists() for s in SETS):
        raise SystemExit(f"octave failed ({done.returncode}):\n{done.stdout[-1500:]}\n{done.stderr[-1500:]}")
    return took


def run_lanecast(inputs: list[Path], out: Path, *extra: str) -> tuple[float, float]:
    """``lanecast convert INPUTS --to csp --out OUT [EXTRA]`` in its own process; (wall seconds,
    CPU seconds of it and its workers) it took."""
    if out.exists():
        shutil.rmtree(out)
    started, cpu = time.perf_counter(), _cpu()
    cmd = lanecast_cmd("convert", *map(str, inputs), "--to", "csp", "--out", str(out), *extra)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env())
    return time.perf_counter() - started, _cpu() - cpu


def octave_found() -> bool:
    return shutil.which("octave") is not None


def compare_sets(ours: Path, theirs: Path) -> list[str]:
    """Every difference between two directories of sets (empty: equal element for element)."""
    from scipy.io import loadmat

    problems: list[str] = []
    for name in SETS:
        a, b = loadmat(ours / f"{name}.mat"), loadmat(theirs / f"{name}.mat")
        ta, tb = a["traj"], b["traj"]
        if ta.dtype != tb.dtype or ta.shape != tb.shape:
            problems.append(f"{name} traj: {ta.dtype}{ta.shape} vs {tb.dtype}{tb.shape}")
        else:
            bad = np.argwhere(~((ta == tb) | (np.isnan(ta) & np.isnan(tb))))
            problems += [f"{name} traj[{r}, {c}]: {ta[r, c]} vs {tb[r, c]}" for r, c in bad[:20]]
            if len(bad) > 20:
                problems.append(f"{name} traj: {len(bad)} elements differ")
        ca, cb = a["tracks"], b["tracks"]
        if ca.shape != cb.shape:
            problems.append(f"{name} tracks: cell {ca.shape} vs {cb.shape}")
            continue
        for index in np.ndindex(ca.shape):
            x, y = ca[index], cb[index]
            if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y):
                problems.append(
                    f"{name} tracks{{{index[0] + 1},{index[1] + 1}}}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}"
                )
    return problems


def tiled(paths: list[Path], out: Path, copies: int) -> list[Path]:
    """Each file repeated ``copies`` times one after the other in time (frames, Global_Time and
    vehicle ids shifted per copy): NGSIM-sized files from simulated ones (reused when made)."""
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    made = []
    for path in paths:
        target = out / path.name
        made.append(target)
        if target.exists():
            continue
        rows = pd.read_csv(path, sep=r"\s+", header=None)
        ids = int(rows[0].max())
        span = int(rows[1].max() - rows[1].min()) + 100
        parts = []
        for c in range(copies):
            part = rows.copy()
            part[0] += c * ids
            part[1] += c * span
            part[3] += c * span * 100
            parts.append(part)
        tmp = target.with_suffix(".tmp")
        pd.concat(parts).to_csv(tmp, sep=" ", header=False, index=False)
        tmp.replace(target)
    return made
