"""Inputs every command refuses cleanly: FIFOs, symlink loops, directories, unreadable files, a model
given where data goes; one error line and exit status 2, no traceback."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO, _model_copy, _record, _s, assert_one_line_error, cli, json_log, straight_messages

from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.workflows.cli import main


def test_fifo_input_is_refused_without_opening_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)
    for fmt in (["--format", "mcap"], []):
        status, err = cli(["convert", str(fifo), *fmt, "--out", str(tmp_path / "x.parquet")], capsys)
        assert_one_line_error(status, err, "convert", str(fifo))
        assert "not a regular file" in err


def test_symlink_loops_and_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    good = json_log(tmp_path / "good.mcap", straight_messages())
    status, err = cli(["convert", str(loop), "--out", str(tmp_path / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(loop))
    status, err = cli(["convert", str(good), "--out", str(loop)], capsys)
    assert_one_line_error(status, err, "convert", str(loop))
    status, err = cli(["convert", str(good), "--out", str(tmp_path)], capsys)
    assert_one_line_error(status, err, "convert", str(tmp_path))
    assert "is a directory" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    status, err = cli(["convert", str(good), "--out", str(blocker / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(blocker))
    assert not (tmp_path / "x.parquet").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads and writes regardless of modes")
def test_unreadable_input_and_read_only_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = json_log(tmp_path / "good.mcap", straight_messages())
    good.chmod(0)
    status, err = cli(["convert", str(good), "--out", str(tmp_path / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(good))
    good.chmod(0o644)
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    status, err = cli(["convert", str(good), "--out", str(ro / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(ro))


@pytest.mark.slow
def test_cli_subprocess_prints_no_traceback(tmp_path: Path) -> None:
    """End to end through the installed entry point: exit 2 and one line."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(mcap_reader.MAGIC + _record(0x03, struct.pack("<H", 1) + _s("x")[:3]))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "lanecast", "convert", str(bad), "--out", str(tmp_path / "x.parquet")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("lanecast convert: error: ")
    assert str(bad) in done.stderr and "offset 8" in done.stderr


def test_a_model_given_where_data_goes_is_named_as_a_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A model directory (or its weights) given to info, windows, evaluate or train was 'format
    not recognised' or 'inputs.npy: missing file of a windows dataset'."""
    model = _model_copy(tmp_path)
    weights = next(model.glob("*.safetensors"))
    for argv, named, words in (
        (["info", str(model)], model, "a model (the output of `lanecast train`), not a dataset or log"),
        (["info", str(weights)], weights, "a model (the output of `lanecast train`), not a dataset or log"),
        (["windows", str(model), "--out", str(tmp_path / "w")], model, "not a dataset or log"),
        (["evaluate", str(model), "--out", str(tmp_path / "e")], model, "a model directory (the output of"),
        (["train", str(model), "--out", str(tmp_path / "t")], model, "not a windows dataset"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"error: {named}: " in err and words in err and "--model or --init" in err, err
    assert not any((tmp_path / name).exists() for name in ("w", "e", "t"))
