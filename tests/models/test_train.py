"""Training of the ST-CNN on small synthetic windows: losses fall, a few windows are overfitted,
a seed reproduces the weights, save → load → predict gives identical outputs, and equal weights
save to equal bytes."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import torch
from conftest import REPO, synthetic_windows
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from lanecast.io_adapters.contracts.windows import Windows
from lanecast.io_adapters.errors import InputError
from lanecast.models.checkpoint import load_checkpoint, resolve, save_checkpoint, write_safetensors
from lanecast.models.losses import (
    class_weights,
    classifier_loss,
    future_stats,
    horizon_weights,
    regressor_loss,
)
from lanecast.models.metrics import displacement_errors, rmse
from lanecast.models.predict import STCNNForecaster
from lanecast.models.stcnn import STCNN, count_parameters
from lanecast.models.train import TrainConfig, labelled, lr_factor, select_epoch, train


@pytest.fixture(scope="module")
def windows() -> Windows:
    return synthetic_windows()


def test_future_stats_by_hand() -> None:
    future = np.array([[[1, 0]] * 5, [[3, 2]] * 5], np.float32)  # mean (2, 1); centred entries ±1
    mean, std = future_stats(future)
    np.testing.assert_allclose(mean, [[2, 1]] * 5)
    assert std == pytest.approx(1.0)


def test_regressor_loss_is_batch_rmse() -> None:
    pred = torch.zeros(2, 5, 2)
    true = torch.zeros(2, 5, 2)
    true[0, :, 0] = 3.0
    true[0, :, 1] = 4.0  # error 5 m on all steps of window 0, 0 on window 1
    assert float(regressor_loss(pred, true)) == pytest.approx(np.sqrt(25 / 2))


def test_class_weights_by_hand() -> None:
    maneuver = np.array([[0, 0, 0, 1, 1], [0, 0, 0, 1, 2]])  # counts 6, 3, 1 → frequencies .6, .3, .1
    # power 1: ∝ (1/.6, 1/.3, 1/.1); mean over steps .6·5/3 + .3·10/3 + .1·10 = 3 → divide by 3
    np.testing.assert_allclose(class_weights(maneuver, 1.0), [5 / 9, 10 / 9, 10 / 3], rtol=1e-6)
    # power .5: ∝ (.6, .3, .1)**-.5; mean .6**.5 + .3**.5 + .1**.5
    raw = np.array([0.6, 0.3, 0.1]) ** -0.5
    np.testing.assert_allclose(
        class_weights(maneuver, 0.5), raw / (0.6**0.5 + 0.3**0.5 + 0.1**0.5), rtol=1e-6
    )
    np.testing.assert_array_equal(class_weights(maneuver, 0.0), [1, 1, 1])
    np.testing.assert_allclose(class_weights(np.array([[0, 0, 1]]), 1.0), [0.75, 1.5, 0.0])  # no right


def test_weighted_nll_by_hand() -> None:
    logits = torch.zeros(2, 5, 3)
    logits[0, :, 1] = np.log(2.0)  # window 0: p = (1/4, 1/2, 1/4) on every step
    maneuver = torch.tensor([[0, 0, 0, 1, 2], [0, 0, 0, 0, 0]])  # window 1: p = 1/3 everywhere
    weight = torch.tensor([0.5, 2.0, 4.0])
    w0 = 3 * 0.5 * np.log(4) + 2.0 * np.log(2) + 4.0 * np.log(4)
    w1 = 5 * 0.5 * np.log(3)
    assert float(classifier_loss(logits, maneuver, weight)) == pytest.approx((w0 + w1) / 2, rel=1e-6)
    plain = (4 * np.log(4) + np.log(2) + 5 * np.log(3)) / 2
    assert float(classifier_loss(logits, maneuver)) == pytest.approx(plain, rel=1e-6)
    assert float(classifier_loss(logits, maneuver, torch.ones(3))) == pytest.approx(plain, rel=1e-6)


def test_select_epoch_on_constructed_history() -> None:
    history = [
        {"epoch": 1, "val_nll": 0.70, "val_macro_f1": 0.50},
        {"epoch": 2, "val_nll": 0.55, "val_macro_f1": 0.58},  # lowest NLL
        {"epoch": 3, "val_nll": 0.60, "val_macro_f1": 0.66},  # highest macro-F1 (first of the tie)
        {"epoch": 4, "val_nll": 0.80, "val_macro_f1": 0.66},
    ]
    assert select_epoch(history, "nll") == 2
    assert select_epoch(history, "macro_f1") == 3
    with pytest.raises(ValueError, match="select_classifier"):
        TrainConfig(select_classifier="accuracy")
    with pytest.raises(ValueError, match="class_weight_power"):
        TrainConfig(class_weight_power=-1.0)
    old = TrainConfig.from_dict({"epochs": 3})  # cards from before the options: the paper's plain NLL
    assert old.class_weight_power == 0.0 and old.select_classifier == "nll"


@pytest.mark.slow
def test_weighted_loss_and_macro_f1_selection(windows: Windows) -> None:
    cfg = TrainConfig(epochs=4, batch_size=32, lr=2e-3, seed=1, threads=1)
    plain = train(windows, cfg)
    weighted_cfg = TrainConfig(
        epochs=4,
        batch_size=32,
        lr=2e-3,
        seed=1,
        threads=1,
        class_weight_power=1.0,
        select_classifier="macro_f1",
    )
    weighted = train(windows, weighted_cfg)
    t = weighted.card["training"]
    assert t["best_epoch"]["classifier"] == select_epoch(weighted.history, "macro_f1")
    assert t["classifier_selected_by"] == "val_macro_f1" and "beyond the paper" in t["classifier_loss"]
    assert plain.card["training"]["classifier_loss"].startswith("sum over steps of the NLL")
    assert TrainConfig.from_dict(t["config"]) == weighted_cfg
    # the regressor does not depend on the classifier's loss: same batches, same weights
    a, b = plain.model.regressor.state_dict(), weighted.model.regressor.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(plain.model.classifier.fc2.weight, weighted.model.classifier.fc2.weight)
    for row in weighted.history:
        assert 0.0 <= row["val_macro_f1"] <= 1.0 and len(row["val_recall"]) == 3


def test_horizon_weights_by_hand() -> None:
    """Residual RMS 1, 2, 2, 4, 4 m over the steps: power 1 weighs them 4, 2, 2, 1, 1 (then mean 1),
    power 0 equally; the weighted loss multiplies each step's squared error by its weight."""
    residual = np.zeros((2, 5, 2), np.float32)
    residual[:, :, 0] = np.array([1, 2, 2, 4, 4], np.float32) * np.array([[1], [-1]])
    w = horizon_weights(residual, 1.0)
    np.testing.assert_allclose(w, np.array([4, 2, 2, 1, 1]) / 2.0, rtol=1e-6)
    np.testing.assert_allclose(horizon_weights(residual, 0.0), np.ones(5))
    pred, true = torch.zeros(1, 5, 2), torch.zeros(1, 5, 2)
    true[0, 0, 0] = 1.0  # a 1 m error at 1 s only
    assert float(regressor_loss(pred, true, torch.from_numpy(w))) == pytest.approx(np.sqrt(2.0 / 5))
    with pytest.raises(ValueError, match="horizon_weight_power"):
        TrainConfig(horizon_weight_power=-1)


