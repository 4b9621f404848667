"""The datasets of a csp conversion, read from raw NGSIM files or highD recordings.

NGSIM: one dataset per file, columns as ``preprocess_data.m`` takes them from the raw .txt
(Vehicle_ID, Frame_ID, Local_X, Local_Y in feet, Lane_ID; Local_Y is the front bumper, as in the
file). Dataset ids follow the script's order whatever order the files come in: US-101 files first,
then I-80, then any other location, each in name order (NGSIM's names sort by time of day), so
NGSIM's six files get the script's ids 1–6 and any other count of files gets 1…n in that order.
US-101's lanes 6 and above (its auxiliary lane and ramps) become lane 6, as the script does for its
first three files.

highD, by PiP's convention (Song et al., ECCV 2020, ``preprocess_highD.m``, whose datasets are
``NN-fwd.csv`` as id 2r−1 and ``NN-bck.csv`` as id 2r): the r-th recording given (in recording
number order) gives dataset 2r−1 for its lower lanes (drivingDirection 2, travelling along the
image's x axis: "forward") and 2r for its upper lanes (drivingDirection 1, "backward"). Each
direction is resampled to 10 Hz (lanecast's resampler: linear between highD's 25 Hz samples, lane
ids of the nearest earlier sample), so that 30, 40 and 50 rows mean 3, 4 and 5 s as on NGSIM; frames
count 0.1 s from the recording's start. Local_Y is the vehicle's centre along its direction of
travel and Local_X its lateral position, positive to the right, both in feet (PiP also moves
NGSIM-format Local_Y to the centre); lanes are numbered from 1 at the left (the median), as NGSIM's
are, so that a rising lane id is a change to the right in both.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.csp.sets import Dataset
from lanecast.io_adapters.datasets.highd import columns as highd_columns
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd.sniff import recordings as highd_recordings
from lanecast.io_adapters.datasets.ngsim import locations as ngsim_locations
from lanecast.io_adapters.datasets.ngsim.parse import parse_file as ngsim_parse_file
from lanecast.io_adapters.datasets.ngsim.sniff import folder_files as ngsim_folder_files
from lanecast.io_adapters.errors import InputError, UsageError

#: A track table → the same at 10 Hz.
Resample = Callable[[pa.Table], pa.Table]
FT = 0.3048
US101_LAST_LANE = 6
_LOCATION_RANK = {"us-101": 0, "i-80": 1}


def ngsim_files(paths: Sequence[Path]) -> list[Path]:
    """The NGSIM files named by ``paths`` (directories expanded), each once."""
    found: list[Path] = []
    for p in paths:
        listed = ngsim_folder_files(p) if p.is_dir() else [p]
        if not listed:
            raise InputError(p, "no NGSIM files in this directory", expected="NGSIM .txt files")
        found += [f for f in listed if f.resolve() not in {g.resolve() for g in found}]
    return found


def ngsim_order(paths: Sequence[Path], location: str | None = None) -> list[tuple[Path, str]]:
    """(file, location) of every NGSIM file, in dataset id order: by the location ``--location`` or
    the file's name (or folder) gives, then by name."""
    forced = ngsim_locations.normalise_location(location) if location else None
    files = [(p, forced or ngsim_locations.location_from_path(p)[0]) for p in ngsim_files(paths)]
    return sorted(files, key=lambda f: (_LOCATION_RANK.get(f[1], 2), f[0].name, str(f[0])))


def ngsim_dataset(ident: int, path: Path, location: str | None = None) -> tuple[str, Dataset]:
    """(location, dataset ``ident``) of one NGSIM file."""
    p = ngsim_parse_file(path, ngsim_locations.normalise_location(location) if location else None)
    if len(p.locations) != 1:
        raise UsageError(
            "--location",
            f"{path} holds rows of {len(p.locations)} locations ({', '.join(p.locations)})",
            expected="--location naming the one to convert",
        )
    cols = p.columns
    vehicle = cols["vehicle_id"]
    bad = np.flatnonzero(vehicle < 1)
    if bad.size:
        header = 0 if p.path.suffix.lower() == ".txt" else 1
        raise InputError(
            p.path,
            f"vehicle id {vehicle[bad[0]]:g}",
            line=int(bad[0]) + 1 + header,
            column="Vehicle_ID",
            expected="ids of 1 or more (the .mat files index a cell array by them)",
        )
    lane = cols["lane_id"].astype(np.float32)
    if p.locations[0] == "us-101":
        lane[lane >= US101_LAST_LANE] = US101_LAST_LANE
    f32 = np.float32
    return p.locations[0], Dataset(
        ident,
        str(p.path),
        vehicle.astype(f32),
        cols["frame_id"].astype(f32),
        cols["local_x"].astype(f32),
        cols["local_y"].astype(f32),
        lane,
    )


def ngsim_datasets(paths: Sequence[Path], location: str | None = None) -> list[tuple[str, Path, Dataset]]:
    """(location, file, dataset) per NGSIM file, in dataset id order (read one after the other)."""
    out = []
    for ident, (path, _) in enumerate(ngsim_order(paths, location), start=1):
        found, ds = ngsim_dataset(ident, path, location)
        out.append((found, path, ds))
    return out


def highd_order(paths: Sequence[Path]) -> list[Path]:
    """The tracks files of the highD recordings named by ``paths``, in recording order."""
    return [rec.path("tracks") for rec in sorted(highd_recordings(paths), key=lambda r: r.prefix)]


def highd_datasets(paths: Sequence[Path], resample: Resample) -> list[tuple[str, Path, Dataset]]:
    """(recording direction, tracks file, dataset) per highD driving direction, by PiP's ids."""
    return [
        d for r, path in enumerate(highd_order(paths), start=1) for d in highd_recording(r, path, resample)
    ]


def highd_recording(r: int, tracks_csv: Path, resample: Resample) -> list[tuple[str, Path, Dataset]]:
    """The datasets 2r−1 (lower lanes) and 2r (upper lanes) of one highD recording; ``resample``:
    the track table at 10 Hz (``lanecast.pipeline.resample.resample``, handed in by the command:
    io_adapters imports no pipeline stage)."""
    out = []
    for rec in highd_recordings([tracks_csv]):
        table = resample(highd.read([rec.path("tracks")]))
        meta = track_table.read_meta(table)
        names = table.column("recording").to_numpy(zero_copy_only=False).astype(str)
        for ident, direction in ((2 * r - 1, highd_columns.LOWER), (2 * r, highd_columns.UPPER)):
            name = next(
                (n for n, m in meta.recordings.items() if m.extra.get("driving_direction") == direction), None
            )
            if name is None:
                continue
            rows = names == name
            lane_id = table.column("lane_id").to_numpy(zero_copy_only=False)[rows]
            y = table.column("y").to_numpy()[rows]
            lane_id = np.nan_to_num(lane_id.astype(np.float64), nan=0.0).astype(np.int64)
            known = np.unique(lane_id[lane_id > 0])
            left_first = known[np.argsort([-y[lane_id == k].mean() for k in known])]
            lane = np.zeros(lane_id.size, dtype=np.float32)
            for number, k in enumerate(left_first, start=1):
                lane[lane_id == k] = number
            ds = Dataset(
                ident,
                f"{rec.path('tracks')} ({name})",
                table.column("track_id").to_numpy()[rows].astype(np.float32),
                table.column("frame").to_numpy()[rows].astype(np.float32),
                (-y / FT).astype(np.float32),
                (table.column("x").to_numpy()[rows] / FT).astype(np.float32),
                lane,
            )
            out.append((name, rec.path("tracks"), ds))
    return out
