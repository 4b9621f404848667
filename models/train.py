"""Training of the two networks, separately as in the paper (no shared weights, one optimiser each).

* classifier: Adam, loss = sum over the 5 steps of the negative log-likelihood (mean over the batch);
* regressor: Adam, loss = batch RMSE sqrt(mean over windows and steps of the squared Euclidean error),
  with the ground-truth maneuvers as its input.

Both walk the same shuffled batches (each batch is read and normalised once for both networks) but
they never see each other's gradients, so this equals training them one after the other. Each
network keeps its best epoch on the validation split (classifier: NLL; regressor: RMSE).

Inputs are normalised with statistics from the training split (``pipeline.normalise``). Future
offsets are normalised per model as (offset − mean[step, axis]) / std, one std for all steps and both
axes, so the regressor's loss stays proportional to the RMSE in metres (the paper's criterion);
both are stored in the card.

Deviation from the paper, on purpose: the paper trains 300 epochs at lr 7e-5 (batch size not
stated); on a CPU we use large batches and a larger learning rate (``TrainConfig`` defaults).
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn import functional as F

from io_adapters.errors import InputError
from io_adapters.progress import bar
from models.checkpoint import torch_device
from models.stcnn import STCNN, STCNNConfig


@dataclass
class TrainConfig:
    """Training hyper-parameters (stored in the card; ``--config FILE`` is this as JSON)."""

    epochs: int = 30
    batch_size: int = 256
    lr: float = 1e-3
    seed: int = 0
    threads: int = 2
    device: str = "auto"
    model: STCNNConfig = field(default_factory=STCNNConfig)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["model"] = self.model.to_dict()
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown training config keys: {sorted(unknown)}")
        kw = dict(data)
        if "model" in kw:
            kw["model"] = STCNNConfig.from_dict(kw["model"])
        return cls(**kw)

    @classmethod
    def from_file(cls, path: Path) -> TrainConfig:
        """Read a JSON config file (keys of TrainConfig; ``model`` holds STCNNConfig keys)."""
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, json.JSONDecodeError, ValueError, TypeError) as exc:
            raise InputError(
                path, f"bad training config: {exc}", expected="JSON with TrainConfig keys"
            ) from exc


@dataclass
class TrainResult:
    """The trained network (best epochs), the card sections training knows, and the per-epoch history."""

    model: STCNN
    card: dict[str, Any]
    history: list[dict[str, float]]


def labelled(windows: Any, splits: tuple[str, ...]) -> np.ndarray:
    """Indices [M] of windows in ``splits`` whose future and maneuvers are all known."""
    split = windows.index.column("split").to_numpy(zero_copy_only=False)
    ok = np.isin(split, list(splits))
    ok &= np.all(np.isfinite(np.asarray(windows.future)), axis=(1, 2))
    ok &= np.all(np.asarray(windows.maneuver) >= 0, axis=1)
    return np.flatnonzero(ok)


def future_stats(future: np.ndarray) -> tuple[np.ndarray, float]:
    """Offset normalisation: future [N, 5, 2] → (mean float32 [5, 2], one std over all centred entries)."""
    f = np.asarray(future, np.float64)
    mean = f.mean(axis=0)
    std = float(np.sqrt(np.mean((f - mean) ** 2)))
    return mean.astype(np.float32), (std if std > 1e-6 else 1.0)


class _Batches:
    """Gathers and normalises batches from (possibly memory-mapped) windows."""

    def __init__(self, windows: Any, input_stats: Any, future_mean: np.ndarray, future_std: float) -> None:
        from pipeline.normalise import normalise

        self.w, self.stats, self.normalise = windows, input_stats, normalise
        self.mean, self.std = future_mean, future_std

    def get(self, idx: np.ndarray, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        idx = np.sort(idx)  # sequential reads of the memory map; order inside a batch is irrelevant
        x = self.normalise(self.w.inputs[idx], self.w.present[idx], self.stats)
        y = (np.asarray(self.w.future[idx]) - self.mean) / self.std
        m = np.asarray(self.w.maneuver[idx])
        return (
            torch.from_numpy(x).to(device),
            torch.from_numpy(y.astype(np.float32)).to(device),
            torch.from_numpy(m).to(device),
        )


def classifier_loss(logits: torch.Tensor, maneuver: torch.Tensor) -> torch.Tensor:
    """Sum over steps of the NLL, mean over the batch: logits [B, 5, 3], maneuver [B, 5] → scalar."""
    return F.cross_entropy(logits.reshape(-1, logits.shape[-1]), maneuver.reshape(-1), reduction="sum") / len(
        logits
    )


def regressor_loss(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """Batch RMSE: sqrt(mean over windows and steps of the squared Euclidean error); [B, 5, 2] → scalar."""
    return torch.sqrt(torch.mean(torch.sum((pred - true) ** 2, dim=-1)))


@torch.no_grad()
def _validate(
    model: STCNN, batches: _Batches, idx: np.ndarray, device: torch.device, batch_size: int
) -> dict[str, float]:
    """Validation losses over ``idx``: NLL, accuracy, RMSE (normalised and in metres, GT maneuvers)."""
    model.eval()
    nll = sq = correct = 0.0
    for start in range(0, len(idx), batch_size):
        x, y, m = batches.get(idx[start : start + batch_size], device)
        logits = model.classifier(x)
        nll += float(classifier_loss(logits, m)) * len(x)
        correct += float((logits.argmax(2) == m).float().sum())
        sq += float(torch.sum((model.regressor(x, m) - y) ** 2))
    n = max(len(idx), 1)
    rmse = float(np.sqrt(sq / (n * model.config.horizon)))
    return {
        "val_nll": nll / n,
        "val_accuracy": correct / (n * model.config.horizon),
        "val_rmse": rmse,
        "val_rmse_m": rmse * batches.std,
    }


def train(
    windows: Any,
    config: TrainConfig | None = None,
    *,
    data_card: dict[str, Any] | None = None,
    classifier_from: STCNN | None = None,
) -> TrainResult:
    """Train both networks on the ``train`` split, validating on ``val`` each epoch; keep the best epochs.

    windows: a ``pipeline.windows_data.Windows`` (memory-mapped is fine). ``classifier_from``: copy
    that model's (trained) classifier and train only the regressor (e.g. for the regression-only
    ablation, whose classifier is the same network). Reproducible for a seed on a given machine and
    thread count. Raises InputError when there is nothing to train on.
    """
    from pipeline.normalise import compute_stats

    config = config or TrainConfig()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    device = torch_device(config.device)

    train_idx = labelled(windows, ("train",))
    val_idx = labelled(windows, ("val",))
    if len(train_idx) == 0:
        raise InputError(
            None, "no labelled training windows (split 'train')", expected="windows with known futures"
        )
    input_stats = compute_stats(windows.inputs[train_idx], windows.present[train_idx])
    future_mean, future_std = future_stats(windows.future[train_idx])
    batches = _Batches(windows, input_stats, future_mean, future_std)
    select_on = "val" if len(val_idx) else "train"
    check_idx = val_idx if len(val_idx) else train_idx

    model = STCNN(config.model)
    if classifier_from is not None:
        model.classifier.load_state_dict(classifier_from.classifier.state_dict())
    model.to(device)
    train_classifier = classifier_from is None
    opt_c = torch.optim.Adam(model.classifier.parameters(), lr=config.lr)
    opt_r = torch.optim.Adam(model.regressor.parameters(), lr=config.lr)
    best_c = (float("inf"), 0, copy.deepcopy(model.classifier.state_dict()))
    best_r = (float("inf"), 0, copy.deepcopy(model.regressor.state_dict()))
    history: list[dict[str, float]] = []
    n_batches = -(-len(train_idx) // config.batch_size)
    train_seconds = 0.0
    progress = bar(desc="train", total=config.epochs * n_batches, unit="batch")
    for epoch in range(1, config.epochs + 1):
        model.train()
        perm = rng.permutation(train_idx)
        sum_c = sum_r = 0.0
        t_start = time.perf_counter()
        for b in range(n_batches):
            x, y, m = batches.get(perm[b * config.batch_size : (b + 1) * config.batch_size], device)
            if train_classifier:
                loss_c = classifier_loss(model.classifier(x), m)
                opt_c.zero_grad(set_to_none=True)
                loss_c.backward()
                opt_c.step()
            else:
                with torch.no_grad():
                    loss_c = classifier_loss(model.classifier(x), m)
            loss_r = regressor_loss(model.regressor(x, m), y)
            opt_r.zero_grad(set_to_none=True)
            loss_r.backward()
            opt_r.step()
            sum_c += loss_c.item() * len(x)
            sum_r += loss_r.item() ** 2 * len(x)
            progress.update(1)
            if b % 20 == 0:
                progress.set_postfix(epoch=epoch, nll=f"{loss_c.item():.3f}", rmse=f"{loss_r.item():.3f}")
        train_seconds += time.perf_counter() - t_start
        val = _validate(model, batches, check_idx, device, 4096)
        row = {
            "epoch": epoch,
            "train_nll": sum_c / len(train_idx),
            "train_rmse": float(np.sqrt(sum_r / len(train_idx))),
            **val,
        }
        history.append(row)
        progress.set_postfix(
            epoch=epoch, val_nll=f"{val['val_nll']:.3f}", val_rmse_m=f"{val['val_rmse_m']:.3f}"
        )
        if train_classifier and val["val_nll"] < best_c[0]:
            best_c = (val["val_nll"], epoch, copy.deepcopy(model.classifier.state_dict()))
        if val["val_rmse"] < best_r[0]:
            best_r = (val["val_rmse"], epoch, copy.deepcopy(model.regressor.state_dict()))
    progress.close()
    model.classifier.load_state_dict(best_c[2])
    model.regressor.load_state_dict(best_r[2])
    model.to("cpu").eval()

    card = {
        "normalisation": {
            "inputs": input_stats.to_dict(),
            "future": {"mean": future_mean.tolist(), "std": future_std, "units": "m"},
        },
        "training": {
            "config": config.to_dict(),
            "device": str(device),
            "data": {
                **(data_card or {}),
                "train_windows": len(train_idx),
                "val_windows": len(val_idx),
                "train_maneuver_counts": np.bincount(
                    np.asarray(windows.maneuver[train_idx]).ravel(), minlength=3
                ).tolist(),
            },
            "selected_on": select_on,
            "best_epoch": {"classifier": best_c[1] if train_classifier else "copied", "regressor": best_r[1]},
            "train_seconds": round(train_seconds, 2),
            "train_samples_per_s": round(len(train_idx) * config.epochs / max(train_seconds, 1e-9), 1),
            "history": history,
        },
    }
    return TrainResult(model=model, card=card, history=history)