@pytest.mark.parametrize(
    ("field", "value"), [("horizon_weight_power", 1.0), ("predicted_maneuver_share", 0.5)]
)
def test_regressor_options_change_the_regressor_only(windows: Windows, field: str, value: float) -> None:
    """Same seed and batches: weighting the horizons, or feeding the regressor the classifier's
    maneuvers for half the windows, changes the regressor's weights, not the classifier's, and is
    recorded in the card; a value out of range is refused."""
    plain = TrainConfig(epochs=1, batch_size=64, seed=2, threads=1)
    changed = dataclasses.replace(plain, **{field: value})
    a, b = train(windows, plain), train(windows, changed)
    assert torch.equal(a.model.classifier.fc2.weight, b.model.classifier.fc2.weight)
    assert not torch.equal(a.model.regressor.fc2.weight, b.model.regressor.fc2.weight)
    assert b.card["training"]["config"][field] == value
    with pytest.raises(ValueError, match=field):
        TrainConfig(**{field: 3.0})


def test_lr_schedules() -> None:
    assert [lr_factor("constant", s, 100) for s in (0, 50, 100)] == [1.0, 1.0, 1.0]
    assert [lr_factor("cosine", s, 100) for s in (0, 50, 100, 120)] == pytest.approx([1.0, 0.5, 0.0, 0.0])
    assert lr_factor("cosine", 25, 100) == pytest.approx(0.5 * (1 + np.sqrt(0.5)))
    with pytest.raises(ValueError, match="lr_schedule"):
        TrainConfig(lr_schedule="step")


