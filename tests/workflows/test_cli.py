"""One CLI vocabulary: --out for every output, --model alike everywhere, defaults in --help,
--version, and a closed stdout (`| head`) that ends quietly."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO

from lanecast import __version__
from lanecast.workflows import cli
from lanecast.workflows.vocabulary import MODEL_HELP

WRITERS = ("demo", "simulate", "convert", "windows", "train", "evaluate", "annotate", "report")


def help_of(command: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as done:
        cli.main([command, "--help"])
    assert done.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # one line: argparse wraps help text anywhere


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert capsys.readouterr().out.strip() == f"lanecast {__version__}"


@pytest.mark.parametrize("command", cli.COMMANDS)
def test_every_default_is_in_the_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    text = help_of(command, capsys)
    options = text.split("options:", 1)[1]
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]  # type: ignore[index]
    for action in sub._actions:
        if action.default in (None, False, "==SUPPRESS==") or not action.option_strings:
            continue
        option_help = options.split(f" {action.option_strings[-1]} ", 1)[1]
        assert "default" in option_help.split(" --", 1)[0], f"{command} {action.option_strings[-1]}"
    assert "example" in text


@pytest.mark.parametrize("command", WRITERS)
def test_every_output_is_named_by_out(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    text = help_of(command, capsys)
    assert re.search(r"--out [A-Z_]+", text)
    assert "--report" not in text


def test_model_means_the_same_everywhere(capsys: pytest.CaptureFixture[str]) -> None:
    with_model = [c for c in cli.COMMANDS if "--model MODEL" in help_of(c, capsys)]
    assert {"demo", "evaluate", "annotate"} <= set(with_model)
    for command in with_model:
        assert " ".join(MODEL_HELP.split()) in help_of(command, capsys)


@pytest.mark.slow
def test_a_closed_stdout_ends_quietly(tmp_path: Path) -> None:
    """`lanecast info … | head`: the reader is gone before lanecast writes; no traceback."""
    from lanecast.io_adapters.contracts import track_table
    from lanecast.io_adapters.datasets.highd import reader as highd
    from lanecast.io_adapters.sim import recording

    rec = recording.simulate(
        tmp_path / "sim", minutes=0.05, seed=1, section_length_m=100.0, approach_length_m=150.0,
        show_progress=False,
    )  # fmt: skip
    table = track_table.write_parquet(highd.read([rec]), tmp_path / "t.parquet")
    proc = subprocess.Popen(
        [sys.executable, "-m", "lanecast", "info", str(table)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # like `head` that has read all it wanted
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err


@pytest.fixture
def small_table(tmp_path: Path) -> Path:
    from conftest import make_track_table

    from lanecast.io_adapters.contracts import track_table

    n = 30
    table = make_track_table(
        {"track_id": np.repeat([1, 2], n), "frame": np.tile(np.arange(n), 2), "x": np.arange(2 * n) * 1.0,
         "y": np.zeros(2 * n), "lane_id": np.ones(2 * n, dtype=np.int32)},
        coordinate_frame="map",
    )  # fmt: skip
    return track_table.write_parquet(table, tmp_path / "t.parquet")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "x.csv"], "--out {tmp}/x.csv: lanecast does not write .csv files"),
        (["--to", "mcap", "--out", "x.parquet"], "--to mcap writes .mcap files"),
        (["--to", "ros2", "--out", "x.mcap"], "a ROS 2 bag is a directory"),
    ],
)
def test_convert_refuses_a_suffix_it_would_not_write(
    small_table: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    out_arg = args.index("--out") + 1
    args = [*args[:out_arg], str(tmp_path / args[out_arg]), *args[out_arg + 1 :]]
    assert cli.main(["convert", str(small_table), *args]) == 2
    assert message.format(tmp=tmp_path) in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.parquet"]


def test_convert_to_ros2_writes_mcap_storage_unless_asked(small_table: Path, tmp_path: Path) -> None:
    from lanecast.io_adapters.formats import registry

    assert cli.main(["convert", str(small_table), "--to", "ros2", "--out", str(tmp_path / "bag")]) == 0
    assert [p.suffix for p in (tmp_path / "bag").iterdir() if p.name != "metadata.yaml"] == [".mcap"]
    assert "storage_identifier: mcap" in (tmp_path / "bag" / "metadata.yaml").read_text()
    args = [
        "convert",
        str(small_table),
        "--to",
        "ros2",
        "--storage",
        "sqlite3",
        "--out",
        str(tmp_path / "b3"),
    ]
    assert cli.main(args) == 0
    assert [p.suffix for p in (tmp_path / "b3").iterdir() if p.name != "metadata.yaml"] == [".db3"]
    for bag in ("bag", "b3"):
        back = registry.read_any([tmp_path / bag])
        assert back.column("x").to_pylist() == registry.read_any([small_table]).column("x").to_pylist()


def test_the_location_choices_are_the_readers_locations() -> None:
    from lanecast.io_adapters.datasets.ngsim import reader as ngsim
    from lanecast.workflows.vocabulary import NGSIM_LOCATIONS

    assert NGSIM_LOCATIONS == ngsim.FREEWAYS + ngsim.ARTERIALS


def readme_first_session() -> list[str]:
    text = (REPO / "README.md").read_text()
    block = text.split("## A first session", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def test_the_readme_first_session_is_the_help_examples_and_chains(capsys: pytest.CaptureFixture[str]) -> None:
    """Every line of the README's first session is an example in its command's --help, and every
    input a line names (relative) is the output of an earlier line: the examples chain."""
    lines = readme_first_session()
    assert len(lines) >= 10
    made: set[str] = set()
    for line in lines:
        words = line.split()
        assert words[0] == "lanecast"
        with pytest.raises(SystemExit):
            cli.main([words[1], "--help"])
        assert f"  {line}" in capsys.readouterr().out, line
        inputs = [w for w in words[2:] if (not w.startswith("-") and "/" in w) or w.endswith(".parquet")]
        outputs = {words[i + 1] for i, w in enumerate(words) if w == "--out"}
        for path in set(inputs) - outputs:
            assert path.rstrip("/") in made or any(m.startswith(path.rstrip("/") + "/") for m in made), (
                line,
                path,
            )
        made |= {o.rstrip("/") for o in outputs}
        if words[1] == "export":  # writes beside the model it is given
            made.add(words[2])
