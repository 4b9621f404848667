"""Property-based hostile inputs (hypothesis): valid files of every format, mutated, must give a
clean refusal naming the file or a correct reading; never another exception, a hang or a silent
change.

Seeds: the highD triple, NGSIM .txt and CSV, a Parquet track table, MCAP (chunked protobuf with
CRCs; unchunked JSON), ROS 1 bags, ROS 2 bags (sqlite3 and MCAP storage) and a model card.
Mutations: truncation, byte flips, 8-byte fields overwritten with huge sizes, zeroed runs,
inserted bytes; for text formats, a cell replaced by a hostile token, a line deleted or repeated;
for cards, a field replaced by a value of the wrong type or range.

The oracle per format (what "correct" means for an accepted mutant):

* formats with integrity checks over the data (MCAP with CRCs, ROS 2 MCAP storage with the CRCs
  lanecast writes, Parquet with page checksums, and the ROS 1 and sqlite3 bags lanecast writes,
  whose metadata holds a checksum of every message): the table's columns equal the original's;
* CSV and .txt (highD, NGSIM): every row of a vehicle not named on the mutated line (before or
  after the edit) is present and equal; a recordingMeta edit (frame rate) may change every row;
* formats without checksums (unchunked MCAP whose writer left the data CRC at 0; ROS 1 and
  sqlite3 bags other tools write): the reading is a valid track table; a flipped value cannot be
  told from a real one;
* model cards: a card that loads gives finite forecasts.

Every example runs under a time bound (``LANECAST_FUZZ_SECONDS``, default 30 s). CI runs
``LANECAST_FUZZ_EXAMPLES`` examples per format (default 12); the long campaign is
``LANECAST_FUZZ_EXAMPLES=500 pytest -m slow tests/io_adapters/formats/test_formats_fuzz.py``.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from conftest import REPO, TESTS
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LanecastError
from lanecast.io_adapters.formats import registry

DATA = TESTS / "data"


EXAMPLES = int(os.environ.get("LANECAST_FUZZ_EXAMPLES", "12"))


SECONDS = int(os.environ.get("LANECAST_FUZZ_SECONDS", "30"))


pytestmark = pytest.mark.slow


FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,  # the time bound is the alarm below (a hang fails the example)
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.function_scoped_fixture,
        HealthCheck.data_too_large,
    ],
    derandomize=os.environ.get("LANECAST_FUZZ_RANDOM") is None,  # CI: the same examples every run
    database=None,
)


class Hang(Exception):
    """An example ran past its time bound."""


@contextlib.contextmanager
def time_bound(seconds: int = SECONDS) -> Iterator[None]:
    def alarm(_signum: int, _frame: Any) -> None:
        raise Hang(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def read_or_refuse(paths: list[Path], where: Path, **options: Any) -> pa.Table | None:
    """The table, or None after a clean refusal naming a path inside ``where``; anything else fails."""
    try:
        with time_bound():
            table = registry.read_any(paths, **options)
    except LanecastError as exc:
        assert str(where) in str(exc), f"the refusal does not name the file: {exc}"
        assert "\n" not in str(exc).strip(), f"a refusal is one line: {exc!r}"
        event(f"refused ({type(exc).__name__})")
        return None
    track_table.validate(table)
    event("accepted")
    return table


# ------------------------------------------------------------------------------------- mutations

HUGE = [2**31, 2**32 - 1, 2**40, 2**53 + 1, 2**63 - 1, 2**64 - 1]


@st.composite
def byte_mutation(draw: st.DrawFn, size: int) -> Callable[[bytes], bytes]:
    """A function that mutates bytes of length ``size``: truncate, flip, huge field, zeros, insert."""
    kind = draw(st.sampled_from(["truncate", "flip", "huge", "zeros", "insert"]))
    pos = draw(st.integers(0, max(size - 1, 0)))
    if kind == "truncate":
        return lambda data: data[:pos]
    if kind == "flip":
        flips = draw(
            st.lists(st.tuples(st.integers(0, size - 1), st.integers(1, 255)), min_size=1, max_size=3)
        )

        def flip(data: bytes) -> bytes:
            out = bytearray(data)
            for at, mask in flips:
                out[at] ^= mask
            return bytes(out)

        return flip
    if kind == "huge":
        value = draw(st.sampled_from(HUGE)).to_bytes(8, "little")
        return lambda data: data[:pos] + value + data[pos + 8 :]
    if kind == "zeros":
        length = draw(st.integers(1, 64))
        return lambda data: data[:pos] + bytes(min(length, len(data) - pos)) + data[pos + length :]
    extra = draw(st.binary(min_size=1, max_size=16))
    return lambda data: data[:pos] + extra + data[pos:]


TOKENS = [
    "",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "-0.0",
    "1e30",
    "-1e308",
    "9223372036854775808",
    "9007199254740993",
    "2147483648",
    "abc",
    "1,2",
    '"',
    "\x00",
    "\xff",
    "  ",
]


@st.composite
def line_mutation(
    draw: st.DrawFn, lines: list[str], sep: str
) -> tuple[int, Callable[[list[str]], list[str]]]:
    """(0-based line index, a function mutating the lines): a cell replaced, a line deleted or repeated."""
    index = draw(st.integers(1 if sep == "," else 0, len(lines) - 1))
    kind = draw(st.sampled_from(["cell", "cell", "cell", "delete", "repeat"]))
    if kind == "delete":
        return index, lambda ls: ls[:index] + ls[index + 1 :]
    if kind == "repeat":
        return index, lambda ls: [*ls[: index + 1], ls[index], *ls[index + 1 :]]
    cells = lines[index].split(sep) if sep == "," else lines[index].split()
    column = draw(st.integers(0, len(cells) - 1))
    token = draw(st.one_of(st.sampled_from(TOKENS), st.text(max_size=12)))

    def edit(ls: list[str]) -> list[str]:
        row = ls[index].split(sep) if sep == "," else ls[index].split()
        row[column] = token
        return [*ls[:index], (sep if sep == "," else "  ").join(row), *ls[index + 1 :]]

    return index, edit


def rows_by_key(table: pa.Table) -> dict[tuple[str, int, int], tuple[Any, ...]]:
    names = [n for n in table.column_names if n != "recording"]
    rec = table.column("recording").cast(pa.string()).to_pylist()
    cols = [table.column(n).to_pylist() for n in names]
    return {(r, row[0], row[1]): row for r, row in zip(rec, zip(*cols, strict=True), strict=True)}


def assert_unchanged_except(original: pa.Table, mutated: pa.Table, vehicles: set[int]) -> None:
    """Rows of every vehicle not in ``vehicles`` are present in ``mutated`` and equal."""
    before, after = rows_by_key(original), rows_by_key(mutated)
    for key, row in before.items():
        if key[1] in vehicles:
            continue
        assert key in after, f"row {key} vanished"
        assert after[key] == row, f"row {key} changed"


def line_ids(line: str, sep: str, column: int) -> set[int]:
    cells = line.split(sep) if sep == "," else line.split()
    out = set()
    with contextlib.suppress(ValueError, IndexError, OverflowError):
        out.add(int(float(cells[column])) if "." in cells[column] else int(cells[column]))
    return out


# ------------------------------------------------------------------------------------------- seeds


class Seeds(dict[str, Any]):
    """The seed files (a short repr: hypothesis prints it with every failing example)."""

    def __repr__(self) -> str:
        return "seeds"


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> Seeds:
    from lanecast.io_adapters.logs.mcap import writer as mcap_writer
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    root = tmp_path_factory.mktemp("seeds")
    us101 = registry.read_any([DATA / "ngsim" / "us-101" / "trajectories-fixture.txt"])
    peach = root / "peachtree.csv"
    peach.write_text(
        "\n".join((DATA / "ngsim" / "peachtree_sample.csv").read_text().splitlines()[:400]) + "\n"
    )
    out = Seeds(us101=us101, peachtree_csv=peach)
    out["parquet"] = track_table.write_parquet(us101, root / "t.parquet")
    out["mcap"] = mcap_writer.write(us101, root / "chunked.mcap", "mcap", chunk_size=600)
    out["mcap_json"] = _unchunked_json_mcap(us101, root / "json.mcap")
    out["ros1"] = rosbag_writer.write(us101, root / "bag1.bag", "ros1")
    out["ros2_sqlite3"] = rosbag_writer.write(us101, root / "bag_sqlite", "ros2", storage="sqlite3")
    out["ros2_mcap"] = rosbag_writer.write(us101, root / "bag_mcap", "ros2", storage="mcap")
    return out


def _unchunked_json_mcap(table: pa.Table, path: Path) -> Path:
    """The table as JSON SceneUpdates in an unchunked MCAP (records straight in the data section)."""
    from mcap.writer import Writer

    schema = (REPO / "io_adapters/data/foxglove/jsonschema/SceneUpdate.json").read_bytes()
    t = table.to_pydict()
    times = sorted(set(t["time_ns"]))
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        cid = w.register_channel(
            "/objects", "json", w.register_schema("foxglove.SceneUpdate", "jsonschema", schema)
        )
        for stamp in times:
            entities = [
                {
                    "frame_id": "map",
                    "id": str(t["track_id"][i]),
                    "metadata": [{"key": "class", "value": "car"}],
                    "cubes": [
                        {
                            "pose": {
                                "position": {"x": t["x"][i], "y": t["y"][i], "z": 0},
                                "orientation": {"w": 1},
                            },
                            "size": {"x": t["length"][i], "y": t["width"][i], "z": 1.5},
                        }
                    ],
                }
                for i in range(len(t["time_ns"]))
                if t["time_ns"][i] == stamp
            ]
            w.add_message(
                cid, log_time=stamp, data=json.dumps({"entities": entities}).encode(), publish_time=stamp
            )
        w.finish()
    return path


@contextlib.contextmanager
def workdir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="lanecast-fuzz-") as d:
        yield Path(d)


# ----------------------------------------------------------------------------- binary formats


def _binary_case(seed: Path, draw: st.DrawFn, checked: bool, **options: Any) -> None:
    """Mutate one file of ``seed`` (a file, or a bag directory's storage file) and check the oracle."""
    original = registry.read_any([seed], **options)
    with workdir() as d:
        target = d / seed.name
        if seed.is_dir():
            shutil.copytree(seed, target)
            victim = next(p for p in sorted(target.iterdir()) if p.suffix in (".mcap", ".db3"))
        else:
            shutil.copyfile(seed, target)
            victim = target
        data = victim.read_bytes()
        mutated = draw(byte_mutation(len(data)))(data)
        victim.write_bytes(mutated)
        table = read_or_refuse([target], d, **options)
        if table is not None and checked and mutated != data:
            for name in original.column_names:
                if name == "recording":
                    continue
                assert table.column(name).to_pylist() == original.column(name).to_pylist(), (
                    f"accepted a mutant with a different {name!r}"
                )


@FUZZ
@given(data=st.data())
def test_fuzz_parquet(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["parquet"], data.draw, checked=True)


@FUZZ
@given(data=st.data())
def test_fuzz_mcap_chunked_protobuf(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["mcap"], data.draw, checked=True)


@FUZZ
@given(data=st.data())
def test_fuzz_mcap_unchunked_json(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["mcap_json"], data.draw, checked=False)


@FUZZ
@given(data=st.data())
def test_fuzz_ros1_bag(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["ros1"], data.draw, checked=True)


@FUZZ
@given(data=st.data())
def test_fuzz_ros2_sqlite3_bag(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["ros2_sqlite3"], data.draw, checked=True)


@FUZZ
@given(data=st.data())
def test_fuzz_ros2_mcap_bag(seeds: dict[str, Any], data: st.DataObject) -> None:
    _binary_case(seeds["ros2_mcap"], data.draw, checked=True)


# ------------------------------------------------------------------------------- text formats


def _text_case(files: dict[str, Path], victim: str, draw: st.DrawFn, id_column: int | None) -> None:
    """Copy ``files`` (name → source) into a work dir, mutate the lines of ``victim`` and check."""
    original = registry.read_any([files[victim]])
    with workdir() as d:
        for name, src in files.items():
            target = d / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, target)
        path = d / victim
        raw = path.read_bytes()
        if draw(st.booleans()):  # a byte-level mutation of the text
            path.write_bytes(draw(byte_mutation(len(raw)))(raw))
            vehicles = None
        else:
            lines = raw.decode().splitlines()
            sep = "," if path.suffix == ".csv" else " "
            index, edit = draw(line_mutation(lines, sep))
            new = edit(lines)
            path.write_text("\n".join(new) + "\n", errors="surrogateescape")
            vehicles = set()
            if id_column is not None:
                vehicles = line_ids(lines[index], sep, id_column)
                if index < len(new):
                    vehicles |= line_ids(new[index], sep, id_column)
        table = read_or_refuse([path], d)
        if table is not None and vehicles is not None and id_column is not None:
            assert_unchanged_except(original, table, vehicles)