def test_cosine_schedule_is_applied(windows: Windows) -> None:
    """Same seed and batches: the cosine run differs from the constant one (only the lr differs)."""
    cosine = TrainConfig(epochs=2, batch_size=64, seed=2, threads=1, lr_schedule="cosine")
    a = train(windows, cosine)
    b = train(windows, TrainConfig(epochs=2, batch_size=64, seed=2, threads=1))
    assert not torch.equal(a.model.regressor.fc2.weight, b.model.regressor.fc2.weight)
    assert not torch.equal(a.model.classifier.fc2.weight, b.model.classifier.fc2.weight)
    assert TrainConfig.from_dict(a.card["training"]["config"]) == cosine


def test_labelled_skips_unknown_futures(windows: Windows) -> None:
    w = Windows(
        windows.inputs, windows.present, windows.future.copy(), windows.maneuver.copy(), windows.index
    )
    w.future[0, 3] = np.nan
    w.maneuver[6, 0] = -1
    train_idx = labelled(w, ("train",))
    assert 0 not in train_idx and 6 not in train_idx and 1 in train_idx
    assert len(train_idx) == 420 - 2


@pytest.mark.slow
def test_training_reduces_both_losses(windows: Windows) -> None:
    result = train(windows, TrainConfig(epochs=6, batch_size=32, lr=2e-3, seed=1, threads=1))
    first, last = result.history[0], result.history[-1]
    assert last["train_nll"] < 0.6 * first["train_nll"]
    assert last["train_rmse"] < 0.6 * first["train_rmse"]
    assert last["val_nll"] < first["val_nll"] and last["val_rmse_m"] < first["val_rmse_m"]
    best = result.card["training"]["best_epoch"]
    assert best["regressor"] == 1 + int(np.argmin([h["val_rmse"] for h in result.history]))
    assert best["classifier"] == 1 + int(np.argmin([h["val_nll"] for h in result.history]))  # default: NLL
    assert count_parameters(result.model) == 65_721


@pytest.mark.slow
def test_overfits_a_few_windows(windows: Windows) -> None:
    few = Windows(
        windows.inputs[:6],
        windows.present[:6],
        windows.future[:6],
        windows.maneuver[:6],
        windows.index.slice(0, 6).set_column(3, "split", pa.array(["train"] * 6)),
    )
    result = train(few, TrainConfig(epochs=250, batch_size=6, lr=3e-3, seed=0, threads=1))
    assert result.card["training"]["selected_on"] == "train"  # no val windows: selection on train
    assert result.history[-1]["train_nll"] < 0.05  # summed over 5 steps
    assert result.history[0]["train_rmse"] * result.card["normalisation"]["future"]["std"] > 10.0  # m
    pred = STCNNForecaster(result.model, result.card).predict(few.inputs, few.present)
    np.testing.assert_array_equal(pred.maneuver, few.maneuver)
    assert np.all(rmse(displacement_errors(pred.offsets, few.future)) < 0.4)  # m, offsets up to 175 m


