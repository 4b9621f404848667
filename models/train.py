"""Training of the two networks, separately as in the paper (no shared weights, one optimiser each).

* classifier: Adam, loss = sum over the 5 steps of the negative log-likelihood (mean over the batch);
  optionally class-weighted (``class_weight_power`` > 0, beyond the paper, see ``class_weights``);
* regressor: Adam, loss = batch RMSE sqrt(mean over windows and steps of the squared Euclidean error),
  with the ground-truth maneuvers as its input.

Both walk the same shuffled batches (each batch is read and normalised once for both networks) but
they never see each other's gradients, so this equals training them one after the other. Each
network keeps its best epoch on the validation split (regressor: RMSE; classifier: NLL, or with
``select_classifier="macro_f1"`` the per-step macro-F1, which rewards lane-change recall that the
NLL, dominated by the ~97 % straight steps, does not).

Inputs are normalised with statistics from the training split (``lanecast.io_adapters.contracts.normalisation``). Future
offsets are normalised per model as (offset − mean[step, axis]) / std, one std for all steps and both
axes, so the regressor's loss stays proportional to the RMSE in metres (the paper's criterion);
both are stored in the card.

Deviation from the paper, on purpose: the paper trains 300 epochs at lr 7e-5 (batch size not
stated); on a CPU we use large batches and a larger learning rate (``TrainConfig`` defaults).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.contracts.normalisation import NormStats, compute_stats, normalise
from lanecast.io_adapters.contracts.windows import Windows, labelled
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import check_input
from lanecast.io_adapters.progress import bar
from lanecast.models import ood
from lanecast.models.augment import Augmentation, augment
from lanecast.models.baselines import CV_SPAN, RELATIVE_TO, reference_offsets
from lanecast.models.card import check_architecture
from lanecast.models.checkpoint import torch_device
from lanecast.models.decision_offsets import choose_offsets, classifier_log_probs, fold_into_classifier
from lanecast.models.losses import (
    class_weights,
    classifier_loss,
    future_stats,
    horizon_weights,
    regressor_loss,
)
from lanecast.models.metrics import confusion_matrix, macro_f1, precision_recall
from lanecast.models.stcnn import STCNN, STCNNConfig

#: classifier selection criterion → (history key, sign): the best epoch minimises sign * value
SELECTION = {"nll": ("val_nll", 1.0), "macro_f1": ("val_macro_f1", -1.0)}


def select_epoch(history: list[dict[str, Any]], criterion: str) -> int:
    """The classifier's best epoch (1-based) in ``history`` by ``criterion``; the first one on ties."""
    key, sign = SELECTION[criterion]
    return 1 + int(np.argmin([sign * row[key] for row in history]))


def lr_factor(schedule: str, step: int, total: int) -> float:
    """Learning-rate multiplier after ``step`` of ``total`` optimiser steps: 1 ("constant") or the
    half cosine 0.5·(1 + cos(π·step/total)) from 1 down to 0 ("cosine")."""
    if schedule == "constant":
        return 1.0
    return 0.5 * (1.0 + float(np.cos(np.pi * min(step, total) / max(total, 1))))


