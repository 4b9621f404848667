"""Export a checkpoint to ONNX: the whole library prediction path as one graph, for ONNX Runtime.

The graph is what ``STCNNForecaster.predict`` computes per batch, from physical inputs to physical
outputs: normalise with the card's statistics (absent entries 0), both networks (fused, see
``FusedSTCNN``), per-step maneuver probabilities, the K most probable of the 3^5 maneuver
sequences (one matrix product with their one-hot codes, then TopK), the regressor once per
sequence, de-normalised offsets. K is an input of the graph, the batch size a dynamic axis.

The ONNX file sits beside the weights as ``<stem>.onnx``; the card gets an ``onnx`` section with the
opset, the inputs' and outputs' shapes, the SHA-256 of the safetensors (and of the normalisation) it was exported from (a
retrained model leaves a stale ONNX file that the loader detects and ignores, see
``lanecast.models.onnx_predict``), and the largest difference to torch measured at export.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from lanecast.io_adapters.contracts.normalisation import NormStats
from lanecast.io_adapters.contracts.windows import HORIZON_S, TARGET_ROW
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.ownership import check_replaceable_files
from lanecast.models.baselines import CV_SPAN, _fit_matrix
from lanecast.models.card import file_sha256, lanecast_version, normalisation_sha256, write_card
from lanecast.models.checkpoint import load_checkpoint, resolve
from lanecast.models.onnx_predict import GRAPH_VERSION, OnnxForecaster
from lanecast.models.predict import FusedSTCNN, STCNNForecaster, all_sequences
from lanecast.models.stcnn import STCNN

#: ONNX opset of the exported graphs (ONNX Runtime ≥ 1.12 runs it).
OPSET = 17
#: Graph inputs and outputs: name → (dtype, shape); "N" is the batch, "K" the number of sequences.
GRAPH_INPUTS: dict[str, tuple[str, list[Any]]] = {
    "inputs": ("float32", ["N", 4, 8, 30]),
    "present": ("bool", ["N", 8, 30]),
    "k": ("int64", []),
}
GRAPH_OUTPUTS: dict[str, tuple[str, list[Any]]] = {
    "probs": ("float32", ["N", 5, 3]),
    "maneuver": ("int64", ["N", 5]),
    "top_sequences": ("int64", ["N", "K", 5]),
    "top_probs": ("float32", ["N", "K"]),
    "top_offsets": ("float32", ["N", "K", 5, 2]),
}
#: Difference to torch accepted at export, |onnx − torch| ≤ atol + rtol·|torch| (physical units:
#: metres, probabilities). The relative part is float32's: offsets of a fast target reach ~200 m, where
#: one float32 step is already 1.5e-5 m and a different summation order moves the last bits.
EXPORT_ATOL = 1e-4
EXPORT_RTOL = 1e-5


class PredictionGraph(nn.Module):
    """The library's prediction path as one traceable module.

    Forward: inputs float32 [N, 4, 8, 30] physical, present bool [N, 8, 30], k int64 scalar →
    probs [N, 5, 3], maneuver [N, 5], top_sequences [N, K, 5], top_probs [N, K], top_offsets
    [N, K, 5, 2] (window frame, metres).
    """

    sequences: torch.Tensor
    one_hot: torch.Tensor
    in_mean: torch.Tensor
    in_std: torch.Tensor
    out_mean: torch.Tensor
    out_std: torch.Tensor
    cv_weights: torch.Tensor
    horizons: torch.Tensor

    def __init__(self, model: STCNN, card: dict[str, Any]) -> None:
        super().__init__()
        reference = STCNNForecaster(model, card)
        cfg = model.config
        self.fused = FusedSTCNN(model)
        self.regressor = model.regressor
        self.horizon = cfg.horizon
        sequences = all_sequences(cfg.horizon, cfg.classes)  # [S, H]
        one_hot = F.one_hot(sequences, cfg.classes).to(torch.float32).reshape(len(sequences), -1)
        self.register_buffer("sequences", sequences)
        self.register_buffer("one_hot", one_hot.T.contiguous())  # [H·C, S]
        stats = reference.input_stats
        self.register_buffer("in_mean", torch.from_numpy(stats.mean.copy()).view(1, -1, 1, 1))
        self.register_buffer("in_std", torch.from_numpy(stats.std.copy()).view(1, -1, 1, 1))
        self.register_buffer("out_mean", torch.from_numpy(reference.future_mean.copy()))
        self.register_buffer("out_std", torch.tensor(float(reference.future_std)))
        # offsets relative to the constant-velocity extrapolation (card normalisation.future.relative_to)
        self.relative_to_cv = reference.relative_to == "cv"
        velocity = _fit_matrix(CV_SPAN, 1)[
            1
        ]  # least-squares velocity weights over the last CV_SPAN positions
        self.register_buffer("cv_weights", torch.tensor(velocity, dtype=torch.float64))
        self.register_buffer("horizons", torch.tensor(HORIZON_S, dtype=torch.float64).view(1, -1, 1))

    def forward(
        self, inputs: torch.Tensor, present: torch.Tensor, k: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        x = (inputs - self.in_mean) / self.in_std * present.unsqueeze(1).to(inputs.dtype)
        logits, features = self.fused(x)
        log_probs = F.log_softmax(logits, dim=2)
        n = log_probs.shape[0]
        scores = log_probs.reshape(n, self.one_hot.shape[0]) @ self.one_hot  # [N, S]
        best, idx = torch.topk(scores, k, dim=1)  # type: ignore[arg-type]  # k: a graph input
        seqs = self.sequences[idx]  # [N, K, H]
        kk = idx.shape[1]
        width = features.shape[1]
        flat = features.unsqueeze(1).expand(n, kk, width).reshape(n * kk, width)
        offsets = self.regressor.head(flat, seqs.reshape(n * kk, self.horizon))
        offsets = offsets.view(n, kk, self.horizon, 2) * self.out_std + self.out_mean
        if self.relative_to_cv:
            # in float64 like lanecast.models.baselines.extrapolate, then float32 (the same rounding)
            track = inputs[:, :2, TARGET_ROW, -CV_SPAN:].double()  # [N, 2, span]
            velocity = (track * self.cv_weights).sum(-1)  # [N, 2]
            base = track[:, None, :, -1] + velocity[:, None, :] * self.horizons  # [N, 5, 2]
            offsets = offsets + base.float()[:, None]
        return log_probs.exp(), logits.argmax(dim=2), seqs, best.exp(), _kinematic_limits(offsets)


def _kinematic_limits(offsets: torch.Tensor) -> torch.Tensor:
    """lanecast.models.baselines.kinematic_limits in the graph: [N, K, H, 2] → x ≥ 0 and
    non-decreasing over the horizons (a running maximum unrolled over the fixed H steps: ONNX has no
    cummax), |y| ≤ x."""
    along = offsets[..., 0].clamp(min=0.0)
    steps = [along[..., 0]]
    for h in range(1, along.shape[-1]):
        steps.append(torch.maximum(steps[-1], along[..., h]))
    forward = torch.stack(steps, dim=-1)
    across = torch.minimum(torch.maximum(offsets[..., 1], -forward), forward)
    return torch.stack((forward, across), dim=-1)


def export_onnx(model: Path | str | None, out_dir: Path | str | None = None, *, force: bool = False) -> Path:
    """Export a checkpoint to ``<out_dir>/<stem>.onnx`` and record it in the card; returns the ONNX path.

    ``out_dir`` None: beside the weights (the card there is updated). Another directory receives a
    complete model: the weights copied, the card with its ``onnx`` section, the ONNX file.
    The exported graph is checked against torch on synthetic windows before anything is written.
    A file in the way that lanecast did not write (a user's own ``<stem>.onnx``) is refused before
    the work unless ``force``.
    """
    weights_path, card_path = resolve(model)
    net, card = load_checkpoint(weights_path)
    out = Path(out_dir) if out_dir is not None else weights_path.parent
    if out.exists() and not out.is_dir():
        raise InputError(out, "not a directory", expected="a directory for the exported model")
    stem = weights_path.stem
    onnx_path = out / f"{stem}.onnx"
    written: tuple[str, ...] = (onnx_path.name, card_path.name)
    if out.resolve() != weights_path.parent.resolve():
        written += (weights_path.name,)
    check_replaceable_files(out, written, force=force)
    graph = PredictionGraph(net, card).eval()
    example = synthetic_windows(card, 64, seed=0)
    with atomic_path(onnx_path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(
            graph,
            (torch.from_numpy(example[0]), torch.from_numpy(example[1]), torch.tensor(3)),
            str(tmp),
            dynamo=False,
            opset_version=OPSET,
            input_names=list(GRAPH_INPUTS),
            output_names=list(GRAPH_OUTPUTS),
            dynamic_axes={
                name: {i: dim for i, dim in enumerate(shape) if isinstance(dim, str)}
                for name, (_, shape) in {**GRAPH_INPUTS, **GRAPH_OUTPUTS}.items()
                if any(isinstance(d, str) for d in shape)
            },
        )
        difference, excess = parity_with_torch(tmp, STCNNForecaster(net, card), card)
        if excess > 0:
            raise InputError(
                weights_path,
                f"the exported ONNX graph differs from torch by {difference:.3g}",
                expected=f"at most {EXPORT_ATOL:g} + {EXPORT_RTOL:g}·|torch output|",
            )
        tmp.chmod(0o644)
    if out.resolve() != weights_path.parent.resolve():
        with atomic_path(out / weights_path.name) as tmp:
            shutil.copyfile(weights_path, tmp)
            tmp.chmod(0o644)
    card["onnx"] = {
        "file": onnx_path.name,
        "sha256": file_sha256(onnx_path),
        "weights_sha256": file_sha256(weights_path),
        "normalisation_sha256": normalisation_sha256(card),
        "opset": OPSET,
        "graph_version": GRAPH_VERSION,
        "exporter": f"torch.onnx.export (TorchScript), torch {torch.__version__}",
        "lanecast_version": lanecast_version(),
        "inputs": {k: {"dtype": t, "shape": s} for k, (t, s) in GRAPH_INPUTS.items()},
        "outputs": {k: {"dtype": t, "shape": s} for k, (t, s) in GRAPH_OUTPUTS.items()},
        "max_difference_to_torch": difference,
    }
    write_card(out / card_path.name, card)
    return onnx_path


def synthetic_windows(card: dict[str, Any], n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n windows drawn from the card's input statistics, 30 % of entries absent: (inputs, present)."""
    stats = NormStats.from_dict(card["normalisation"]["inputs"])
    rng = np.random.default_rng(seed)
    present = rng.random((n, 8, 30)) > 0.3
    inputs = stats.mean[None, :, None, None] + stats.std[None, :, None, None] * rng.standard_normal(
        (n, 4, 8, 30)
    )
    inputs = (inputs * present[:, None]).astype(np.float32)
    return inputs, present


def parity_with_torch(
    onnx_path: Path, reference: STCNNForecaster, card: dict[str, Any]
) -> tuple[float, float]:
    """ONNX Runtime against torch on 512 synthetic windows (top 3): (largest absolute difference,
    largest excess over the tolerance EXPORT_ATOL + EXPORT_RTOL·|torch|; > 0 means out of tolerance).

    Raises when the two disagree on a top-3 sequence (beyond near-ties of the probabilities).
    """
    inputs, present = synthetic_windows(card, 512, seed=1)
    ours = OnnxForecaster.from_file(onnx_path, card).predict(inputs, present, top_k=3)
    theirs = reference.predict(inputs, present, top_k=3)
    assert ours.top_sequences is not None and theirs.top_sequences is not None
    same = (ours.top_sequences == theirs.top_sequences).all(axis=(1, 2))
    if not same.all():
        gaps = np.abs(np.diff(theirs.top_probs, axis=1)).min(axis=1)
        if (gaps[~same] > 1e-5).any():
            raise InputError(
                onnx_path,
                "the exported graph ranks maneuver sequences differently from torch",
                expected="the same top-3 sequences as torch",
            )
    pairs = [(ours.top_offsets[same], theirs.top_offsets[same]), (ours.top_probs, theirs.top_probs)]
    pairs.append((ours.probs, theirs.probs))
    gaps = [np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)) for a, b in pairs]
    bounds = [EXPORT_ATOL + EXPORT_RTOL * np.abs(np.asarray(b, np.float64)) for _, b in pairs]
    difference = max(float(g.max(initial=0.0)) for g in gaps)
    excess = max(float((g - bound).max(initial=-np.inf)) for g, bound in zip(gaps, bounds, strict=True))
    return difference, excess
