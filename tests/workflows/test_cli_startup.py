"""The command line imports what it uses: `lanecast --help` and `--version` load no command module."""

from __future__ import annotations

import argparse
import subprocess
import sys

from lanecast.workflows.cli import SUMMARIES, build_parser

PROBE = """
import sys
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
