"""What train and windows say: constant velocity beside the RMSE, no lane change to learn, a skewed split."""

from __future__ import annotations

import pytest

from lanecast.workflows.cli import main
from lanecast.workflows.train import shipped_defaults, summary
from lanecast.workflows.windows import split_skew


def _card(maneuver_counts: list[int]) -> dict:
    metrics = {
        "rmse": [0.1, 0.3, 0.6, 1.0, 1.5],
        "maneuver_accuracy": 0.97,
        "maneuver_macro_f1": 1.0,
        "constant_velocity_rmse": [0.1, 0.4, 0.8, 1.4, 2.0],
    }
    return {
        "training": {
            "data": {"train_windows": 1200, "train_maneuver_counts": maneuver_counts},
            "train_seconds": 12.0,
            "train_samples_per_s": 2000.0,
            "best_epoch": {"classifier": 15, "regressor": 9},
        },
        "metrics": {"validation": metrics, "test": metrics},
    }


def test_the_summary_sets_constant_velocity_beside_the_rmse_and_names_the_best_epochs() -> None:
    lines = summary(_card([5000, 120, 130]), epochs=20)
    assert lines[0].endswith("best epochs: classifier 15, regressor 9")
    assert "{" not in lines[0]
    test = next(line for line in lines if line.strip().startswith("test:"))
    assert "constant velocity 0.10 0.40 0.80 1.40 2.00 m; 0.75x at 5 s" in test
    assert not any("no lane change" in line for line in lines)


def test_the_summary_warns_when_the_training_split_holds_no_lane_change() -> None:
    lines = summary(_card([6000, 0, 0]), epochs=20)
    assert "the training split holds no lane change (6,000 straight steps)" in lines[-1]
    assert "trivial" in lines[-1]


def test_a_split_far_from_70_10_20_is_named_with_its_shares() -> None:
    assert split_skew({"train": 700, "val": 100, "test": 200}, "pip") is None
    note = split_skew({"train": 890, "val": 70, "test": 40}, "pip")
    assert note is not None and "89 / 7 / 4 % train / val / test" in note and "--split hash" in note
    assert split_skew({"train": 10, "val": 0, "test": 0}, "pip") is None  # too few to judge
    assert split_skew({"none": 500}, "none") is None


def test_train_help_shows_the_shipped_values_and_windows_help_says_what_pip_is(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for command in ("train", "windows"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    epochs = shipped_defaults()["epochs"]
    assert (
        f"(default: {epochs}, the shipped model's)" in out
        and "see --config)" not in out.split("--lr")[1][:80]
    )
    assert "pip = the PiP convention (Song et al., ECCV 2020; by vehicle id within each recording" in out