@FUZZ
@given(data=st.data(), victim=st.sampled_from(["01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"]))
def test_fuzz_highd(data: st.DataObject, victim: str) -> None:
    files = {p.name: p for p in (DATA / "highd").glob("01_*.csv")}
    id_column = {"01_tracks.csv": 1, "01_tracksMeta.csv": 0}.get(victim)
    _text_case(files, victim, data.draw, id_column)


@FUZZ
@given(data=st.data())
def test_fuzz_ngsim_txt(data: st.DataObject) -> None:
    files = {"us-101/trajectories-fixture.txt": DATA / "ngsim" / "us-101" / "trajectories-fixture.txt"}
    _text_case(files, "us-101/trajectories-fixture.txt", data.draw, 0)


@FUZZ
@given(data=st.data())
def test_fuzz_ngsim_csv(seeds: dict[str, Any], data: st.DataObject) -> None:
    _text_case({"peachtree.csv": seeds["peachtree_csv"]}, "peachtree.csv", data.draw, 0)


# -------------------------------------------------------------------------------- model cards

HOSTILE_VALUES: list[Any] = [None, "1", -1, 0, 2**40, 1e308, [], {}, True, "x" * 300, [[[[]]]], -0.0, 1.5]


def _leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    if isinstance(doc, dict):
        return [p for k, v in doc.items() for p in _leaves(v, (*path, k))] + ([path] if path else [])
    if isinstance(doc, list) and doc:
        return [p for i, v in enumerate(doc) for p in _leaves(v, (*path, i))] + [path]
    return [path]


