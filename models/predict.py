"""Batch prediction: windows in, maneuver probabilities and trajectories out (the one path every command uses).

The classifier gives per-step probabilities [N, 5, 3]; the regressor gets the argmax sequence (the
paper's inference). Beyond the paper, the K most probable of the 3^5 = 243 maneuver sequences (the
probability of a sequence is the product of its per-step probabilities) are each regressed too.
Offsets are de-normalised with the card's statistics; ``forecasts_table`` maps them to the source
frame. For speed both networks run as one fused module (see ``FusedSTCNN``). This is the torch engine;
``lanecast.models.onnx_predict`` runs the same path exported to ONNX (``lanecast.models.runtime``
picks one). What a prediction is (``lanecast.models.predictions``) and the forecasts table
(``lanecast.models.forecasts_from_predictions``) are torch-free.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from lanecast.io_adapters.contracts.normalisation import NormStats, normalise
from lanecast.models import ood
from lanecast.models.baselines import kinematic_limits, reference_offsets
from lanecast.models.checkpoint import load_checkpoint
from lanecast.models.forecasts_from_predictions import forecasts_table as forecasts_table
from lanecast.models.predictions import Predictions
from lanecast.models.stcnn import STCNN


def all_sequences(horizon: int = 5, classes: int = 3) -> torch.Tensor:
    """Every maneuver sequence, int64 [classes**horizon, horizon], lexicographic (all straight first)."""
    return torch.tensor(list(itertools.product(range(classes), repeat=horizon)), dtype=torch.int64)


def top_k_sequences(
    log_probs: torch.Tensor, k: int, sequences: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The k most probable sequences: log_probs [N, H, C], sequences [S, H] → (ids [N, k, H], probs [N, k]).

    The log-probability of every sequence is one matrix product: log_probs [N, H·C] @ one-hot [H·C, S].
    """
    n, h, c = log_probs.shape
    one_hot = F.one_hot(sequences, c).to(log_probs.dtype).reshape(len(sequences), h * c)  # [S, H·C]
    scores = log_probs.reshape(n, h * c) @ one_hot.T  # [N, S]
    best, idx = torch.topk(scores, k, dim=1)
    return sequences[idx], best.exp()


class FusedSTCNN(nn.Module):
    """Inference form of an STCNN: both conv stacks as one (conv1 stacked, the rest grouped).

    Numerically the same network: conv1 of both is one conv with 48 filters, conv2–4 are grouped
    convolutions (groups=2), so each kernel launch serves both networks.
    Forward: x [N, 4, 8, 30] normalised → (classifier logits [N, 5, 3], regressor features [N, 96]).
    """

    def __init__(self, model: STCNN) -> None:
        super().__init__()
        self.config = model.config
        convs_c = [m for m in model.classifier.conv if isinstance(m, nn.Conv2d)]
        convs_r = [m for m in model.regressor.conv if isinstance(m, nn.Conv2d)]
        layers: list[nn.Module] = []
        for i, (c, r) in enumerate(zip(convs_c, convs_r, strict=True)):
            groups = 1 if i == 0 else 2
            fused = nn.Conv2d(
                c.in_channels * groups,
                c.out_channels * 2,
                c.kernel_size,  # type: ignore[arg-type]
                dilation=c.dilation,  # type: ignore[arg-type]
                groups=groups,
            )
            assert c.bias is not None and r.bias is not None and fused.bias is not None
            with torch.no_grad():
                fused.weight.copy_(torch.cat([c.weight, r.weight]))
                fused.bias.copy_(torch.cat([c.bias, r.bias]))
            layers += [fused, nn.LeakyReLU(self.config.negative_slope)]
        self.conv = nn.Sequential(*layers)
        self.cls_fc1, self.cls_fc2 = model.classifier.fc1, model.classifier.fc2
        self.act = nn.LeakyReLU(self.config.negative_slope)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.conv(x)  # [N, 48, 1, 4]
        half = h.shape[1] // 2
        fc = h[:, :half].flatten(1)
        fr = h[:, half:].flatten(1)
        logits = self.cls_fc2(self.act(self.cls_fc1(fc))).view(-1, self.config.horizon, self.config.classes)
        return logits, fr