@dataclass
class TrainConfig:
    """Training hyper-parameters (stored in the card; ``--config FILE`` is this as JSON)."""

    epochs: int = 30
    batch_size: int = 256
    lr: float = 1e-3
    seed: int = 0
    threads: int = 2
    device: str = "auto"
    #: classifier loss weights (inverse class frequency)**power; 0 = the paper's plain NLL
    class_weight_power: float = 0.0
    #: classifier best-epoch criterion on validation: "nll" (lowest) or "macro_f1" (highest)
    select_classifier: str = "nll"
    #: learning rate over the run, both networks: "constant" (the paper) or "cosine" (lr → 0 at the end)
    lr_schedule: str = "constant"
    #: the regressor predicts offsets relative to "cv" (the constant-velocity extrapolation of the
    #: input history: it learns the correction) or "none" (absolute offsets, the paper's)
    future_relative_to: str = "none"
    #: std (m) of Gaussian noise added to the x, y inputs of training batches (tracker-like jitter,
    #: augmentation beyond the paper; 0 = none). Targets stay clean.
    position_noise_m: float = 0.0
    #: std of Gaussian noise on the speed (m/s) and longitudinal acceleration (m/s²) inputs of
    #: training batches: real trackers' derivatives are noisy (NGSIM's accelerations, standing
    #: still, spread ±0.6 m/s²), simulated ones are exact. 0 = none.
    speed_noise_mps: float = 0.0
    acc_noise_mps2: float = 0.0
    #: share of the (window, vehicle, frame) entries of training batches whose speed and acceleration
    #: inputs get an outlier (acceleration + N(0, 1.5 m/s²), speed + |N(0, 0.2 m/s)|): real
    #: datasets' derivatives flicker (NGSIM: a standing car's v_Vel 0 → 0.12 m/s → 0 with v_Acc
    #: ±1.5 m/s² in one frame, 5 % of its standing rows in the Peachtree sample), which Gaussian
    #: jitter of 0.4 m/s² does not teach a network to ignore. 0 = none.
    derivative_outliers: float = 0.0
    #: each training window's speed and acceleration jitter and outlier share scaled by its own
    #: factor from U(1 − spread, 1 + spread) (0 = every window alike): with one noise level for all
    #: windows a network learns to distrust exact derivatives as much as a real tracker's; with a
    #: spread it might tell them apart by their look (models/augment.py; measured in BENCHMARKS.md)
    derivative_noise_spread: float = 0.0
    #: regressor loss weight of horizon h ∝ (r_5s / r_h)**power, r_h the RMS of the training targets
    #: at h (after the reference), normalised to mean 1: 0 = the paper's plain RMSE, where the 1 s
    #: errors (centimetres) count for almost nothing beside the 5 s ones (metres) and a model may
    #: lose to constant velocity at 1 s; 1 = each horizon's error in proportion to its scale
    horizon_weight_power: float = 0.0
    #: share of training windows whose regressor gets the classifier's argmax maneuvers instead of
    #: the true ones (0 = the paper: always the true ones). At inference the regressor only ever sees
    #: the classifier's; trained on the truth alone it follows a wrong maneuver confidently.
    predicted_maneuver_share: float = 0.0
    #: share of training windows shown with every neighbour removed (the target alone). Real data
    #: misses neighbours (a sparse sample, the edge of a sensor's range, lost tracks), and a network
    #: that never saw a target alone extrapolates arbitrarily there: trained on SUMO's queues, it
    #: forecast a standing car with no neighbour in sight 3 m ahead at 5 s. 0 = the paper.
    neighbour_dropout: float = 0.0
    #: after training, shift the classifier's decision by per-class logit offsets chosen for the best
    #: validation macro-F1 (lanecast.models.decision_offsets); False = the paper's plain argmax
    decision_offsets: bool = False
    model: STCNNConfig = field(default_factory=STCNNConfig)

    def __post_init__(self) -> None:
        if self.select_classifier not in SELECTION:
            raise ValueError(
                f"select_classifier must be one of {sorted(SELECTION)}, not {self.select_classifier!r}"
            )
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(f"lr_schedule must be 'constant' or 'cosine', not {self.lr_schedule!r}")
        if self.future_relative_to not in RELATIVE_TO:
            raise ValueError(
                f"future_relative_to must be one of {RELATIVE_TO}, not {self.future_relative_to!r}"
            )
        if not (self.speed_noise_mps >= 0 and self.acc_noise_mps2 >= 0):
            raise ValueError("speed_noise_mps and acc_noise_mps2 must be >= 0")
        if not self.position_noise_m >= 0:
            raise ValueError(f"position_noise_m must be >= 0, not {self.position_noise_m}")
        if not 0 <= self.predicted_maneuver_share <= 1:
            raise ValueError(
                f"predicted_maneuver_share must be in [0, 1], not {self.predicted_maneuver_share}"
            )
        if not 0 <= self.derivative_outliers <= 1:
            raise ValueError(f"derivative_outliers must be in [0, 1], not {self.derivative_outliers}")
        if not 0 <= self.derivative_noise_spread <= 1:
            raise ValueError(f"derivative_noise_spread must be in [0, 1], not {self.derivative_noise_spread}")
        if not 0 <= self.neighbour_dropout <= 1:
            raise ValueError(f"neighbour_dropout must be in [0, 1], not {self.neighbour_dropout}")
        if not 0 <= self.horizon_weight_power <= 2:
            raise ValueError(f"horizon_weight_power must be in [0, 2], not {self.horizon_weight_power}")
        if not self.class_weight_power >= 0:
            raise ValueError(f"class_weight_power must be >= 0, not {self.class_weight_power}")

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
            # jf.loads: not UTF-8, NaN-free JSON or nested too deep is a FieldError naming the file;
            # check_input: a FIFO would block the read, /dev/zero would never end it
            data = jf.check(jf.loads(check_input(path).read_bytes(), "config"), "config", "object")
            if "model" in data:  # checked before torch sees it
                check_architecture(data["model"], "model")
            return cls.from_dict(data)
        except jf.FieldError as exc:
            raise jf.as_input_error(path, "bad training config", exc) from exc
        except (OSError, ValueError, TypeError) as exc:
            raise InputError(
                path, f"bad training config: {exc}", expected="JSON with TrainConfig keys"
            ) from exc


