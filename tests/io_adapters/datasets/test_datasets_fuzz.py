"""Seeded structural and semantic mutations of small dataset files, through the real CLI.

Each case writes real files in ``tmp_path`` (a highD recording as highD publishes it, an NGSIM
US-101 .txt, the real Peachtree CSV rows, a Parquet track table), applies one mutation drawn with
a fixed seed from a family (files that disagree with each other, quirks of real exports, defects of
one cell or row), and runs ``lanecast convert``, ``info`` or ``windows`` on it. The outcome must be
one of:

* ``same``: a quirk that must not change the data (line endings, a BOM, column order, rows in
  another order, quoting, an extra column): exit 0 and the output equal to the clean input's;
* ``refuse``: a defect: exit 2 and one ``lanecast <cmd>: error:`` line naming the file and where
  (line, row, column or offset) and what was expected; no traceback; nothing left behind.

The seed fixes every drawn parameter (the track, the row, the permutation): a failure reproduces
with its test id.
"""

from __future__ import annotations

import json
import random
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from conftest import TESTS

from lanecast.io_adapters.contracts import track_table
from lanecast.workflows.cli import main as cli_main

SEED = 20261202


DATA = TESTS / "data"


PEACHTREE = DATA / "ngsim" / "peachtree_sample.csv"


TRACKS, TRACKS_META, RECORDING_META = "01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"


LOCATION = re.compile(r"\b(line|row|offset|window) \d+|column '")


# ------------------------------------------------------------------------------ clean inputs

TRACK_COLUMNS = (
    "frame,id,x,y,width,height,xVelocity,yVelocity,xAcceleration,yAcceleration,frontSightDistance,"
    "backSightDistance,dhw,thw,ttc,precedingXVelocity,precedingId,followingId,leftPrecedingId,"
    "leftAlongsideId,leftFollowingId,rightPrecedingId,rightAlongsideId,rightFollowingId,laneId"
).split(",")


META_COLUMNS = (
    "id,width,height,initialFrame,finalFrame,numFrames,class,drivingDirection,traveledDistance,"
    "minXVelocity,maxXVelocity,meanXVelocity,minDHW,minTHW,minTTC,numLaneChanges"
).split(",")


UPPER_MARKINGS, LOWER_MARKINGS = (8.0, 11.75, 15.5, 19.25), (23.25, 27.0, 30.75, 34.5)


def write_highd(folder: Path) -> Path:
    """Recording 01 as highD publishes it: 25 Hz, 4 vehicles per direction for 12 s each, x/y the
    bounding box's upper-left corner (y down), upper lanes (drivingDirection 1) towards -x, laneIds
    2-4 upper and 6-8 lower; vehicle 2 changes from lane 6 to lane 7."""
    folder.mkdir(parents=True)
    tracks, metas = [",".join(TRACK_COLUMNS)], [",".join(META_COLUMNS)]
    for vid in range(1, 9):
        upper = vid > 4
        lane = (vid - 1) % 3
        lanes = UPPER_MARKINGS if upper else LOWER_MARKINGS
        first, n = 1 + 20 * (vid - 1), 300
        length, width = (12.0, 2.5) if vid % 4 == 0 else (4.5, 1.9)
        speed = 27.0 + vid
        frames = np.arange(first, first + n)
        t = (frames - first) / 25
        centre = (lanes[lane] + lanes[lane + 1]) / 2 + np.zeros(n)
        if vid == 2:  # a lane change over 4 s
            shift = np.clip((t - 4) / 4, 0, 1)
            centre = centre + shift * (lanes[2] - lanes[1])
        x = (380.0 - speed * t) if upper else (20.0 + speed * t)
        lane_id = (2 if upper else 6) + lane + (centre > lanes[lane + 1]).astype(int)
        vy = np.gradient(centre, 1 / 25)
        for k in range(n):
            cells = [
                frames[k], vid, f"{x[k]:.2f}", f"{centre[k] - width / 2:.2f}",
                length, width, f"{-speed if upper else speed:.2f}", f"{vy[k]:.4f}", 0, 0, 100, 100,
                0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, lane_id[k],
            ]  # fmt: skip
            tracks.append(",".join(str(c) for c in cells))
        cls = "Truck" if vid % 4 == 0 else "Car"
        changes = 1 if vid == 2 else 0
        metas.append(
            f"{vid},{length},{width},{first},{first + n - 1},{n},{cls},{1 if upper else 2},{speed * 12:.2f},"
            f"{speed},{speed},{speed},-1,-1,-1,{changes}"
        )
    (folder / TRACKS).write_text("\n".join(tracks) + "\n")
    (folder / TRACKS_META).write_text("\n".join(metas) + "\n")
    (folder / RECORDING_META).write_text(
        "id,frameRate,locationId,speedLimit,month,weekDay,startTime,duration,totalDrivenDistance,"
        "totalDrivenTime,numVehicles,numCars,numTrucks,upperLaneMarkings,lowerLaneMarkings\n"
        f"1,25,2,-1.00,09.2017,Tue,08:38,20.0,2600.0,96.0,8,6,2,"
        f"{';'.join(f'{m:.2f}' for m in UPPER_MARKINGS)},{';'.join(f'{m:.2f}' for m in LOWER_MARKINGS)}\n"
    )
    return folder


