"""`lanecast annotate` on bad input: a bad card, weights or forecasts table, a damaged log, --every
off the grid; one error line up front, nothing left behind."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import _model_copy, _set, cli, json_log, refused, straight_messages

from lanecast.workflows.cli import main


@pytest.mark.parametrize("every", ["0.01", "0.04"])
def test_annotate_every_outside_the_grid_is_one_error_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], every: str
) -> None:
    """0.01 s failed as 'FAILED <log>: <input>: --every 0.01', exit 1 (nan and inf: in
    test_numeric_options_out_of_range_are_usage_errors)."""
    from conftest import json_log, straight_messages

    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    refused(
        ["annotate", str(log), "--every", every, "--out", str(out)], capsys, "--every: ", "at least 0.1 s"
    )
    assert not out.exists()


def test_a_log_that_fails_in_annotate_ends_stderr_with_its_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A truncated log given to annotate: exit 1 with its error only on stdout (in the summary)
    and a progress line last on stderr; now the error is the last line on stderr, as for every
    other command, and the good log beside it is still annotated."""
    from conftest import json_log, straight_messages

    logs = tmp_path / "logs"
    logs.mkdir()
    good = json_log(logs / "good.mcap", straight_messages(n=60))
    data = good.read_bytes()
    (logs / "cut.mcap").write_bytes(data[: len(data) // 2])
    out = tmp_path / "out"
    status = main(["annotate", str(logs), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1 and "Traceback" not in "".join(err)
    assert err[-1].startswith(f"lanecast annotate: error: {logs / 'cut.mcap'}, offset "), err[-1]
    assert (out / "good.mcap").is_file() and not (out / "cut.mcap").exists()


def test_annotate_of_only_a_damaged_log_is_refused_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One truncated log: exit 1 and an OUT_DIR holding only a manifest of the failure. Now exit 2
    (a refused input, as every command) and no OUT_DIR; an OUT_DIR that existed keeps its manifest
    (the resume state of earlier runs); exit 1 is for a run where other logs were annotated."""
    from conftest import json_log, straight_messages

    good = json_log(tmp_path / "good.mcap", straight_messages(n=60))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    out = tmp_path / "out"
    assert main(["annotate", str(cut), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"lanecast annotate: error: {cut}, offset "), err[-1]
    assert not out.exists()
    assert main(["annotate", str(good), "--out", str(out)]) == 0
    assert main(["annotate", str(cut), "--out", str(out)]) == 2  # this run annotated nothing
    assert (out / "good.mcap").is_file() and (out / "manifest.jsonl").is_file()
    assert not (out / "cut.mcap").exists()


@pytest.mark.parametrize("damage", ["nan point", "null point", "garbage", "no x"])
def test_annotate_with_a_bad_forecasts_table_is_one_error_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    """--forecasts with a NaN point was written into the log as a line that draws nothing; a file
    that is not Parquet failed each log as 'ArrowInvalid: …' and a missing column as '<input>,
    column …', both after OUT_DIR got a manifest and a lock. Now the table is checked before."""
    from conftest import forecasts_for, make_mcap

    log = make_mcap(tmp_path / "drive.mcap", n=60)
    table = forecasts_for("drive", [1, 2], [1, 2])
    fc = tmp_path / "fc.parquet"
    x = table.column("x").to_pylist()
    if damage == "garbage":
        fc.write_bytes(b"PAR1garbagePAR1")
        said: tuple[str, ...] = (f"{fc}: unreadable forecasts table",)
    elif damage == "no x":
        pq.write_table(table.drop_columns(["x"]), fc)
        said = (f"{fc}, column 'x': forecasts table lacks a column",)
    else:
        x[2][3] = float("nan") if damage == "nan point" else None
        pq.write_table(table.set_column(table.column_names.index("x"), "x", pa.array(x)), fc)
        said = (f"{fc}, column 'x': row 2: forecast point", "expected finite coordinates")
    out = tmp_path / "ann"
    refused(["annotate", str(log), "--forecasts", str(fc), "--out", str(out)], capsys, *said)
    assert not out.exists()


def test_annotate_with_a_bad_card_is_one_clean_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _model_copy(tmp_path, _set("architecture.config.hidden", 2**40))
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    status, err = cli(["annotate", str(log), "--model", str(model), "--out", str(tmp_path / "out")], capsys)
    assert status == 2 and "stcnn.json" in err and "hidden" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("damage", "match"),
    [
        (lambda b: b[: len(b) // 2], "unreadable weights"),
        (lambda b: b"", "unreadable weights"),
        (lambda b: b[:8] + b[8:].replace(b'"F32"', b'"F16"', 1), "unreadable weights|do not fit"),
    ],
)
def test_annotate_with_bad_weights_leaves_no_trace(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: object, match: str
) -> None:
    """Truncated, empty or mistyped weights failed per log, after OUT_DIR got a manifest.jsonl and a
    lock file: the model is now loaded (as the logs will be) before anything is created."""
    import re

    model = _model_copy(tmp_path)
    weights = model / "stcnn.safetensors"
    weights.write_bytes(damage(weights.read_bytes()))  # type: ignore[operator]
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    status, err = cli(["annotate", str(log), "--model", str(model), "--out", str(out)], capsys)
    assert status == 2 and err.startswith(f"lanecast annotate: error: {weights}") and re.search(match, err), (
        err
    )
    assert not out.exists()