def test_seed_reproduces_weights(windows: Windows) -> None:
    cfg = TrainConfig(epochs=2, batch_size=64, seed=7, threads=1)
    a = train(windows, cfg).model.state_dict()
    b = train(windows, cfg).model.state_dict()
    c = train(windows, TrainConfig(epochs=2, batch_size=64, seed=8, threads=1)).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_save_load_predict_identical(windows: Windows, tmp_path) -> None:
    result = train(windows, TrainConfig(epochs=1, batch_size=128, seed=3, threads=1))
    card_path = save_checkpoint(result.model, result.card, tmp_path / "model")
    card = json.loads(card_path.read_text())
    assert card["architecture"]["parameters"] == {"classifier": 32_863, "regressor": 32_858, "total": 65_721}
    assert card["format"] == "lanecast-stcnn" and "inputs" in card["normalisation"]
    before = STCNNForecaster(result.model, result.card).predict(windows.inputs, windows.present, top_k=3)
    net, loaded_card = load_checkpoint(tmp_path / "model")
    after = STCNNForecaster(net, loaded_card).predict(windows.inputs, windows.present, top_k=3, batch_size=77)
    for key in ("offsets", "probs", "maneuver", "top_sequences", "top_probs", "top_offsets"):
        np.testing.assert_array_equal(getattr(before, key), getattr(after, key), err_msg=key)
    assert resolve(tmp_path / "model") == (tmp_path / "model/stcnn.safetensors", card_path)


# A small seeded model saved as a checkpoint; run both in this process and in a fresh one.
_SAVE_SMALL_MODEL = """
import sys
from pathlib import Path
import torch
from lanecast.models.checkpoint import save_checkpoint
from lanecast.models.stcnn import STCNN, STCNNConfig

def save(out):
    torch.manual_seed(0)
    norm = {"inputs": {"mean": [0.0] * 4, "std": [1.0] * 4}, "future": {"mean": [0.0] * 10, "std": 1.0}}
    save_checkpoint(STCNN(STCNNConfig(hidden=8)), {"normalisation": norm}, out)

if __name__ == "__main__":
    save(Path(sys.argv[1]))
"""


def _header(path: Path) -> tuple[int, dict]:
    data = path.read_bytes()
    size = int.from_bytes(data[:8], "little")
    return size, json.loads(data[8 : 8 + size])


