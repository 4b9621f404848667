"""ONNX export and ONNX Runtime prediction: the same forecasts as torch, stale exports never used, no torch."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.errors import InputError
from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, read_card, resolve
from lanecast.models.checkpoint import load_checkpoint, save_checkpoint
from lanecast.models.onnx_export import parity_with_torch
from lanecast.models.onnx_predict import OnnxForecaster, onnx_file
from lanecast.models.predict import STCNNForecaster
from lanecast.models.runtime import load_forecaster
from lanecast.pipeline.make_windows import make_windows
from lanecast.workflows.cli import main


@pytest.fixture(scope="module")
def windows(sim_recording_dir: Path):  # type: ignore[no-untyped-def]
    """Every 3 s window of the simulated recording, future or not (real traffic, not random tensors)."""
    return make_windows(highd.read([sim_recording_dir]), stride=5, require_future=False, split="none")


@pytest.fixture
def model_copy(tmp_path: Path) -> Path:
    """The shipped model (weights and card, without its ONNX file) in a fresh directory."""
    out = tmp_path / "model"
    out.mkdir()
    for suffix in (".safetensors", ".json"):
        shutil.copy(WEIGHTS_DIR / f"{SHIPPED_STEM}{suffix}", out / f"{SHIPPED_STEM}{suffix}")
    card = json.loads((out / f"{SHIPPED_STEM}.json").read_text())
    card.pop("onnx", None)
    (out / f"{SHIPPED_STEM}.json").write_text(json.dumps(card))
    return out


def assert_same_forecasts(ours, theirs) -> None:  # type: ignore[no-untyped-def]
    """Offsets (m) and probabilities within 1e-5; maneuvers and top-K sequences identical."""
    np.testing.assert_array_equal(ours.top_sequences, theirs.top_sequences)
    np.testing.assert_array_equal(ours.maneuver, theirs.maneuver)
    np.testing.assert_allclose(ours.top_offsets, theirs.top_offsets, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours.offsets, theirs.offsets, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours.probs, theirs.probs, rtol=0, atol=1e-5)
    np.testing.assert_allclose(ours.top_probs, theirs.top_probs, rtol=0, atol=1e-5)
    for name in ("offsets", "probs", "maneuver", "top_sequences", "top_probs", "top_offsets"):
        assert getattr(ours, name).dtype == getattr(theirs, name).dtype, name


def test_shipped_onnx_is_fresh_and_serves_by_default() -> None:
    """The shipped ONNX file was exported from the shipped weights (rerun `lanecast export` after training)."""
    weights, card_path = resolve(None)
    path, why = onnx_file(card_path, weights, read_card(card_path))
    assert path == WEIGHTS_DIR / f"{SHIPPED_STEM}.onnx", (
        f"{why}: run `lanecast export {WEIGHTS_DIR} --to onnx`"
    )
    assert isinstance(load_forecaster(None), OnnxForecaster)


@pytest.mark.parametrize("top_k", [3, 1, 5])
def test_onnx_runtime_matches_torch_on_real_windows(windows, top_k: int) -> None:  # type: ignore[no-untyped-def]
    inputs, present = np.asarray(windows.inputs), np.asarray(windows.present)
    assert len(inputs) > 500
    ours = load_forecaster(None, engine="onnx").predict(inputs, present, top_k=top_k, batch_size=333)
    theirs = STCNNForecaster.load(None).predict(inputs, present, top_k=top_k, batch_size=4096)
    assert ours.top_sequences is not None and ours.top_sequences.shape == (len(inputs), top_k, 5)
    assert_same_forecasts(ours, theirs)
    assert (ours.maneuver != 0).any()  # lane changes are predicted, not only straight driving


def test_export_writes_a_complete_model_with_shapes_in_the_card(
    model_copy: Path, tmp_path: Path, windows
) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "deploy"
    assert main(["export", str(model_copy), "--to", "onnx", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        f"{SHIPPED_STEM}{s}" for s in (".json", ".onnx", ".safetensors")
    ]
    assert "onnx" not in read_card(model_copy / f"{SHIPPED_STEM}.json")  # the source model is untouched
    section = read_card(out / f"{SHIPPED_STEM}.json")["onnx"]
    assert section["opset"] == 17
    assert section["inputs"]["inputs"] == {"dtype": "float32", "shape": ["N", 4, 8, 30]}
    assert section["outputs"]["top_offsets"] == {"dtype": "float32", "shape": ["N", "K", 5, 2]}
    # within the export's tolerance, atol + rtol·|torch| element by element (float32 offsets reach ~200 m)
    difference, excess = parity_with_torch(
        out / f"{SHIPPED_STEM}.onnx", STCNNForecaster.load(out), read_card(out / f"{SHIPPED_STEM}.json")
    )
    assert excess <= 0
    assert 0 <= section["max_difference_to_torch"] < 1e-3
    assert difference < 1e-3

    import onnx

    graph = onnx.load(str(out / f"{SHIPPED_STEM}.onnx")).graph
    assert [i.name for i in graph.input] == ["inputs", "present", "k"]
    assert [o.name for o in graph.output] == [
        "probs",
        "maneuver",
        "top_sequences",
        "top_probs",
        "top_offsets",
    ]
    dims = [d.dim_param or d.dim_value for d in graph.input[0].type.tensor_type.shape.dim]
    assert dims[1:] == [4, 8, 30] and isinstance(dims[0], str)

    served = load_forecaster(out)
    assert isinstance(served, OnnxForecaster)
    inputs, present = np.asarray(windows.inputs[:700]), np.asarray(windows.present[:700])
    assert_same_forecasts(
        served.predict(inputs, present), STCNNForecaster.load(model_copy).predict(inputs, present)
    )


def test_a_retrained_model_is_served_by_torch_until_exported_again(
    model_copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["export", str(model_copy), "--to", "onnx"]) == 0
    assert isinstance(load_forecaster(model_copy), OnnxForecaster)
    net, card = load_checkpoint(model_copy)
    with torch.no_grad():
        net.classifier.fc2.bias += 1.0  # "retrained": other weights, same file names, the old card's sections
    save_checkpoint(net, card, model_copy, stem=SHIPPED_STEM)
    capsys.readouterr()
    served = load_forecaster(model_copy)
    assert isinstance(served, STCNNForecaster)
    assert "stale" in capsys.readouterr().err
    with pytest.raises(InputError, match="stale"):
        load_forecaster(model_copy, engine="onnx")

    assert main(["export", str(model_copy), "--to", "onnx"]) == 0
    assert isinstance(load_forecaster(model_copy), OnnxForecaster)
    (model_copy / f"{SHIPPED_STEM}.onnx").unlink()
    capsys.readouterr()
    assert isinstance(load_forecaster(model_copy), STCNNForecaster)
    assert "missing" in capsys.readouterr().err


def test_empty_and_top_zero_predictions_have_the_torch_shapes() -> None:
    ours, theirs = load_forecaster(None, engine="onnx"), STCNNForecaster.load(None)
    for n, k in ((0, 3), (1, 0), (2, 1)):
        rng = np.random.default_rng(n)
        inputs = rng.standard_normal((n, 4, 8, 30)).astype(np.float32)
        present = rng.random((n, 8, 30)) > 0.5
        a, b = ours.predict(inputs, present, top_k=k), theirs.predict(inputs, present, top_k=k)
        for name in ("offsets", "probs", "maneuver", "top_sequences", "top_probs", "top_offsets"):
            assert getattr(a, name).shape == getattr(b, name).shape, (n, k, name)


@pytest.mark.slow
def test_annotating_with_onnx_runtime_never_imports_torch(sim_recording_dir: Path, tmp_path: Path) -> None:
    """`lanecast annotate` end to end (CLI, bulk runner, forecasts, messages) without torch in the process."""
    from lanecast.io_adapters.formats import registry

    log = registry.write_any(highd.read([sim_recording_dir]), tmp_path / "drive.mcap", "mcap")
    code = (
        "import sys\n"
        "from lanecast.workflows.cli import main\n"
        f"assert main(['annotate', {str(log)!r}, '--out', {str(tmp_path / 'out')!r}]) == 0\n"
        "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout
    assert (tmp_path / "out" / "drive.mcap").stat().st_size > log.stat().st_size


def test_an_onnx_export_onnx_runtime_cannot_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An .onnx file the card vouches for (its sha256 updated) that is not ONNX escaped as
    onnxruntime's InvalidProtobuf traceback; now ``engine="onnx"`` refuses it naming the file and
    ``"auto"`` predicts with torch, saying why. (A file that differs from the card's checksum was
    already never used.)"""
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, file_sha256
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.runtime import load_forecaster

    model = tmp_path / "model"
    model.mkdir()
    for suffix in (".safetensors", ".json", ".onnx"):
        (model / f"{SHIPPED_STEM}{suffix}").write_bytes(
            (WEIGHTS_DIR / f"{SHIPPED_STEM}{suffix}").read_bytes()
        )
    onnx = model / f"{SHIPPED_STEM}.onnx"
    onnx.write_bytes(b"not onnx" * 100)
    card_path = model / f"{SHIPPED_STEM}.json"
    card = json.loads(card_path.read_text())
    card["onnx"]["sha256"] = file_sha256(onnx)
    card_path.write_text(json.dumps(card))
    with pytest.raises(InputError, match="ONNX Runtime cannot load it") as err:
        load_forecaster(model, engine="onnx")
    assert err.value.path == str(onnx)
    capsys.readouterr()
    assert isinstance(load_forecaster(model), STCNNForecaster)
    assert f"{SHIPPED_STEM}.onnx: ONNX Runtime cannot load it" in capsys.readouterr().err


