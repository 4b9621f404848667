"""``write_csp``: raw NGSIM files or highD recordings → conv-social-pooling's ``.mat`` sets.

The output directory gets ``TrainSet.mat``, ``ValSet.mat`` and ``TestSet.mat`` (each ``traj`` and
``tracks``, MATLAB 5 format, zlib-compressed as MATLAB's default ``-v7`` save is: see
matfile.py; ``scipy.io.loadmat`` reads them) and ``lanecast-csp.json`` (the dataset ids given to the inputs,
row counts, and the size and modification time of each set, by which a later run knows the files
are its own). All files are staged beside the directory and moved in together: the directory gets
all of a run's files or none. A file of those names that lanecast did not write is refused, never
replaced; other files in the directory are left alone.
"""

from __future__ import annotations

import functools
import json
import os
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from lanecast.io_adapters.datasets.csp import inputs, matfile, sets
from lanecast.io_adapters.errors import InputError, OutputError, UsageError
from lanecast.io_adapters.files import check_output, staged_files
from lanecast.io_adapters.progress import progress

MANIFEST = "lanecast-csp.json"
CONVENTIONS = {
    "ngsim": "conv-social-pooling preprocess_data.m (Deo & Trivedi, CVPRW 2018)",
    "highd": "the same fields; highD datasets numbered as PiP's preprocess_highD.m (Song et al., ECCV 2020)",
}


def _own_files(out: Path) -> dict[str, dict[str, int]]:
    """The sets an earlier run wrote into ``out``, by name: their size and mtime as it recorded them."""
    manifest = out / MANIFEST
    if not manifest.exists():
        return {}
    try:
        written = json.loads(manifest.read_text())["files"]
        return {str(k): {"size": int(v["size"]), "mtime_ns": int(v["mtime_ns"])} for k, v in written.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise OutputError(
            manifest, "exists and is not lanecast's record of a csp conversion, so it is not replaced"
        ) from exc


def check_csp_output(out: str | Path) -> Path:
    """``out`` if the sets can be written there: a directory (or a new path) whose files of the
    sets' names are an earlier run's, unchanged since; OutputError naming the first that is not."""
    out = check_output(out, directory=True)
    own = _own_files(out)
    for name in (*(f"{s}.mat" for s in sets.SET_NAMES), MANIFEST):
        path = out / name
        if path.is_dir() and not path.is_symlink():
            raise OutputError(path, "is a directory", expected="a file lanecast may replace")
        if name == MANIFEST or not os.path.lexists(path):
            continue
        info = path.lstat()
        if own.get(name) != {"size": info.st_size, "mtime_ns": info.st_mtime_ns}:
            raise OutputError(
                path,
                "exists and was not written by lanecast (or changed since), so it is not replaced",
                expected="a new or empty --out directory, or remove the file first",
            )
    return out


Job = tuple[str, int, Path, "str | None"]
Result = list[tuple[str, Path, int, int, list[sets.SetParts]]]


def plan(paths: Sequence[str | Path], fmt: str, location: str | None) -> list[Job]:
    """One job per NGSIM file or highD recording, in dataset id order."""
    given = [Path(p) for p in paths]
    if fmt == "ngsim":
        return [
            ("ngsim", i, path, location) for i, (path, _) in enumerate(inputs.ngsim_order(given, location), 1)
        ]
    if fmt == "highd":
        return [("highd", r, path, None) for r, path in enumerate(inputs.highd_order(given), start=1)]
    raise InputError(
        ", ".join(map(str, given)), f"{fmt} input", expected="raw NGSIM .txt files or highD recordings"
    )


def run_job(job: Job, resample: inputs.Resample | None = None) -> Result:
    """Read one job's datasets and compute their sets' pieces: (source, file, id, rows, pieces)."""
    kind, number, path, location = job
    if kind == "ngsim":
        found, ds = inputs.ngsim_dataset(number, path, location)
        datasets = [(found, path, ds)]
    else:
        if resample is None:
            raise UsageError("--to csp", "highD needs a resampler to 10 Hz", expected="resample=")
        datasets = inputs.highd_recording(number, path, resample)
    return [(src, p, ds.ident, int(ds.vehicle.size), sets.dataset_parts(ds)) for src, p, ds in datasets]


def _results(jobs: list[Job], workers: int, resample: inputs.Resample | None) -> Iterator[Result]:
    run = functools.partial(run_job, resample=resample)
    if workers <= 1 or len(jobs) <= 1:
        yield from map(run, jobs)
        return
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
        yield from pool.map(run, jobs)


def write_csp(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    fmt: str = "ngsim",
    location: str | None = None,
    level: int = 1,
    workers: int = 1,
    resample: inputs.Resample | None = None,
) -> dict[str, Any]:
    """Write the three sets of ``paths`` into the directory ``out``; returns what the manifest holds.

    ``level``: zlib level of the .mat files (0: uncompressed); ``workers``: processes reading and
    computing datasets in parallel (the result is the same); ``resample``: a track table at 10 Hz,
    for highD (``lanecast.pipeline.resample.resample``)."""
    started = time.perf_counter()
    out = check_csp_output(out)
    jobs = plan(paths, fmt, location)
    if not jobs:
        raise InputError(", ".join(map(str, paths)), "no rows", expected="at least one dataset to convert")
    parts = [sets.SetParts() for _ in sets.SET_NAMES]
    described = []
    unit = "file" if fmt == "ngsim" else "recording"
    for result in progress(_results(jobs, workers, resample), desc="csp", total=len(jobs), unit=unit):
        for source, path, ident, rows, pieces in result:
            for whole, piece in zip(parts, pieces, strict=True):
                whole.traj += piece.traj
                whole.tracks += piece.tracks
            described.append({"id": ident, "file": str(path), "source": source, "rows": rows})
    record: dict[str, Any] = {
        "format": "csp",
        "convention": CONVENTIONS[fmt],
        "input_format": fmt,
        "datasets": described,
        "sets": {},
        "files": {},
    }
    with staged_files(out, force=True) as stage:  # check_csp_output refused what lanecast did not write

        def write(name: str, part: sets.SetParts) -> tuple[str, int, int]:
            traj = sets.traj_matrix(part)
            part.traj.clear()
            matfile.save(
                stage / f"{name}.mat", {"traj": traj, "tracks": sets.tracks_cell(part.tracks)}, level
            )
            return name, int(traj.shape[0]), len(part.tracks)

        named = list(zip(sets.SET_NAMES, parts, strict=True))
        # threads: compression and copies release the GIL, so a set compresses while another is built
        with ThreadPoolExecutor(max_workers=max(1, min(workers, len(named)))) as pool:
            done = pool.map(lambda item: write(*item), named)
            for name, rows, vehicles in progress(done, desc="csp: writing", total=len(named), unit="set"):
                record["sets"][name] = {"rows": rows, "vehicles": vehicles}
        record["seconds"] = round(time.perf_counter() - started, 1)
        for name in record["sets"]:
            # the times the files will have in ``out``: os.replace keeps them
            info = (stage / f"{name}.mat").stat()
            record["files"][f"{name}.mat"] = {"size": info.st_size, "mtime_ns": info.st_mtime_ns}
        (stage / MANIFEST).write_text(json.dumps(record, indent=1) + "\n")
    return record