def test_checkpoint_bytes_are_reproducible(tmp_path: Path) -> None:
    """The same tensors and card give the same bytes in another process (safetensors' own writer
    orders ``__metadata__`` by a per-process hash); the library and our loader read them back."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    script = [sys.executable, "-c", _SAVE_SMALL_MODEL, str(tmp_path / "a")]
    subprocess.run(script, cwd=REPO, env=env, check=True, timeout=120)
    namespace: dict = {}
    exec(_SAVE_SMALL_MODEL, namespace)
    namespace["save"](tmp_path / "b")
    for name in ("stcnn.safetensors", "stcnn.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    weights = tmp_path / "a/stcnn.safetensors"
    size, header = _header(weights)
    assert size % 8 == 0 and next(iter(header)) == "__metadata__"
    assert list(header["__metadata__"].items()) == [("format", "lanecast-stcnn"), ("format_version", "1")]
    net, _ = load_checkpoint(tmp_path / "a")
    state = net.state_dict()
    library = load_file(str(weights))
    assert library.keys() == state.keys() and all(torch.equal(library[k], state[k]) for k in state)
    with safe_open(str(weights), "pt") as f:
        assert f.metadata() == header["__metadata__"]


def test_write_safetensors_ignores_insertion_order_and_matches_the_library(tmp_path: Path) -> None:
    gen = torch.Generator().manual_seed(0)
    tensors = {
        "w": torch.randn(3, 4, generator=gen),
        "steps": torch.arange(5),
        "mask": torch.tensor([True, False, True]),
        "half": torch.randn(2, generator=gen).to(torch.bfloat16),
        "scalar": torch.tensor(2.5, dtype=torch.float64),
        "empty": torch.zeros(0, 4),
        "column": torch.randn(4, 3, generator=gen)[:, 1],  # not contiguous
    }
    metadata = {f"key{i}": str(i) for i in range(10)}
    write_safetensors(tmp_path / "a", tensors, metadata)
    write_safetensors(tmp_path / "b", dict(reversed(tensors.items())), dict(reversed(metadata.items())))
    assert (tmp_path / "a").read_bytes() == (tmp_path / "b").read_bytes()
    back = load_file(str(tmp_path / "a"))
    assert back.keys() == tensors.keys()
    assert all(back[k].dtype == v.dtype and torch.equal(back[k], v) for k, v in tensors.items())
    # one dtype and one metadata key (no order to vary): exactly the library's bytes
    floats = {k: v.contiguous() for k, v in tensors.items() if v.dtype == torch.float32}
    write_safetensors(tmp_path / "ours", floats, {"format": "x"})
    save_file(floats, str(tmp_path / "lib"), metadata={"format": "x"})
    assert (tmp_path / "ours").read_bytes() == (tmp_path / "lib").read_bytes()


def test_shipped_weights_load_and_resave_unchanged(tmp_path: Path) -> None:
    net, card = load_checkpoint(None)
    save_checkpoint(net, card, tmp_path / "a")
    save_checkpoint(load_checkpoint(tmp_path / "a")[0], card, tmp_path / "b")
    again = load_checkpoint(tmp_path / "b")[0].state_dict()
    assert all(torch.equal(again[k], v) for k, v in net.state_dict().items())
    a, b = (tmp_path / "a/stcnn.safetensors").read_bytes(), (tmp_path / "b/stcnn.safetensors").read_bytes()
    assert a == b


def test_load_rejects_bad_files(tmp_path) -> None:
    (tmp_path / "m").mkdir()
    (tmp_path / "m/stcnn.json").write_text('{"format": "lanecast-stcnn", "format_version": 1}')
    (tmp_path / "m/stcnn.safetensors").write_bytes(b"\x80\x04not safetensors")
    with pytest.raises(InputError, match="architecture"):
        load_checkpoint(tmp_path / "m")
    with pytest.raises(InputError, match="expected one model"):
        load_checkpoint(tmp_path)


def test_forecaster_equals_the_plain_networks(windows: Windows) -> None:
    """The fused, channels-last, batched path gives what classifier → argmax → regressor gives."""
    from lanecast.io_adapters.contracts.normalisation import compute_stats, normalise

    torch.manual_seed(5)
    model = STCNN().eval()
    stats = compute_stats(windows.inputs, windows.present)
    mean, std = future_stats(windows.future)
    card = {"normalisation": {"inputs": stats.to_dict(), "future": {"mean": mean.tolist(), "std": std}}}
    pred = STCNNForecaster(model, card).predict(windows.inputs, windows.present, top_k=2, batch_size=128)
    with torch.no_grad():
        logits, offsets = model(torch.from_numpy(normalise(windows.inputs, windows.present, stats)))
    np.testing.assert_array_equal(pred.maneuver, logits.argmax(2).numpy())
    np.testing.assert_allclose(pred.offsets, offsets.numpy() * std + mean, atol=1e-4)
    assert pred.probs is not None
    np.testing.assert_allclose(pred.probs, torch.softmax(logits, 2).numpy(), atol=1e-6)
    np.testing.assert_allclose(pred.top_probs[:, 0], pred.probs.max(axis=2).prod(axis=1), rtol=1e-5)


def test_init_starts_from_the_given_weights_and_normalisation(windows: Windows, tmp_path) -> None:
    """--init: with lr 0 fine-tuning keeps the given weights exactly; the normalisation is the init
    model's even on data with other statistics; with lr > 0 the weights move away from them."""
    base = train(windows, TrainConfig(epochs=1, batch_size=128, seed=3, threads=1))
    other = synthetic_windows(300, seed=5)
    other.inputs[:, 2] *= 0.3  # slower traffic: other input statistics
    still = train(
        other, TrainConfig(epochs=1, batch_size=64, lr=0.0, threads=1), init_from=(base.model, base.card)
    )
    for k, v in base.model.state_dict().items():
        assert torch.equal(v, still.model.state_dict()[k]), k
    assert still.card["normalisation"] == base.card["normalisation"]
    fresh = train(other, TrainConfig(epochs=1, batch_size=64, threads=1))
    assert fresh.card["normalisation"]["inputs"] != base.card["normalisation"]["inputs"]
    moved = train(other, TrainConfig(epochs=1, batch_size=64, threads=1), init_from=(base.model, base.card))
    w0, w1 = base.model.state_dict(), moved.model.state_dict()
    assert not all(torch.equal(w0[k], w1[k]) for k in w0)
    # closer to the init than a model trained from scratch
    dist = lambda a, b: sum(float((a[k] - b[k]).norm()) for k in a)  # noqa: E731
    assert dist(w0, w1) < dist(w0, fresh.model.state_dict())


