"""Fine-tuning that keeps the base model: the L2-SP penalty keeps the weights nearer the base than a
plain fine-tune, a classifier is kept when the new data holds no lane change, replay windows are
mixed in at the asked share, and the card records the base and an OOD range covering both datasets."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from conftest import synthetic_windows

from lanecast.io_adapters.contracts.windows import Windows, labelled
from lanecast.io_adapters.errors import InputError
from lanecast.models import ood
from lanecast.models.checkpoint import save_checkpoint
from lanecast.models.finetune import (
    L2SP,
    FinetuneOptions,
    finetune,
    interpolate_regressor,
    load_replay,
    merged_distribution,
    mix_replay,
    save_replay,
    summary,
)
from lanecast.models.stcnn import STCNN
from lanecast.models.train import TrainConfig, TrainResult, train

CONFIG = TrainConfig(epochs=1, batch_size=64, lr=3e-3, seed=2, threads=1)


@pytest.fixture(scope="module")
def base() -> TrainResult:
    return train(synthetic_windows(240, seed=1), dataclasses.replace(CONFIG, epochs=2))


@pytest.fixture(scope="module")
def queue() -> Windows:
    """New data of another kind: slower traffic without a single lane change."""
    w = synthetic_windows(160, seed=7, lane_change_share=0.0)
    w.inputs[:, 2] *= 0.4
    w.inputs[:, 0] *= 0.4
    w.future[:, :, 0] *= 0.4
    assert not np.any(w.maneuver > 0)
    return w


def tune(base: TrainResult, data: Windows, replay: Windows | None = None, **options: object) -> TrainResult:
    return finetune(
        data,
        CONFIG,
        (base.model, base.card),
        base_name="tiny base",
        base_sha256="ab" * 32,
        replay=replay,
        options=FinetuneOptions(**options),  # type: ignore[arg-type]
        data_card={"windows": "queue"},
    )


def distance(a: torch.nn.Module, b: torch.nn.Module) -> float:
    sa, sb = a.state_dict(), b.state_dict()
    return float(sum(torch.sum((sa[k].float() - sb[k].float()) ** 2) for k in sa))


def test_penalty_keeps_weights_nearer_the_base(base: TrainResult, queue: Windows) -> None:
    plain = tune(base, queue, keep_base="none", classifier="train")
    kept = tune(base, queue, keep_base="l2sp", l2sp_weight=1.0, classifier="train")
    for net in ("regressor", "classifier"):
        d_plain = distance(getattr(base.model, net), getattr(plain.model, net))
        d_kept = distance(getattr(base.model, net), getattr(kept.model, net))
        assert 0 < d_kept < 0.5 * d_plain, (net, d_kept, d_plain)
    penalty = L2SP(base.model, 2.0)
    with torch.no_grad():
        assert float(penalty("regressor", base.model.regressor)) == 0.0
        expected = 2.0 * distance(base.model.regressor, plain.model.regressor)
        assert float(penalty("regressor", plain.model.regressor)) == pytest.approx(expected, rel=1e-4)


def test_classifier_kept_when_the_new_data_has_no_lane_change(base: TrainResult, queue: Windows) -> None:
    kept = tune(base, queue, keep_base="none", classifier="auto")
    for k, v in base.model.classifier.state_dict().items():
        assert torch.equal(v, kept.model.classifier.state_dict()[k]), k
    assert kept.card["finetune"]["classifier"].startswith("frozen: the new training windows hold 0")
    assert kept.card["training"]["best_epoch"]["classifier"] == "copied"
    assert "classifier frozen: the new training windows hold 0" in summary(kept.card)
    assert distance(base.model.regressor, kept.model.regressor) > 0  # the regressor did learn
    trained = tune(base, queue, keep_base="none", classifier="train")
    assert distance(base.model.classifier, trained.model.classifier) > 0
    # with lane changes in the new data, "auto" trains the classifier
    lanes = synthetic_windows(120, seed=9)
    mixed = tune(base, lanes, keep_base="none", classifier="auto", min_lane_change_windows=10)
    assert mixed.card["finetune"]["classifier"].startswith("fine-tuned on ")
    assert distance(base.model.classifier, mixed.model.classifier) > 0
    kept = tune(base, lanes, keep_base="none")  # the default keeps it whatever the data
    assert distance(base.model.classifier, kept.model.classifier) == 0


def test_card_records_base_added_data_and_merged_range(base: TrainResult, queue: Windows) -> None:
    tuned = tune(base, queue, keep_base="l2sp")
    f = tuned.card["finetune"]
    assert f["base"]["name"] == "tiny base" and f["base"]["weights_sha256"] == "ab" * 32
    assert f["added"]["windows"] == "queue" and f["added"]["lane_change_train_windows"] == 0
    assert f["added"]["train_windows"] == len(labelled(queue, ("train",)))
    data = tuned.card["training"]["data"]
    assert data["distribution_base"] == base.card["training"]["data"]["distribution"]
    speed = data["distribution"]["speed_mps"]
    for part in (data["distribution_base"], data["distribution_added"]):
        assert speed["p0.5"] <= part["speed_mps"]["p0.5"] and speed["p99.5"] >= part["speed_mps"]["p99.5"]
    # the new data's slow targets fall outside the base's range but inside the fine-tuned one
    training = tuned.card["training"]["data"]["distribution"]
    flags_base = ood.out_of_distribution(queue.inputs, queue.present, data["distribution_base"])
    flags_tuned = ood.out_of_distribution(queue.inputs, queue.present, training)
    assert flags_base is not None and flags_tuned is not None
    assert flags_base.mean() > 0.5 and flags_tuned.mean() < 0.05
    old = synthetic_windows(200, seed=11)
    flags_old = ood.out_of_distribution(old.inputs, old.present, training)
    assert flags_old is not None and flags_old.mean() < 0.05


def test_merged_distribution_pools_mean_and_std() -> None:
    a = {"speed_mps": {**{f"p{p:g}": 10.0 + p / 100 for p in ood.PERCENTILES}, "mean": 10.0, "std": 1.0}}
    b = {"speed_mps": {**{f"p{p:g}": 2.0 + p / 100 for p in ood.PERCENTILES}, "mean": 2.0, "std": 1.0}}
    m = merged_distribution(a, 300, b, 100)["speed_mps"]
    assert m["mean"] == pytest.approx(8.0)
    assert m["std"] == pytest.approx(np.sqrt(1 + 0.75 * 4 + 0.25 * 36), abs=1e-4)
    assert m["p0.5"] == b["speed_mps"]["p0.5"] and m["p99.5"] == a["speed_mps"]["p99.5"]


def test_replay_round_trip_and_mix(tmp_path, base: TrainResult, queue: Windows) -> None:
    source = synthetic_windows(100, seed=4)
    rows = labelled(source, ("train", "val"))
    path = save_replay(source, rows, tmp_path / "m.replay.npz", {"made_by": "test"})
    replay = load_replay(path)
    assert len(replay) == len(rows) and replay.manifest["replay"] == {"made_by": "test"}
    np.testing.assert_allclose(replay.inputs, source.inputs[rows], rtol=1e-3, atol=1e-2)
    np.testing.assert_array_equal(replay.maneuver, source.maneuver[rows])
    mixed, counts = mix_replay(queue, replay, 0.5, seed=0)
    assert counts["replay_train"] == counts["new_train"] == len(labelled(queue, ("train",)))
    assert counts["replay_val"] == counts["new_val"]
    assert len(mixed) == sum(counts.values())
    tuned = tune(base, queue, replay=replay, keep_base="l2sp+replay")
    assert tuned.card["finetune"]["replay"]["windows"] == counts
    assert "replay windows beside" in summary(tuned.card)
    (tmp_path / "bad.replay.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match=r"bad\.replay\.npz"):
        load_replay(tmp_path / "bad.replay.npz")


def test_cli_fine_tune_writes_card_and_summary(tmp_path, base: TrainResult, queue: Windows, capsys) -> None:
    from lanecast.io_adapters.windows_store.dataset import save_windows
    from lanecast.models.checkpoint import load_checkpoint
    from lanecast.workflows.cli import main as cli_main

    save_checkpoint(base.model, base.card, tmp_path / "base")
    save_windows(queue, tmp_path / "w")
    argv = ["train", str(tmp_path / "w"), "--init", str(tmp_path / "base"), "--epochs", "1", "--threads", "1"]
    assert cli_main([*argv, "--out", str(tmp_path / "tuned")]) == 0
    out = capsys.readouterr().out
    assert "fine-tuned from" in out and "classifier frozen" in out and "no replay set" in out
    _, card = load_checkpoint(tmp_path / "tuned")
    assert card["finetune"]["base"]["name"] == str(tmp_path / "base")
    assert card["finetune"]["keep_base"] == "l2sp" and card["training"]["config"]["lr"] == 3e-4
    assert cli_main([*argv, "--keep-base", "none", "--lr", "1e-3", "--out", str(tmp_path / "plain")]) == 0
    _, plain = load_checkpoint(tmp_path / "plain")
    assert plain["finetune"]["keep_base"] == "none" and plain["training"]["config"]["lr"] == 1e-3
    assert cli_main(["train", str(tmp_path / "w"), "--keep-base", "none", "--out", str(tmp_path / "x")]) == 2
    assert "--keep-base" in capsys.readouterr().err


def test_interpolate_regressor_moves_only_the_regressor_the_share_of_the_way() -> None:
    torch.manual_seed(0)
    base, tuned = STCNN(), STCNN()
    half = interpolate_regressor(base, tuned, 0.5)
    for k, v in half.regressor.state_dict().items():
        b, t = base.regressor.state_dict()[k], tuned.regressor.state_dict()[k]
        assert torch.allclose(v, (b + t) / 2) and not torch.equal(b, t)
    for k, v in half.classifier.state_dict().items():
        assert torch.equal(v, base.classifier.state_dict()[k])
    for share, end in ((0.0, base), (1.0, tuned)):
        at = interpolate_regressor(base, tuned, share).regressor.state_dict()
        assert all(torch.equal(v, end.regressor.state_dict()[k]) for k, v in at.items())
    x = torch.randn(3, 4, 8, 30)
    assert torch.equal(base(x)[0], half(x)[0])  # the same maneuver logits
    with pytest.raises(ValueError, match="share"):
        interpolate_regressor(base, tuned, 1.5)