def write_us101(path: Path) -> Path:
    """An NGSIM US-101 .txt (18 whitespace-separated columns, feet, 10 Hz): 6 vehicles on 3 lanes,
    10 s each."""
    rows = []
    for vid in range(1, 7):
        lane = (vid - 1) % 3 + 1
        for k in range(100):
            f = 10 + 5 * vid + k
            y = 40.0 * vid + 6.0 * k
            rows.append(
                f"{vid:4d} {f:5d} {100:5d} {1118846980000 + 100 * f} {6 + 12 * (lane - 1):8.3f} {y:9.3f} "
                f"6451155.641 {1873444.255 + y:.3f} {15.0:5.1f} {6.0:4.1f} 2 {60.0:6.2f} {0.0:5.2f} {lane} "
                f"0 0 0.00 0.00"
            )
    path.write_text("\n".join(rows) + "\n")
    return path


@dataclass(frozen=True)
class Inputs:
    highd: Path
    us101: Path
    peachtree: Path
    table: Path
    clean: dict[str, pa.Table]  # input kind -> its clean conversion
    clean_windows: dict[str, np.ndarray]


def run_cli(argv: list[str], cwd: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``lanecast argv`` run in ``cwd`` (exit status, stderr); any exception escaping the CLI is a
    traceback a user would see, and fails the test."""
    capsys.readouterr()
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(cwd)
        try:
            status = cli_main(argv)
        except SystemExit as exc:
            status = int(exc.code or 0)
    return status, capsys.readouterr().err


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Inputs:
    root = tmp_path_factory.mktemp("clean")
    highd = write_highd(root / "highd")
    us101 = write_us101(root / "us-101-fuzz.txt")
    peachtree = root / PEACHTREE.name
    shutil.copy(PEACHTREE, peachtree)
    clean: dict[str, pa.Table] = {}
    for kind, src in (("highd", highd), ("txt", us101), ("csv", peachtree)):
        assert cli_main(["convert", str(src), "--out", str(root / f"{kind}.parquet")]) == 0
        clean[kind] = pq.read_table(root / f"{kind}.parquet")
    clean["parquet"] = clean["highd"]
    assert cli_main(["windows", str(root / "highd.parquet"), "--out", str(root / "win")]) == 0
    win = {name: np.load(root / "win" / f"{name}.npy") for name in ("inputs", "future", "maneuver")}
    assert len(win["inputs"]) > 20
    return Inputs(highd, us101, peachtree, root / "highd.parquet", clean, win)


# ------------------------------------------------------------------------------ mutations


def rows_of(path: Path) -> list[list[str]]:
    return [line.split(",") for line in path.read_text().splitlines()]


def write_rows(path: Path, rows: list[list[str]]) -> None:
    path.write_text("".join(",".join(r) + "\n" for r in rows))


def edit_csv(fn: Callable[[list[list[str]]], list[list[str]] | None]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        rows = rows_of(path)
        write_rows(path, fn(rows) or rows)

    return apply


def edit_bytes(fn: Callable[[bytes], bytes]) -> Callable[[Path], None]:
    return lambda path: path.write_bytes(fn(path.read_bytes()))


def set_cell(row_pick: Callable[[list[list[str]]], int], column: str, value: str) -> Callable[[Path], None]:
    def fn(rows: list[list[str]]) -> None:
        rows[row_pick(rows)][rows[0].index(column)] = value

    return edit_csv(fn)


def txt_edit(fn: Callable[[list[list[str]]], list[list[str]]], sep: str = " ") -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        rows = [line.split() for line in path.read_text().splitlines()]
        path.write_text("".join(sep.join(r) + "\n" for r in fn(rows)))

    return apply


def txt_cell(row: int, field: int, value: str) -> Callable[[list[list[str]]], list[list[str]]]:
    """Field ``field`` (0-based) of data row ``row`` of a .txt set to ``value``."""

    def fn(rows: list[list[str]]) -> list[list[str]]:
        rows[row][field] = value
        return rows

    return fn


def pq_edit(fn: Callable[[pa.Table], pa.Table], **write: object) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        pf = pq.ParquetFile(path)
        table = pf.read().replace_schema_metadata(track_table.file_schema(pf).metadata)
        pq.write_table(fn(table), path, **write)  # type: ignore[arg-type]

    return apply


def shuffled_columns(seed: float) -> Callable[[list[list[str]]], list[list[str]]]:
    def fn(rows: list[list[str]]) -> list[list[str]]:
        perm = list(range(len(rows[0])))
        random.Random(seed).shuffle(perm)
        return [[row[j] for j in perm] for row in rows]

    return fn


def shuffled_rows(seed: float, header: bool) -> Callable[[list[list[str]]], list[list[str]]]:
    def fn(rows: list[list[str]]) -> list[list[str]]:
        head, body = (rows[:1], rows[1:]) if header else ([], rows)
        body = list(body)
        random.Random(seed).shuffle(body)
        return head + body

    return fn


def with_unit(unit: str) -> Callable[[pa.Table], pa.Table]:
    def fn(t: pa.Table) -> pa.Table:
        fields = [f.with_metadata({b"unit": unit.encode()}) if f.name in ("x", "y") else f for f in t.schema]
        return pa.Table.from_arrays(t.columns, schema=pa.schema(fields, metadata=t.schema.metadata))

    return fn


def shuffled_table(seed: int) -> Callable[[pa.Table], pa.Table]:
    return lambda t: t.take(pa.array(np.random.default_rng(seed).permutation(t.num_rows)))


def tracks_shuffled(seed: int) -> Callable[[pa.Table], pa.Table]:
    """Each recording's rows in another order, the recordings one after the other."""

    def fn(t: pa.Table) -> pa.Table:
        rec = pc.cast(t.column("recording"), pa.string()).to_numpy(zero_copy_only=False)
        noise = np.random.default_rng(seed).permutation(t.num_rows)
        return t.take(pa.array(np.lexsort((noise, rec))))

    return fn


def retyped(types: dict[str, pa.DataType]) -> Callable[[pa.Table], pa.Table]:
    """Columns in other types that hold the same values (as other tools write them)."""

    def fn(t: pa.Table) -> pa.Table:
        for name, type_ in types.items():
            i = t.schema.get_field_index(name)
            t = t.set_column(i, t.schema.field(i).with_type(type_), t.column(i).cast(type_))
        return t

    return fn


def row_twice(at: float) -> Callable[[pa.Table], pa.Table]:
    return lambda t: pa.concat_tables([t, t.slice(int(at * t.num_rows), 1)])


def null_at(column: str, at: float) -> Callable[[pa.Table], pa.Table]:
    def fn(t: pa.Table) -> pa.Table:
        values = t.column(column).to_pylist()
        values[int(at * len(values))] = None
        i = t.schema.get_field_index(column)
        f = t.schema.field(i).with_nullable(True)
        return t.set_column(i, f, pa.array(values, type=f.type))

    return fn


@dataclass(frozen=True)
class Case:
    family: str
    what: str
    kind: str  # highd | txt | csv | parquet
    victim: str  # the file mutated (relative to the case folder)
    mutate: Callable[[Path], None]
    expect: str  # same | refuse
    cmd: str = "convert"
    names: str | None = None  # the file the error must name (default: victim)


def cases() -> list[Case]:
    """The seeded mutations (one draw of every parameter from SEED)."""
    r = random.Random(SEED)
    track = r.randrange(1, 9)  # a vehicle of the highD recording
    meta_line = lambda rows: next(i for i, row in enumerate(rows) if i and row[0] == str(track))  # noqa: E731
    data_line = lambda at: lambda rows: 1 + int(at * (len(rows) - 1))  # noqa: E731  (a data row)
    hd = "in"
    out: list[Case] = [
        # highD: quirks of real exports that must not change the data
        Case("highd-format", "CRLF line ends", "highd", f"{hd}/{TRACKS}", edit_bytes(lambda b: b.replace(b"\n", b"\r\n")), "same"),
        Case("highd-format", "a BOM", "highd", f"{hd}/{TRACKS_META}", edit_bytes(lambda b: b"\xef\xbb\xbf" + b), "same"),
        Case("highd-format", "a BOM and CRLF in recordingMeta", "highd", f"{hd}/{RECORDING_META}",
             edit_bytes(lambda b: b"\xef\xbb\xbf" + b.replace(b"\n", b"\r\n")), "same", cmd="windows"),
        Case("highd-format", "tracks columns in another order", "highd", f"{hd}/{TRACKS}", edit_csv(shuffled_columns(r.random())), "same"),
        Case("highd-format", "tracksMeta columns in another order", "highd", f"{hd}/{TRACKS_META}", edit_csv(shuffled_columns(r.random())), "same"),
        Case("highd-format", "an extra unknown column", "highd", f"{hd}/{TRACKS}",
             edit_csv(lambda rows: [[*rows[0], "comment"], *([*row, "x"] for row in rows[1:])]), "same"),
        Case("highd-format", "every tracksMeta cell quoted", "highd", f"{hd}/{TRACKS_META}",
             edit_csv(lambda rows: [[f'"{c}"' for c in row] for row in rows]), "same"),
        Case("highd-format", "a trailing comma on every line", "highd", f"{hd}/{TRACKS}",
             edit_bytes(lambda b: b.replace(b"\n", b",\n")), "same"),
        # highD: files that disagree with each other
        Case("highd-consistency", f"track {track} missing from tracksMeta", "highd", f"{hd}/{TRACKS_META}",
             edit_csv(lambda rows: [row for i, row in enumerate(rows) if i != meta_line(rows)]), "refuse", names="01_"),
        Case("highd-consistency", f"numFrames of track {track} off by one", "highd", f"{hd}/{TRACKS_META}",
             edit_csv(lambda rows: rows[meta_line(rows)].__setitem__(5, str(int(rows[meta_line(rows)][5]) + 1))),
             "refuse", cmd="info", names="01_"),
        Case("highd-consistency", f"finalFrame of track {track} past its frames", "highd", f"{hd}/{TRACKS_META}",
             edit_csv(lambda rows: rows[meta_line(rows)].__setitem__(4, str(int(rows[meta_line(rows)][4]) + 25))),
             "refuse", names="01_"),
        Case("highd-consistency", "drivingDirection 3", "highd", f"{hd}/{TRACKS_META}",
             set_cell(meta_line, "drivingDirection", "3"), "refuse"),
        Case("highd-consistency", "a blank class", "highd", f"{hd}/{TRACKS_META}", set_cell(meta_line, "class", " "), "refuse"),
        Case("highd-consistency", "frameRate 0", "highd", f"{hd}/{RECORDING_META}", set_cell(lambda rows: 1, "frameRate", "0"), "refuse"),
        Case("highd-consistency", "recordingMeta of recording 2 under 01's name", "highd", f"{hd}/{RECORDING_META}",
             set_cell(lambda rows: 1, "id", str(r.choice([2, 17, 60]))), "refuse", cmd=r.choice(["convert", "windows"])),
        Case("highd-consistency", "a frame repeated with another x", "highd", f"{hd}/{TRACKS}",
             edit_csv(lambda rows: [*rows[:200], [*rows[199][:2], "999.0", *rows[199][3:]], *rows[200:]]), "refuse"),
        Case("highd-consistency", "laneId 0", "highd", f"{hd}/{TRACKS}", set_cell(data_line(r.random()), "laneId", "0"), "refuse"),
        Case("highd-cell", "x is 'nan'", "highd", f"{hd}/{TRACKS}", set_cell(data_line(r.random()), "x", "nan"), "refuse"),
        Case("highd-cell", "a decimal comma", "highd", f"{hd}/{TRACKS}", set_cell(data_line(r.random()), "y", '"31,5"'), "refuse"),
        # NGSIM .txt
        Case("ngsim-txt", "tab-separated", "txt", "us-101-fuzz.txt", txt_edit(lambda rows: rows, sep="\t"), "same"),
        Case("ngsim-txt", "rows shuffled", "txt", "us-101-fuzz.txt", txt_edit(shuffled_rows(r.random(), header=False)), "same"),
        Case("ngsim-txt", "an all-zero row", "txt", "us-101-fuzz.txt",
             txt_edit(lambda rows: [*rows[:50], ["0"] * 18, *rows[50:]]), "refuse"),
        Case("ngsim-txt", "Global_Time 5 s back on one row", "txt", "us-101-fuzz.txt",
             txt_edit(lambda rows: [*rows[:70], [*rows[70][:3], str(int(rows[70][3]) - 5000), *rows[70][4:]], *rows[71:]]),
             "refuse"),
        Case("ngsim-txt", "a vehicle driving backwards on US-101", "txt", "us-101-fuzz.txt",
             txt_edit(lambda rows: [[*row[:5], f"{3000 - float(row[5]):.3f}", *row[6:]] if row[0] == "4" else row for row in rows]),
             "refuse"),
        Case("ngsim-txt", "v_Vel not a number", "txt", "us-101-fuzz.txt",
             txt_edit(lambda rows: [*rows[:33], [*rows[33][:11], "fast", *rows[33][12:]], *rows[34:]]), "refuse", cmd="info"),
        Case("ngsim-txt", "Lane_ID -1 on one row", "txt", "us-101-fuzz.txt",
             txt_edit(txt_cell(r.randrange(600), 13, "-1")),
             "refuse"),
        # NGSIM CSV (real Peachtree rows)
        Case("ngsim-csv", "CRLF line ends", "csv", PEACHTREE.name, edit_bytes(lambda b: b.replace(b"\n", b"\r\n")), "same"),
        Case("ngsim-csv", "two trailing empty columns", "csv", PEACHTREE.name, edit_bytes(lambda b: b.replace(b"\n", b",,\n")), "same"),
        Case("ngsim-csv", "rows shuffled", "csv", PEACHTREE.name, edit_csv(shuffled_rows(r.random(), header=True)), "same"),
        Case("ngsim-csv", "v_Vel 'abc'", "csv", PEACHTREE.name, set_cell(data_line(r.random()), "v_Vel", "abc"), "refuse"),
        Case("ngsim-csv", "Location blank", "csv", PEACHTREE.name, set_cell(data_line(r.random()), "Location", ""), "refuse"),
        # Parquet track tables
        Case("parquet", "rows in another order", "parquet", "in.parquet",
             pq_edit(shuffled_table(r.randrange(1 << 30))),
             "same", cmd=r.choice(["convert", "windows"])),
        Case("parquet", "tracks of each recording in another order", "parquet", "in.parquet",
             pq_edit(tracks_shuffled(r.randrange(1 << 30))), "same", cmd="windows"),
        Case("parquet", "recording as plain strings, frame as int32", "parquet", "in.parquet",
             pq_edit(retyped({"recording": pa.string(), "frame": pa.int32()})), "same", cmd=r.choice(["convert", "windows"])),
        Case("parquet", "row groups of 7 rows", "parquet", "in.parquet", pq_edit(lambda t: t, row_group_size=7), "same"),
        Case("parquet", "a (track, frame) twice", "parquet", "in.parquet",
             pq_edit(row_twice(r.random())), "refuse"),
        Case("parquet", "x null", "parquet", "in.parquet", pq_edit(null_at("x", r.random())), "refuse"),
        Case("parquet", "positions in feet", "parquet", "in.parquet", pq_edit(with_unit("ft")), "refuse", cmd="info"),
        Case("parquet", "track_id as float64", "parquet", "in.parquet",
             pq_edit(lambda t: t.set_column(1, "track_id", pc.cast(t.column("track_id"), pa.float64()))), "refuse"),
    ]  # fmt: skip
    return out


CASES = cases()


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _setup(case: Case, inputs: Inputs, folder: Path) -> str:
    """The case's input in ``folder``, mutated; returns the CLI's input argument."""
    if case.kind == "highd":
        shutil.copytree(inputs.highd, folder / "in")
        target = "in"
    else:
        src = {"txt": inputs.us101, "csv": inputs.peachtree, "parquet": inputs.table}[case.kind]
        target = case.victim
        shutil.copy(src, folder / target)
    case.mutate(folder / case.victim)
    return target


def _equal(got: pa.Table, want: pa.Table) -> str | None:
    """None if the tables hold the same rows and values (dictionaries compared by value)."""
    got, want = got.replace_schema_metadata(None), want.replace_schema_metadata(None)
    if got.num_rows != want.num_rows or got.column_names != want.column_names:
        return f"{got.num_rows} rows {got.column_names} != {want.num_rows} rows {want.column_names}"
    for name in want.column_names:
        a, b = got.column(name), want.column(name)
        if pa.types.is_dictionary(b.type):
            a, b = a.cast(pa.string()), b.cast(pa.string())
        if not a.equals(b):
            return f"column {name} differs"
    return None


@pytest.mark.parametrize("case", CASES, ids=[f"{c.family}:{c.cmd}:{c.what}" for c in CASES])
def test_mutation(case: Case, inputs: Inputs, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = _setup(case, inputs, tmp_path)
    argv = {
        "convert": ["convert", target, "--out", "out.parquet"],
        "info": ["info", target],
        "windows": ["windows", target, "--out", "win"],
    }[case.cmd]
    before = _files(tmp_path)
    status, err = run_cli(argv, tmp_path, capsys)
    assert "Traceback" not in err, err
    if case.expect == "same":
        assert status == 0, f"a valid input was refused: {err.strip()[-400:]}"
        if case.cmd == "convert":
            problem = _equal(pq.read_table(tmp_path / "out.parquet"), inputs.clean[case.kind])
            assert problem is None, f"the data changed: {problem}"
        elif case.cmd == "windows":
            for name, want in inputs.clean_windows.items():
                np.testing.assert_array_equal(np.load(tmp_path / "win" / f"{name}.npy"), want, err_msg=name)
        return
    assert status == 2, f"accepted (exit {status}) a defect: {err.strip()[-400:]}"
    lines = [
        line for line in err.splitlines() if line.strip() and "%|" not in line and "recording/s" not in line
    ]
    last = lines[-1] if lines else ""
    assert last.startswith(f"lanecast {case.cmd}: error: "), err
    message = last.split(": error: ", 1)[1]
    assert (case.names or Path(case.victim).name) in message, message
    assert LOCATION.search(message), f"no line/row/column/offset: {message}"
    assert _files(tmp_path) == before, "a refused run left files behind or changed its input"


def test_the_cases_cover_every_family() -> None:
    """The seeded draw keeps every family and both outcomes (a change of SEED cannot empty one)."""
    families = {(c.family, c.expect) for c in CASES}
    assert {f for f, _ in families} == {
        "highd-format", "highd-consistency", "highd-cell", "ngsim-txt", "ngsim-csv", "parquet"
    }  # fmt: skip
    assert {e for _, e in families} == {"same", "refuse"}
    assert len(CASES) >= 30
    json.dumps([c.what for c in CASES])  # descriptions are plain text (test ids)