def test_export_refuses_a_users_onnx_file_and_replaces_it_with_force(
    model_copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "deploy"
    out.mkdir()
    users = out / f"{SHIPPED_STEM}.onnx"
    users.write_bytes(b"my own graph")
    capsys.readouterr()
    assert main(["export", str(model_copy), "--to", "onnx", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(users) in err and "not an output of lanecast's" in err and "--force" in err
    assert users.read_bytes() == b"my own graph"
    assert sorted(p.name for p in out.iterdir()) == [users.name]  # nothing else written either
    assert main(["export", str(model_copy), "--to", "onnx", "--out", str(out), "--force"]) == 0
    assert users.read_bytes().startswith(b"\x08")  # an ONNX protobuf (ir_version field) now
    assert main(["export", str(model_copy), "--to", "onnx", "--out", str(out)]) == 0  # its own: replaced


def test_a_batch_of_one_predicts_as_a_batch_of_many(windows) -> None:  # type: ignore[no-untyped-def]
    """The one-call path (the compiled session, no slicing) gives what the batched path gives."""
    forecaster = load_forecaster(None, engine="onnx")
    inputs, present = np.asarray(windows.inputs[:7]), np.asarray(windows.present[:7])
    many = forecaster.predict(inputs, present, batch_size=3)
    ones = [forecaster.predict(inputs[i : i + 1], present[i : i + 1], batch_size=1) for i in range(7)]
    for name in ("offsets", "probs", "top_sequences", "top_offsets"):
        np.testing.assert_allclose(
            np.concatenate([getattr(o, name) for o in ones]), getattr(many, name), rtol=1e-5, atol=1e-5
        )
    assert forecaster.predict(inputs.astype(np.float64), present, top_k=1).top_offsets.shape == (7, 1, 5, 2)