@dataclass
class TrainResult:
    """The trained network (best epochs), the card sections training knows, and the per-epoch history."""

    model: STCNN
    card: dict[str, Any]
    history: list[dict[str, Any]]


class _Batches:
    """Gathers and normalises batches from (possibly memory-mapped) windows."""

    def __init__(
        self,
        windows: Windows,
        input_stats: NormStats,
        future_mean: np.ndarray,
        future_std: float,
        transform: Callable[[np.ndarray], np.ndarray] | None = None,
        relative_to: str = "none",
    ) -> None:
        self.w, self.stats = windows, input_stats
        self.mean, self.std = future_mean, future_std
        self.transform = transform
        self.relative_to = relative_to

    def get(
        self,
        idx: np.ndarray,
        device: torch.device,
        augmentation: Augmentation | None = None,
        rng: np.random.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised (inputs, future, maneuver) of windows ``idx``, the inputs augmented
        (lanecast.models.augment) where an ``augmentation`` and a generator are given."""
        idx = np.sort(idx)  # sequential reads of the memory map; order inside a batch is irrelevant
        inputs = np.asarray(self.w.inputs[idx])  # fancy indexing: a fresh array, ours to modify
        present = np.asarray(self.w.present[idx])
        if augmentation is not None and rng is not None:
            augment(inputs, present, augmentation, rng)
        x = normalise(inputs, present, self.stats)
        if self.transform is not None:
            x = np.ascontiguousarray(self.transform(x), dtype=np.float32)
        future = np.asarray(self.w.future[idx])
        base = reference_offsets(inputs, self.relative_to)  # from the inputs the network sees
        if base is not None:
            future = future - base
        y = (future - self.mean) / self.std
        m = np.asarray(self.w.maneuver[idx])
        return (
            torch.from_numpy(x).to(device),
            torch.from_numpy(y.astype(np.float32)).to(device),
            torch.from_numpy(m).to(device),
        )


@torch.no_grad()
def _validate(
    model: STCNN, batches: _Batches, idx: np.ndarray, device: torch.device, batch_size: int
) -> dict[str, Any]:
    """Validation figures over ``idx``: plain NLL, accuracy, macro-F1 and recall per class (per step,
    argmax), RMSE (normalised and in metres, GT maneuvers)."""
    model.eval()
    nll = sq = 0.0
    classes = model.config.classes
    conf = np.zeros((classes, classes), np.int64)
    for start in range(0, len(idx), batch_size):
        x, y, m = batches.get(idx[start : start + batch_size], device)
        logits = model.classifier(x)
        nll += float(classifier_loss(logits, m)) * len(x)
        conf += confusion_matrix(m.cpu().numpy(), logits.argmax(2).cpu().numpy(), classes)
        sq += float(torch.sum((model.regressor(x, m) - y) ** 2))
    n = max(len(idx), 1)
    rmse = float(np.sqrt(sq / (n * model.config.horizon)))
    recall = np.nan_to_num(precision_recall(conf)[1])
    return {
        "val_nll": nll / n,
        "val_accuracy": float(np.trace(conf)) / (n * model.config.horizon),
        "val_macro_f1": macro_f1(conf) if conf.sum() else 0.0,
        "val_recall": [float(r) for r in recall],
        "val_rmse": rmse,
        "val_rmse_m": rmse * batches.std,
    }


def train(
    windows: Windows,
    config: TrainConfig | None = None,
    *,
    data_card: dict[str, Any] | None = None,
    classifier_from: STCNN | None = None,
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
    init_from: tuple[STCNN, dict[str, Any]] | None = None,
    penalty: Callable[[str, torch.nn.Module], torch.Tensor] | None = None,
) -> TrainResult:
    """Train both networks on the ``train`` split, validating on ``val`` each epoch; keep the best epochs.

    windows: a ``lanecast.io_adapters.contracts.windows.Windows`` (memory-mapped is fine). ``classifier_from``: copy
    that model's (trained) classifier and train only the regressor (e.g. for the regression-only
    ablation, whose classifier is the same network). ``transform``: applied to every normalised input
    batch [B, 4, 8, 30] before the networks see it (the input ablations of ``lanecast.models.ablation``;
    its output must fit ``config.model.channels``). ``init_from`` (model, card): fine-tune, starting
    from that model's weights and keeping its normalisation (input and offset statistics): the
    trained filters expect inputs scaled as in their training, and recomputing the statistics on
    a small new dataset would shift every input the network sees before the first step. (The best
    epoch is then chosen among the fine-tuning epochs.) ``penalty(name, network)``: a term added
    to the loss of the network "classifier" or "regressor" (``lanecast.models.finetune.L2SP``),
    not to the losses the history reports. Reproducible for a seed on a given machine
    and thread count. Raises InputError when there is nothing to train on.
    """
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
    relative_to = config.future_relative_to
    if init_from is not None:
        norm = init_from[1]["normalisation"]
        relative_to = norm["future"].get("relative_to", "none")
    target = np.asarray(windows.future[train_idx])
    # the reference needs only the last positions: no copy of the whole inputs
    base = reference_offsets(np.asarray(windows.inputs[:, :, :, -CV_SPAN:][train_idx]), relative_to)
    relative_target = target if base is None else target - base
    if init_from is not None:
        input_stats = NormStats.from_dict(norm["inputs"])
        future_mean = np.asarray(norm["future"]["mean"], dtype=np.float32)
        future_std = float(norm["future"]["std"])
    else:
        input_stats = compute_stats(windows.inputs, windows.present, rows=train_idx)  # chunked: no copy
        future_mean, future_std = future_stats(relative_target)
    step_weight = horizon_weights(relative_target - future_mean, config.horizon_weight_power)
    step_weight_t = torch.from_numpy(step_weight).to(device) if config.horizon_weight_power > 0 else None
    batches = _Batches(windows, input_stats, future_mean, future_std, transform, relative_to)
    train_counts = np.bincount(np.asarray(windows.maneuver[train_idx]).ravel(), minlength=3)
    weights = class_weights(windows.maneuver[train_idx], config.class_weight_power, config.model.classes)
    weight_t = torch.from_numpy(weights).to(device) if config.class_weight_power > 0 else None
    select_on = "val" if len(val_idx) else "train"
    check_idx = val_idx if len(val_idx) else train_idx

    model = STCNN(config.model)
    if init_from is not None:
        model.load_state_dict(init_from[0].state_dict())
    if classifier_from is not None:
        model.classifier.load_state_dict(classifier_from.classifier.state_dict())
    model.to(device)
    train_classifier = classifier_from is None
    opt_c = torch.optim.Adam(model.classifier.parameters(), lr=config.lr)
    opt_r = torch.optim.Adam(model.regressor.parameters(), lr=config.lr)
    total_steps = config.epochs * -(-len(train_idx) // config.batch_size)
    schedules = [
        torch.optim.lr_scheduler.LambdaLR(opt, lambda step: lr_factor(config.lr_schedule, step, total_steps))
        for opt in ((opt_c, opt_r) if train_classifier else (opt_r,))
    ]
    sel_key, sel_sign = SELECTION[config.select_classifier]
    best_c = (float("inf"), 0, copy.deepcopy(model.classifier.state_dict()))
    best_r = (float("inf"), 0, copy.deepcopy(model.regressor.state_dict()))
    history: list[dict[str, Any]] = []
    n_batches = -(-len(train_idx) // config.batch_size)
    aug = Augmentation(
        config.position_noise_m,
        config.speed_noise_mps,
        config.acc_noise_mps2,
        config.neighbour_dropout,
        config.derivative_outliers,
        config.derivative_noise_spread,
    )
    train_seconds = 0.0
    progress = bar(desc="train", total=config.epochs * n_batches, unit="batch")
    for epoch in range(1, config.epochs + 1):
        model.train()
        perm = rng.permutation(train_idx)
        sum_c = sum_r = 0.0
        t_start = time.perf_counter()
        for b in range(n_batches):
            x, y, m = batches.get(perm[b * config.batch_size : (b + 1) * config.batch_size], device, aug, rng)
            if train_classifier:
                logits = model.classifier(x)
                loss_c = classifier_loss(logits, m, weight_t)
                opt_c.zero_grad(set_to_none=True)
                (loss_c if penalty is None else loss_c + penalty("classifier", model.classifier)).backward()
                opt_c.step()
            else:
                with torch.no_grad():
                    logits = model.classifier(x)
                    loss_c = classifier_loss(logits, m, weight_t)
            m_in = m
            if config.predicted_maneuver_share > 0:
                use_predicted = torch.from_numpy(rng.random(len(m)) < config.predicted_maneuver_share)
                m_in = torch.where(use_predicted.to(m.device)[:, None], logits.detach().argmax(dim=2), m)
            loss_r = regressor_loss(model.regressor(x, m_in), y, step_weight_t)
            opt_r.zero_grad(set_to_none=True)
            (loss_r if penalty is None else loss_r + penalty("regressor", model.regressor)).backward()
            opt_r.step()
            for schedule in schedules:
                schedule.step()
            sum_c += loss_c.item() * len(x)
            sum_r += loss_r.item() ** 2 * len(x)
            progress.update(1)
            if b % 20 == 0:
                progress.set_postfix(epoch=epoch, nll=f"{loss_c.item():.3f}", rmse=f"{loss_r.item():.3f}")
        train_seconds += time.perf_counter() - t_start
        val = _validate(model, batches, check_idx, device, 4096)
        row = {
            "epoch": epoch,
            "train_nll": sum_c / len(train_idx),  # the training loss (weighted when configured)
            "train_rmse": float(np.sqrt(sum_r / len(train_idx))),
            **val,
        }
        history.append(row)
        progress.set_postfix(
            epoch=epoch, val_nll=f"{val['val_nll']:.3f}", val_rmse_m=f"{val['val_rmse_m']:.3f}"
        )
        score = sel_sign * float(val[sel_key])
        if train_classifier and score < best_c[0]:  # strict: the first best epoch, as select_epoch
            best_c = (score, epoch, copy.deepcopy(model.classifier.state_dict()))
        if val["val_rmse"] < best_r[0]:
            best_r = (val["val_rmse"], epoch, copy.deepcopy(model.regressor.state_dict()))
    progress.close()
    model.classifier.load_state_dict(best_c[2])
    model.regressor.load_state_dict(best_r[2])
    model.to("cpu").eval()
    decision = None
    if config.decision_offsets and train_classifier and len(val_idx):
        val_batches = (
            batches.get(val_idx[i : i + 4096], torch.device("cpu")) for i in range(0, len(val_idx), 4096)
        )
        decision = choose_offsets(*classifier_log_probs(model, ((x, m) for x, _, m in val_batches)))
        fold_into_classifier(model, decision.offsets)

    params = (getattr(windows, "manifest", None) or {}).get("parameters", {})
    card = {
        "windows": {  # how inference must cut windows to match the training data
            "neighbour_range_m": params.get("neighbour_range_m"),
            "lane_width_m": params.get("lane_width_m"),
            "window_frame": "road (translation only in road frames; history chord elsewhere)",
        },
        "normalisation": {
            "inputs": input_stats.to_dict(),
            "future": {
                "mean": future_mean.tolist(),
                "std": future_std,
                "units": "m",
                "relative_to": relative_to,
            },
        },
        "training": {
            "config": config.to_dict(),
            "device": str(device),
            "data": {
                **(data_card or {}),
                "train_windows": len(train_idx),
                "val_windows": len(val_idx),
                "train_maneuver_counts": train_counts.tolist(),
                # t0 only: [N, 4, 8, 1] instead of the whole [N, 4, 8, 30] tensors
                "distribution": ood.distribution(
                    windows.inputs[:, :, :, -1:][train_idx], windows.present[:, :, -1:][train_idx]
                ),
            },
            "classifier_loss": (
                "sum over steps of the NLL (the paper's)"
                if weight_t is None
                else f"class-weighted NLL, weights (straight, left, right) {[round(float(w), 4) for w in weights]}"
                f" = inverse frequency ** {config.class_weight_power:g}, mean 1 over training steps (beyond the paper)"
            ),
            "selected_on": select_on,
            "initialised_from": None if init_from is None else init_from[1].get("training", {}).get("data"),
            "classifier_selected_by": sel_key,
            "decision_offsets": None if decision is None else decision.to_dict(),
            "best_epoch": {"classifier": best_c[1] if train_classifier else "copied", "regressor": best_r[1]},
            "train_seconds": round(train_seconds, 2),
            "train_samples_per_s": round(len(train_idx) * config.epochs / max(train_seconds, 1e-9), 1),
            "history": history,
        },
    }
    return TrainResult(model=model, card=card, history=history)