class STCNNForecaster:
    """A trained ST-CNN with its card: normalises, predicts in batches, de-normalises."""

    def __init__(
        self, model: STCNN, card: dict[str, Any], name: str = "stcnn", *, compile: bool = False
    ) -> None:
        """``compile``: run the fused networks through ``torch.compile`` (a one-off cost of seconds; pays
        for itself from about a million windows; every batch is padded to ``batch_size``)."""
        self.name = name
        self.model = model.eval()
        self.card = card
        self.input_stats = NormStats.from_dict(card["normalisation"]["inputs"])
        future = card["normalisation"]["future"]
        self.future_mean = np.asarray(future["mean"], np.float32).reshape(model.config.horizon, 2)
        self.future_std = np.float32(future["std"])
        #: offsets are relative to this reference trajectory (lanecast.models.baselines.reference_offsets)
        self.relative_to = str(future.get("relative_to", "none"))
        # channels-last: oneDNN's faster layout for these small convolutions (measured, bench_inference)
        self.fused: Any = FusedSTCNN(self.model).eval().to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        self.compiled = compile
        if compile:
            self.fused = torch.compile(self.fused, dynamic=False)
        self.sequences = all_sequences(model.config.horizon, model.config.classes)
        self._batch = 4096

    @classmethod
    def load(
        cls, model_dir: Path | str | None = None, name: str = "stcnn", *, compile: bool = False
    ) -> STCNNForecaster:
        """Load a checkpoint (None: the shipped model)."""
        net, card = load_checkpoint(model_dir)
        return cls(net, card, name, compile=compile)

    @torch.inference_mode()
    def predict_normalised(self, x: torch.Tensor, top_k: int) -> dict[str, torch.Tensor]:
        """One batch: normalised x [B, 4, 8, 30] → torch outputs (offsets still normalised)."""
        n = x.shape[0]
        if self.compiled and n < self._batch:  # one compiled graph: pad the last batch
            x = torch.cat([x, x.new_zeros((self._batch - n, *x.shape[1:]))])
        logits, features = self.fused(x.contiguous(memory_format=torch.channels_last))
        logits, features = logits[:n], features[:n].contiguous()
        log_probs = F.log_softmax(logits, dim=2)
        k = max(top_k, 1)
        seqs, probs = top_k_sequences(log_probs, k, self.sequences)  # [B, K, 5], [B, K]
        b, h = seqs.shape[0], seqs.shape[2]
        reg = self.model.regressor.head(features.repeat_interleave(k, dim=0), seqs.reshape(b * k, h))
        return {
            "probs": log_probs.exp(),
            "maneuver": logits.argmax(dim=2),
            "top_sequences": seqs,
            "top_probs": probs,
            "top_offsets": reg.view(b, k, h, 2),
        }

    def predict(
        self, inputs: np.ndarray, present: np.ndarray, *, top_k: int = 3, batch_size: int = 4096
    ) -> Predictions:
        """inputs float32 [N, 4, 8, 30] physical (may be memory-mapped), present bool [N, 8, 30] → Predictions.

        ``top_k`` = 0 still regresses the argmax sequence but returns no alternatives (K = 1 kept).
        """
        n = inputs.shape[0]
        k = max(top_k, 1)
        self._batch = batch_size
        cfg = self.model.config
        out = Predictions(
            offsets=np.empty((n, cfg.horizon, 2), np.float32),
            probs=np.empty((n, cfg.horizon, cfg.classes), np.float32),
            maneuver=np.empty((n, cfg.horizon), np.int64),
            top_sequences=np.empty((n, k, cfg.horizon), np.int64),
            top_probs=np.empty((n, k), np.float32),
            top_offsets=np.empty((n, k, cfg.horizon, 2), np.float32),
        )
        for start in range(0, n, batch_size):
            sl = slice(start, start + batch_size)
            x = torch.from_numpy(normalise(inputs[sl], present[sl], self.input_stats))
            res = self.predict_normalised(x, k)
            for key, value in res.items():
                getattr(out, key)[sl] = value.numpy()
        out.top_offsets *= self.future_std
        out.top_offsets += self.future_mean
        base = reference_offsets(inputs, self.relative_to)
        if base is not None:
            out.top_offsets += base[:, None]
        kinematic_limits(out.top_offsets)
        out.offsets[:] = out.top_offsets[:, 0]  # the top sequence is the per-step argmax
        distribution = self.card.get("training", {}).get("data", {}).get("distribution")
        out.out_of_distribution = ood.out_of_distribution(
            inputs[:, :, :, -1:], present[:, :, -1:], distribution
        )
        return out
