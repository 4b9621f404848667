"""``write_csp``: raw NGSIM files or highD recordings → conv-social-pooling's ``.mat`` sets.

The output directory gets ``TrainSet.mat``, ``ValSet.mat`` and ``TestSet.mat`` (each ``traj`` and
``tracks``, MATLAB 5 format as scipy writes it, zlib-compressed as MATLAB's default ``-v7`` save
is; ``scipy.io.loadmat`` reads them) and ``lanecast-csp.json`` (the dataset ids given to the inputs,
row counts, and the size and modification time of each set, by which a later run knows the files
are its own). All files are staged beside the directory and moved in together: the directory gets
all of a run's files or none. A file of those names that lanecast did not write is refused, never
replaced; other files in the directory are left alone.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.datasets.csp import inputs, sets
from lanecast.io_adapters.errors import InputError, OutputError
from lanecast.io_adapters.files import check_output, progress, staged_files

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


def read_datasets(
    paths: Sequence[str | Path], fmt: str, location: str | None
) -> list[tuple[str, Path, sets.Dataset]]:
    """The datasets of ``paths`` (``fmt`` "ngsim" or "highd"), in dataset id order."""
    given = [Path(p) for p in paths]
    if fmt == "ngsim":
        return inputs.ngsim_datasets(given, location)
    if fmt == "highd":
        return inputs.highd_datasets(given)
    raise InputError(
        ", ".join(map(str, paths)), f"{fmt} input", expected="raw NGSIM .txt files or highD recordings"
    )


def _save(path: Path, traj: np.ndarray, tracks: np.ndarray, compress: bool) -> None:
    from scipy.io import savemat

    with path.open("wb") as fh:
        savemat(fh, {"traj": traj, "tracks": tracks}, do_compression=compress, format="5")


def write_csp(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    fmt: str = "ngsim",
    location: str | None = None,
    compress: bool = True,
) -> dict[str, Any]:
    """Write the three sets of ``paths`` into the directory ``out``; returns what the manifest holds."""
    started = time.perf_counter()
    out = check_csp_output(out)
    datasets = read_datasets(paths, fmt, location)
    if not datasets:
        raise InputError(", ".join(map(str, paths)), "no rows", expected="at least one dataset to convert")
    parts = [sets.SetParts() for _ in sets.SET_NAMES]
    described = []
    for source, path, ds in progress(datasets, desc="csp", unit="dataset"):
        for whole, piece in zip(parts, sets.dataset_parts(ds), strict=True):
            whole.traj += piece.traj
            whole.tracks += piece.tracks
        described.append({"id": ds.ident, "file": str(path), "source": source, "rows": int(ds.vehicle.size)})
    record: dict[str, Any] = {
        "format": "csp",
        "convention": CONVENTIONS[fmt],
        "input_format": fmt,
        "datasets": described,
        "sets": {},
        "files": {},
    }
    with staged_files(out) as stage:
        for name, part in progress(
            list(zip(sets.SET_NAMES, parts, strict=True)), desc="csp: writing", unit="set"
        ):
            traj = sets.traj_matrix(part)
            part.traj.clear()
            _save(stage / f"{name}.mat", traj, sets.tracks_cell(part.tracks), compress)
            record["sets"][name] = {"rows": int(traj.shape[0]), "vehicles": len(part.tracks)}
            del traj
        record["seconds"] = round(time.perf_counter() - started, 1)
        for name in record["sets"]:
            # the times the files will have in ``out``: os.replace keeps them
            info = (stage / f"{name}.mat").stat()
            record["files"][f"{name}.mat"] = {"size": info.st_size, "mtime_ns": info.st_mtime_ns}
        (stage / MANIFEST).write_text(json.dumps(record, indent=1) + "\n")
    return record