@FUZZ
@given(data=st.data())
def test_fuzz_model_card(data: st.DataObject) -> None:
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR
    from lanecast.models.checkpoint import load_checkpoint
    from lanecast.models.predict import STCNNForecaster

    card = json.loads((WEIGHTS_DIR / f"{SHIPPED_STEM}.json").read_text())
    sections = {k: card[k] for k in ("format", "format_version", "architecture", "normalisation")}
    path = data.draw(st.sampled_from(sorted(_leaves(sections), key=str)))
    value = data.draw(st.one_of(st.sampled_from(HOSTILE_VALUES), st.floats(allow_nan=True)))
    node = card
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with workdir() as d:
        (d / "m.safetensors").write_bytes((WEIGHTS_DIR / f"{SHIPPED_STEM}.safetensors").read_bytes())
        (d / "m.json").write_text(json.dumps(card))
        try:
            with time_bound():
                net, loaded = load_checkpoint(d)
        except LanecastError as exc:
            assert str(d) in str(exc)
            event(f"refused ({type(exc).__name__})")
            return
        event("accepted")
        rng = np.random.default_rng(0)
        inputs = rng.normal(0, 20, (8, 4, 8, 30)).astype(np.float32)
        preds = STCNNForecaster(net, loaded).predict(inputs, np.ones((8, 8, 30), bool), top_k=2)
        assert np.isfinite(preds.offsets).all() and np.isfinite(preds.probs).all()


# ------------------------------------------------------------------------- annotate (log copy)


@FUZZ
@given(data=st.data())
def test_fuzz_annotate_mcap(seeds: Seeds, data: st.DataObject) -> None:
    """`annotate` reads a log, then copies every record: a mutant is refused naming the file, or
    the annotated copy reads back as the same tracks (the seed's chunks carry CRCs)."""
    from lanecast.io_adapters.logs.mcap import reader as mcap_reader
    from lanecast.workflows.annotation.annotate_log import annotate_log

    original = mcap_reader.read(seeds["mcap"])
    with workdir() as d:
        src = d / "in.mcap"
        raw = seeds["mcap"].read_bytes()
        src.write_bytes(data.draw(byte_mutation(len(raw)))(raw))
        try:
            with time_bound():
                annotate_log(src, d / "out.mcap")
        except LanecastError as exc:
            assert str(d) in str(exc), f"the refusal does not name the file: {exc}"
            event(f"refused ({type(exc).__name__})")
            return
        event("accepted")
        back = mcap_reader.read(d / "out.mcap")
        for name in ("track_id", "frame", "x", "y", "length", "width"):
            assert back.column(name).to_pylist() == original.column(name).to_pylist()
