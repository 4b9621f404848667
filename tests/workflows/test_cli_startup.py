"""The command line imports what it uses: `lanecast --help` and `--version` load no command module."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from lanecast.workflows.cli import SUMMARIES, build_parser

PROBE = """
import sys
from pathlib import Path
from lanecast.workflows.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
heavy = sorted(m for m in ("pyarrow", "torch", "pandas", "rosbags", "mcap", "lanecast.workflows.convert") if m in sys.modules)
print("heavy:" + ",".join(heavy))
"""


def test_each_command_is_listed_with_its_own_help() -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {a.dest: a.help for a in sub._choices_actions} == SUMMARIES


def test_the_top_level_help_and_version_import_no_command() -> None:
    for argv in (["--help"], ["--version"], []):
        probe = subprocess.run(
            [sys.executable, "-c", PROBE.format(argv=argv)], capture_output=True, text=True, check=True
        )
        assert probe.stdout.strip().splitlines()[-1] == "heavy:", (argv, probe.stdout[-300:])


def test_a_command_builds_its_own_parser_and_lists_the_others() -> None:
    parser = build_parser(only="info")
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(SUMMARIES)
    assert any(a.dest == "paths" for a in sub.choices["info"]._actions)
    assert not any(a.dest == "inputs" for a in sub.choices["convert"]._actions)


HEAVY = (
    "numpy",
    "pyarrow",
    "pandas",
    "torch",
    "onnxruntime",
    "scipy",
    "mcap",
    "rosbags",
    "tqdm",
    "matplotlib",
)


def test_every_commands_help_imports_none_of_the_work() -> None:
    """`lanecast <command> --help` reads the parser alone: no array, table, log or model library
    (each costs 0.1–2 s of start-up that a user waiting for a help text should not pay)."""
    probe = f"""
import sys
from pathlib import Path
from lanecast.workflows.cli import main
for command in sys.argv[1:]:
    try:
        main([command, "--help"])
    except SystemExit:
        pass
print("heavy:" + ",".join(sorted({{m.split(".")[0] for m in sys.modules}} & set({HEAVY!r}))))
"""
    done = subprocess.run(
        [sys.executable, "-c", probe, *SUMMARIES], capture_output=True, text=True, check=True
    )
    assert "usage: lanecast simulate" in done.stdout and "usage: lanecast train" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "heavy:", done.stdout[-400:]


def test_reading_a_small_dataset_imports_no_notebook_machinery_nor_looks_up_the_version() -> None:
    """`lanecast info` on a small highD recording: no asyncio (tqdm.auto's, for notebooks, ~20 ms)
    and no look-up of lanecast's version in the installed packages' metadata (only when printed)."""
    data = Path(__file__).resolve().parents[1] / "data" / "highd"
    probe = f"""
import sys
from pathlib import Path
from lanecast.workflows.cli import main
main(["info", {str(data)!r}])
import lanecast
print("loaded:" + ",".join(sorted(({{"asyncio"}} & set(sys.modules)) | ({{"__version__"}} & set(vars(lanecast))))))
"""
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "highd-01-lower" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "loaded:", done.stdout[-400:]
    version = subprocess.run(
        [sys.executable, "-m", "lanecast", "--version"], capture_output=True, text=True, check=True
    )
    assert version.stdout.startswith("lanecast ") and len(version.stdout.split()) == 2
