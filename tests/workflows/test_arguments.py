"""Every numeric command-line option is checked where it is parsed: a usage error naming it."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanecast.workflows.cli import main


@pytest.mark.parametrize(
    ("command", "option", "value", "expected"),
    [
        # tracebacks: "OverflowError: Python int too large to convert to C long" (stride, workers),
        # "ValueError: Maximum allowed dimension exceeded" (top-k)
        ("windows", "--stride", "99999999999999999999", "an integer from 1 to 36000"),
        ("windows", "--workers", "99999999999999999999", "an integer from 1 to 1024"),
        ("convert", "--workers", "99999999999999999999", "an integer from 1 to 1024"),
        ("evaluate", "--top-k", "99999999999999999999", "an integer from 1 to 243"),
        ("annotate", "--top-k", "244", "an integer from 1 to 243"),
        # taken with exit 0: no example scenes, no retries, no neighbour range, a seed out of range
        ("evaluate", "--examples", "-1", "an integer from 0 to 100"),
        ("report", "--examples", "-1", "an integer from 0 to 100"),
        ("convert", "--retries", "-1", "an integer from 0 to 100"),
        ("windows", "--neighbour-range", "inf", "a number above 0, at most 10000 m"),
        ("windows", "--seed", "-1", "an integer from 0 to 2147483647"),
        ("annotate", "--every", "nan", "a number above 0, at most 86400 s"),
        ("windows", "--stride", "ten", "an integer from 1 to 36000"),
        # earlier checks, now where the option is parsed: --batch-size 0 was 'ValueError: range() arg 3
        # must not be zero', --top-k 0 reported minADE@1, --every nan and --time nan 'ValueError:
        # cannot convert float NaN to integer' (--every in every log's task)
        ("evaluate", "--batch-size", "0", "an integer from 1 to 1048576"),
        ("evaluate", "--top-k", "0", "an integer from 1 to 243"),
        ("annotate", "--every", "inf", "a number above 0, at most 86400 s"),
        ("explain", "--time", "nan", "a number from -9.2e+09 to 9.2e+09 s"),
        ("explain", "--time", "1e300", "a number from -9.2e+09 to 9.2e+09 s"),
    ],
)
def test_numeric_options_out_of_range_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, option: str, value: str, expected: str
) -> None:
    """Every numeric option is checked where it is parsed: argparse's one line, exit 2, naming the
    option, the value and the range, before any input is read or output made."""
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        main([command, str(tmp_path / "input"), "--out", str(out), option, value])
    assert exit_info.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"lanecast {command}: error: argument {option}: {value}"), line
    assert line.endswith(f"(expected {expected})"), line
    assert not out.exists()