def test_cli_train_init(windows: Windows, tmp_path, capsys) -> None:
    from lanecast.io_adapters.windows_store.dataset import save_windows
    from lanecast.workflows.cli import main as cli_main

    base = train(windows, TrainConfig(epochs=1, batch_size=128, seed=3, threads=1))
    save_checkpoint(base.model, base.card, tmp_path / "base")
    save_windows(windows, tmp_path / "w")
    code = cli_main(
        ["train", str(tmp_path / "w"), "--init", str(tmp_path / "base"), "--out", str(tmp_path / "tuned"),
         "--epochs", "1", "--lr", "0", "--threads", "1"]
    )  # fmt: skip
    assert code == 0
    net, card = load_checkpoint(tmp_path / "tuned")
    assert card["training"]["data"]["init"] == str(tmp_path / "base")
    for k, v in base.model.state_dict().items():
        assert torch.equal(v, net.state_dict()[k]), k


def test_position_noise_changes_training_only(windows: Windows) -> None:
    clean = train(windows, TrainConfig(epochs=1, batch_size=64, seed=1, threads=1))
    noisy = train(windows, TrainConfig(epochs=1, batch_size=64, seed=1, threads=1, position_noise_m=0.3))
    a, b = clean.model.state_dict(), noisy.model.state_dict()
    assert not all(torch.equal(a[k], b[k]) for k in a)
    assert clean.card["normalisation"] == noisy.card["normalisation"]
    with pytest.raises(ValueError):
        TrainConfig(position_noise_m=-1.0)
    kinematic = train(
        windows,
        TrainConfig(epochs=1, batch_size=64, seed=1, threads=1, speed_noise_mps=0.5, acc_noise_mps2=0.5),
    )
    c = kinematic.model.state_dict()
    assert not all(torch.equal(a[k], c[k]) for k in a)
    with pytest.raises(ValueError):
        TrainConfig(acc_noise_mps2=-0.1)


def test_card_has_the_training_distribution(windows: Windows) -> None:
    card = train(windows, TrainConfig(epochs=1, batch_size=128, threads=1)).card
    dist = card["training"]["data"]["distribution"]
    train_idx = labelled(windows, ("train",))
    speed = windows.inputs[train_idx, 2, 4, -1]
    assert dist["speed_mps"]["p50"] == pytest.approx(float(np.median(speed)), abs=1e-3)
    assert dist["speed_mps"]["p0.5"] >= 20.0 and dist["speed_mps"]["p99.5"] <= 35.0
    assert dist["neighbours_present"]["p50"] == 1.0  # only F


def test_offsets_relative_to_constant_velocity(windows: Windows) -> None:
    """future_relative_to="cv": the card says so, the regressor learns the correction to the CV
    extrapolation, and predictions (torch) add it back: an untrained correction of ~0 gives ~CV."""
    from lanecast.models.baselines import constant_velocity

    result = train(windows, TrainConfig(epochs=2, batch_size=64, threads=1, future_relative_to="cv"))
    assert result.card["normalisation"]["future"]["relative_to"] == "cv"
    idx = labelled(windows, ("test",))
    pred = STCNNForecaster(result.model, result.card).predict(windows.inputs[idx], windows.present[idx])
    cv = constant_velocity().predict(windows.inputs[idx], windows.present[idx])
    err_model = rmse(displacement_errors(pred.offsets, windows.future[idx]))
    err_cv = rmse(displacement_errors(cv.offsets, windows.future[idx]))
    assert err_model[-1] < err_cv[-1]  # lane changes: the correction helps at 5 s
    # zero the regressor's last layer: the prediction is CV + the mean correction
    model = result.model
    with torch.no_grad():
        model.regressor.fc2.weight.zero_()
        model.regressor.fc2.bias.zero_()
    flat = STCNNForecaster(model, result.card).predict(windows.inputs[idx], windows.present[idx])
    mean = np.asarray(result.card["normalisation"]["future"]["mean"], np.float32)
    np.testing.assert_allclose(flat.offsets, cv.offsets + mean, atol=1e-3)
    with pytest.raises(ValueError):
        TrainConfig(future_relative_to="ca")


