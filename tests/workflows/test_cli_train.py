"""`lanecast train` on bad labels, huge inputs and options of the wrong type or range."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import _edit_npy, _set_first, no_output, refused, windows_copy


def test_training_on_a_bad_label_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """maneuver 7 crashed training with an IndexError in the loss (exit 1, a traceback)."""
    directory = windows_copy(tmp_path, _edit_npy("maneuver", _set_first(7)))
    out = tmp_path / "model"
    refused(
        ["train", str(directory), "--out", str(out), "--epochs", "1"],
        capsys,
        "maneuver.npy",
        "window 1 holds 7",
    )
    no_output(out)


def test_training_on_a_huge_finite_input_is_refused_at_its_window(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An input of 1e30 (finite; the fuzzer's seed 300135) overflowed the normalisation statistics
    to inf: train ran an epoch, then said "bad normalisation statistics {...}", naming no file."""
    directory = windows_copy(tmp_path, _edit_npy("inputs", _set_first(1e30)))
    out = tmp_path / "model"
    refused(
        ["train", str(directory), "--out", str(out), "--epochs", "1"],
        capsys,
        "inputs.npy",
        "window 0 holds 1.0000000150474662e+30 (expected finite inputs within ±1e+09",
    )
    no_output(out)


@pytest.mark.parametrize(
    ("options", "config", "named"),
    [
        (["--epochs", "0"], None, "--epochs: 0 (expected an integer from 1 to 100000)"),
        (["--lr", "nan"], None, "--lr: nan (expected a number from 0.0 to 10.0)"),
        (["--lr", "-1"], None, "--lr: -1.0 (expected a number from 0.0 to 10.0)"),
        (["--batch-size", "0"], None, "--batch-size: 0"),
        (["--threads", "0"], None, "--threads: 0"),
        (["--device", "tpu9"], None, "--device: 'tpu9'"),
        (["--position-noise", "-1"], None, "position_noise_m must be >= 0"),
        ([], '{"epochs": "three"}', "epochs: 'three' (expected an integer from 1 to 100000)"),
        # a JSON list trained 30 epochs with the defaults; 10**12 epochs ran until killed; a seed
        # beyond int64 (or below 0) failed in numpy once the data was loaded
        ([], "[]", "config.json, column 'config': bad training config: [] (expected a JSON object)"),
        ([], '[["epochs", 3]]', "bad training config: [['epochs', 3]] (expected a JSON object)"),
        ([], '{"epochs": 1000000000000}', "epochs: 1000000000000 (expected an integer from 1 to 100000)"),
        ([], '{"seed": 1180591620717411303424}', "seed: 1180591620717411303424 (expected an integer from 0"),
        ([], '{"seed": -1}', "seed: -1 (expected an integer from 0"),
        (
            ["--batch-size", str(2**40)],
            None,
            "--batch-size: 1099511627776 (expected an integer from 1 to 1048576)",
        ),
    ],
)
def test_training_options_of_the_wrong_type_or_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str], config: str | None, named: str
) -> None:
    """--epochs 0 saved an untrained model with exit 0; the others ended in tracebacks from torch
    (ValueError: Invalid learning rate, ZeroDivisionError, RuntimeError: Invalid device string, a
    TypeError adding a str epoch count)."""
    directory = windows_copy(tmp_path, lambda d: None)
    if config is not None:
        (tmp_path / "config.json").write_text(config)
        options = ["--config", str(tmp_path / "config.json")]
    out = tmp_path / "model"
    refused(["train", str(directory), "--out", str(out), *options], capsys, named)
    no_output(out)