def test_neighbour_dropout_shows_targets_alone(windows: Windows) -> None:
    """A dropped window keeps its target (inputs and presence) and loses every neighbour: presence
    False and the normalised inputs exactly 0, as for a window recorded without neighbours; the
    others are untouched; the future is the same either way."""
    from lanecast.io_adapters.contracts.normalisation import compute_stats, normalise
    from lanecast.io_adapters.contracts.windows import TARGET_ROW
    from lanecast.models.augment import Augmentation
    from lanecast.models.train import _Batches

    idx = np.arange(64)
    present = np.asarray(windows.present[idx])
    assert present[:, np.arange(8) != TARGET_ROW].any()
    stats = compute_stats(windows.inputs[idx], windows.present[idx])
    batches = _Batches(windows, stats, np.zeros((5, 2), np.float32), 1.0)
    cpu = torch.device("cpu")
    x0, y0, _ = batches.get(idx, cpu)
    x1, y1, _ = batches.get(idx, cpu, Augmentation(neighbour_dropout=1.0), np.random.default_rng(0))
    torch.testing.assert_close(y0, y1)
    alone = np.asarray(windows.inputs[idx]) * (np.arange(8) == TARGET_ROW)[None, None, :, None]
    only_target = present & (np.arange(8) == TARGET_ROW)[None, :, None]
    np.testing.assert_array_equal(x1.numpy(), normalise(alone, only_target, stats))
    np.testing.assert_array_equal(x1.numpy()[:, :, TARGET_ROW], x0.numpy()[:, :, TARGET_ROW])
    x_half, _, _ = batches.get(idx, cpu, Augmentation(neighbour_dropout=0.5), np.random.default_rng(0))
    kept = (x_half.numpy() == x0.numpy()).all(axis=(1, 2, 3))
    assert 0 < kept.sum() < len(idx)
    with pytest.raises(ValueError, match="neighbour_dropout"):
        TrainConfig(neighbour_dropout=1.5)


def test_derivative_outliers_touch_only_present_speed_and_acceleration(windows: Windows) -> None:
    """Outliers go into the speed (upwards only) and acceleration inputs of present entries, at
    about the share asked for; positions, absent entries and the future are untouched."""
    from lanecast.io_adapters.contracts.normalisation import compute_stats
    from lanecast.models.augment import Augmentation
    from lanecast.models.train import _Batches

    idx = np.arange(256)
    present = np.asarray(windows.present[idx])
    stats = compute_stats(windows.inputs[idx], windows.present[idx])
    batches = _Batches(windows, stats, np.zeros((5, 2), np.float32), 1.0)
    cpu = torch.device("cpu")
    x0, y0, _ = batches.get(idx, cpu)
    x1, y1, _ = batches.get(idx, cpu, Augmentation(derivative_outliers=0.2), np.random.default_rng(1))
    x0n, x1n = x0.numpy(), x1.numpy()
    torch.testing.assert_close(y0, y1)
    np.testing.assert_array_equal(x1n[:, :2], x0n[:, :2])
    changed = (x1n != x0n).any(axis=1)  # [B, 8, T]
    assert not (changed & ~present).any()
    share = changed.sum() / present.sum()
    assert 0.15 < share < 0.25
    assert (x1n[:, 2] >= x0n[:, 2]).all()  # speed is normalised by a positive scale: only upwards
    assert (x1n[:, 3] != x0n[:, 3]).sum() > 0.9 * changed.sum()
    with pytest.raises(ValueError, match="derivative_outliers"):
        TrainConfig(derivative_outliers=-0.1)
