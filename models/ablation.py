"""The paper's ablation study (Table II of Mersch et al., IROS 2021): seven variants on the same windows.

Every variant is the ST-CNN with one thing taken away; each is retrained (or reuses the full
model's networks) with the same training config and seed, then scored on the same test windows:

=====================  ==========================================================================
variant                what changes
=====================  ==========================================================================
``xy_only``            only the x and y channels are input (conv1 has 2 input channels, not 4)
``no_neighbourhood``   every row but the target's is zero ("absent"), in training and testing
``shuffled``           the eight vehicle rows in a fixed, spatially incoherent order
                       (``SHUFFLED_ROWS``), in training and testing
``no_dilation``        no dilation anywhere: the conv output grows to 24×1×17 = 408 features, so the
                       dense layers grow with it: 90,681 parameters (the paper's figure)
``no_maneuver``        the regressor alone, without maneuver input (trained on its own)
``sampled_maneuver``   the full model's regressor fed maneuver sequences drawn at random from the
                       training windows' sequences (no classifier; nothing retrained)
``full``               the paper's network
=====================  ==========================================================================

Input ablations act on the *normalised* tensor (zero means absent there), through the ``transform``
hook of ``lanecast.models.train.train``; prediction applies the same transform.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from lanecast.io_adapters.contracts.normalisation import NormStats, normalise
from lanecast.io_adapters.contracts.windows import ROWS, TARGET_ROW, Windows, labelled
from lanecast.io_adapters.errors import InputError
from lanecast.models.baselines import kinematic_limits, reference_offsets
from lanecast.models.metrics import (
    accuracy,
    confusion_matrix,
    displacement_errors,
    fde,
    lane_change_windows,
    macro_f1,
    miss_rate,
    paired_rmse_difference,
    rmse,
)
from lanecast.models.stcnn import STCNN, STCNNConfig, count_parameters
from lanecast.models.train import TrainConfig, TrainResult, train

#: The fixed row order of the shuffled-neighbourhood variant: row i of its input is row
#: SHUFFLED_ROWS[i] of the contract's order FL F FR L T R RL RR: F L FL FR R RR T RL (no row stays in
#: place, no two rows that were adjacent stay adjacent).
SHUFFLED_ROWS: tuple[int, ...] = (1, 3, 0, 2, 5, 7, 4, 6)

#: Table II of the paper (highD, RMSE in m at 1–5 s), for the report's comparison.
PAPER_TABLE_II: dict[str, tuple[float, ...]] = {
    "xy_only": (0.24, 0.64, 1.24, 2.02, 3.00),
    "no_neighbourhood": (0.08, 0.18, 0.39, 0.83, 1.52),
    "shuffled": (0.15, 0.25, 0.43, 0.82, 1.40),
    "no_dilation": (0.15, 0.30, 0.52, 0.90, 1.45),
    "no_maneuver": (0.14, 0.26, 0.47, 0.87, 1.48),
    "sampled_maneuver": (0.14, 0.33, 0.62, 1.04, 1.60),
    "full": (0.10, 0.21, 0.41, 0.78, 1.34),
}


@dataclass(frozen=True)
class InputAblation:
    """What a variant's networks see of a normalised batch x [B, 4, 8, 30] → [B, C', 8, 30]."""

    channels: tuple[int, ...] = (0, 1, 2, 3)
    rows: tuple[int, ...] = tuple(range(8))  # the row order (a permutation of 0..7)
    target_only: bool = False  # every row but the target's zeroed

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.asarray(x, np.float32)
        if self.channels != (0, 1, 2, 3):
            out = out[:, list(self.channels)]
        if self.target_only:
            out = out.copy()
            out[:, :, np.arange(out.shape[2]) != TARGET_ROW] = 0.0
        if self.rows != tuple(range(8)):
            out = out[:, :, list(self.rows)]
        return np.ascontiguousarray(out, dtype=np.float32)

    def is_identity(self) -> bool:
        return self == InputAblation()

    def describe(self) -> dict[str, Any]:
        return {
            "channels": [("x", "y", "v", "a")[c] for c in self.channels],
            "rows": [ROWS[r] for r in self.rows],
            "target_only": self.target_only,
        }


@dataclass(frozen=True)
class Variant:
    """One column of Table II: how it is built and how its forecasts are made."""

    name: str
    label: str  # as in the paper's table
    model: STCNNConfig
    inputs: InputAblation
    #: "train" both networks, "regressor" (train the regressor alone, no maneuver input) or
    #: "sampled" (reuse the full model; its regressor gets random maneuver sequences)
    training: str = "train"

    def transform(self) -> InputAblation | None:
        """The input transform for training and prediction (None: the inputs as they are)."""
        return None if self.inputs.is_identity() else self.inputs


def variants() -> dict[str, Variant]:
    """The seven variants in the paper's column order."""
    paper = STCNNConfig()
    return {
        v.name: v
        for v in (
            Variant(
                "xy_only", "Only input x and y", replace(paper, channels=2), InputAblation(channels=(0, 1))
            ),
            Variant("no_neighbourhood", "Without neighbourhood", paper, InputAblation(target_only=True)),
            Variant("shuffled", "Shuffled neighbourhood", paper, InputAblation(rows=SHUFFLED_ROWS)),
            Variant(
                "no_dilation",
                "Without dilation",
                replace(paper, conv_dilations=((1, 1), (1, 1), (1, 1), (1, 1))),
                InputAblation(),
            ),
            Variant(
                "no_maneuver",
                "Without maneuver",
                replace(paper, maneuver_input=False),
                InputAblation(),
                training="regressor",
            ),
            Variant("sampled_maneuver", "Sampled maneuver", paper, InputAblation(), training="sampled"),
            Variant("full", "Full approach", paper, InputAblation()),
        )
    }


def variant_parameters(variant: Variant) -> int:
    """Trainable parameters of the networks a variant uses (the regressor alone for ``no_maneuver``)."""
    net = STCNN(variant.model)
    if variant.training == "regressor":
        return count_parameters(net.regressor)
    return count_parameters(net)


def sample_sequences(train_maneuver: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n maneuver sequences drawn with replacement from the training windows' sequences.

    train_maneuver int [M, 5] → int64 [n, 5] (the training distribution of whole sequences).
    """
    rng = np.random.default_rng(seed)
    return np.asarray(train_maneuver)[rng.integers(0, len(train_maneuver), size=n)].astype(np.int64)


@dataclass
class VariantForecast:
    """A variant's forecasts of N windows (window frame, metres)."""

    offsets: np.ndarray  # float32 [N, 5, 2]
    probs: np.ndarray | None  # float32 [N, 5, 3], None without a classifier
    maneuver: np.ndarray | None  # int64 [N, 5] the maneuvers the regressor got from the classifier


@torch.inference_mode()
def predict_variant(
    model: STCNN,
    card: dict[str, Any],
    transform: Callable[[np.ndarray], np.ndarray] | None,
    inputs: np.ndarray,
    present: np.ndarray,
    *,
    maneuver: np.ndarray | None = None,
    use_classifier: bool = True,
    batch_size: int = 4096,
) -> VariantForecast:
    """Forecasts of a (possibly ablated) ST-CNN: inputs float32 [N, 4, 8, 30] physical, present [N, 8, 30].

    ``maneuver`` int [N, 5]: the sequences the regressor gets instead of the classifier's argmax
    (the sampled-maneuver variant); ``use_classifier=False`` with a regressor without maneuver input.
    """
    stats = NormStats.from_dict(card["normalisation"]["inputs"])
    fut = card["normalisation"]["future"]
    mean = np.asarray(fut["mean"], np.float32).reshape(-1, 2)
    std = np.float32(fut["std"])
    n = inputs.shape[0]
    offsets = np.empty((n, model.config.horizon, 2), np.float32)
    probs = np.empty((n, model.config.horizon, model.config.classes), np.float32) if use_classifier else None
    chosen = np.empty((n, model.config.horizon), np.int64) if use_classifier else None
    model.eval()
    for start in range(0, n, batch_size):
        sl = slice(start, start + batch_size)
        x_np = normalise(np.asarray(inputs[sl]), np.asarray(present[sl]), stats)
        x = torch.from_numpy(transform(x_np) if transform is not None else x_np)
        m: torch.Tensor | None = None
        if use_classifier:
            logits = model.classifier(x)
            assert probs is not None and chosen is not None
            probs[sl] = torch.softmax(logits, dim=2).numpy()
            chosen[sl] = logits.argmax(dim=2).numpy()
            m = logits.argmax(dim=2)
        if maneuver is not None:
            m = torch.from_numpy(np.asarray(maneuver[sl], np.int64))
        offsets[sl] = model.regressor(x, m).numpy() * std + mean
    base = reference_offsets(np.asarray(inputs), str(fut.get("relative_to", "none")))
    if base is not None:  # offsets relative to the constant-velocity extrapolation
        offsets += base
    kinematic_limits(offsets)  # as the library's prediction path (lanecast.models.predict)
    return VariantForecast(offsets, probs, chosen)


def score(forecast: VariantForecast, future: np.ndarray, maneuver: np.ndarray) -> dict[str, Any]:
    """The ablation's figures for one trained variant: forecast vs future [N, 5, 2], maneuver int [N, 5].

    rmse and rmse_lane_change (per window, 1–5 s), fde, miss_rate, and where the variant classifies
    maneuver_accuracy and maneuver_macro_f1 (over the classes present or predicted).
    """
    err = displacement_errors(forecast.offsets, future)
    lc = lane_change_windows(maneuver)
    out: dict[str, Any] = {
        "rmse": rmse(err).tolist(),
        "rmse_lane_change": rmse(err[lc]).tolist(),
        "fde": fde(err),
        "miss_rate": miss_rate(err),
        "maneuver_accuracy": None,
        "maneuver_macro_f1": None,
    }
    if forecast.maneuver is not None:
        conf = confusion_matrix(maneuver, forecast.maneuver)
        out["maneuver_accuracy"] = accuracy(conf)
        out["maneuver_macro_f1"] = macro_f1(conf)
    return out


def mean_std(runs: list[dict[str, Any]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Mean and (sample, ddof 1; 0 for one run) std over seeds of every numeric figure of ``score``."""
    mean: dict[str, Any] = {}
    std: dict[str, Any] = {}
    for key in runs[0]:
        if runs[0][key] is None:
            mean[key] = std[key] = None
            continue
        values = np.asarray([r[key] for r in runs], np.float64)
        mean[key] = np.mean(values, axis=0).tolist()
        std[key] = (np.std(values, axis=0, ddof=1) if len(runs) > 1 else np.zeros_like(values[0])).tolist()
    return mean, std


def train_variant(
    windows: Windows, variant: Variant, config: TrainConfig, *, full: STCNN | None = None
) -> TrainResult:
    """Train one variant (``lanecast.models.train.train`` with its architecture and input transform).

    ``config``: its ``model`` is replaced by the variant's; ``full``: the trained full
    model, needed by ``no_maneuver`` (whose classifier is copied and left alone). Returns the TrainResult.
    """
    if variant.training == "sampled":
        raise ValueError("the sampled-maneuver variant is not trained: it reuses the full model")
    if variant.training == "regressor" and full is None:
        raise ValueError(f"{variant.name} needs the trained full model")
    return train(
        windows,
        replace(config, model=variant.model),
        transform=variant.transform(),
        classifier_from=full if variant.training == "regressor" else None,
    )


def _split_indices(windows: Windows) -> tuple[np.ndarray, str]:
    """The windows the ablation is scored on: labelled test windows, else validation ones."""
    for split in ("test", "val"):
        idx = labelled(windows, (split,))
        if len(idx):
            return idx, split
    raise InputError(None, "no labelled test or validation windows to score the ablation on")


def headline(variants_: dict[str, Any], squared_5s: dict[str, np.ndarray]) -> dict[str, Any]:
    """Which variant wins at 5 s and whether it is significantly better than the full model and than
    the runner-up: the paired bootstrap of :func:`lanecast.models.metrics.paired_rmse_difference` on
    the scored windows (each window's squared error averaged over the seeds). → the ``headline`` of
    ablation.json: ``winner``, ``comparisons`` [{``against``, ``difference_m`` (winner minus other;
    negative = winner better), ``low``, ``high``, ``significant``}] and the sentence ``text``."""
    ranked = sorted(variants_, key=lambda n: variants_[n]["mean"]["rmse"][-1])
    if not ranked:
        return {"winner": None, "comparisons": [], "text": "no variant was scored"}
    winner = ranked[0]
    others = list(
        dict.fromkeys(n for n in (["full"] if "full" in ranked else []) + ranked[1:2] if n != winner)
    )
    label = variants_[winner]["label"]
    n_windows = len(squared_5s[winner])
    comparisons = []
    parts = []
    for other in others:
        diff, low, high = paired_rmse_difference(squared_5s[winner], squared_5s[other])
        significant = bool(np.isfinite(high) and high < 0)
        comparisons.append(
            {"against": other, "difference_m": diff, "low": low, "high": high, "significant": significant}
        )
        verdict = "significant" if significant else "not significant (the interval includes 0)"
        parts.append(
            f"{-diff:.2f} m better than {variants_[other]['label'].lower()} on the pooled errors of all seeds "
            f"(95 % interval {-high:.2f} to {-low:.2f} m): {verdict}"
        )
    rmse5 = variants_[winner]["mean"]["rmse"][-1]
    text = f"{label} has the lowest RMSE at 5 s, {rmse5:.2f} m on {n_windows:,} windows"
    text += ("; " + "; ".join(parts) if parts else "") + "."
    return {"winner": winner, "n_windows": n_windows, "comparisons": comparisons, "text": text}


def run_ablation(
    windows: Windows,
    names: list[str],
    seeds: list[int],
    config: TrainConfig,
    *,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Train and score every variant in ``names`` for every seed on ``windows`` (train split to train,
    val to select epochs, test to score). ``config``: the training config whose ``seed`` and
    ``model`` each variant replaces. Returns the content of ``ablation.json``."""
    table = variants()
    unknown = sorted(set(names) - set(table))
    if unknown:
        raise ValueError(f"unknown variants {unknown}; choose from {list(table)}")
    order = [n for n in table if n in names]  # the paper's column order; full before its dependants
    need_full = any(table[n].training != "train" for n in order)
    idx, split = _split_indices(windows)
    inputs, present = np.asarray(windows.inputs[idx]), np.asarray(windows.present[idx])
    future, maneuver = np.asarray(windows.future[idx]), np.asarray(windows.maneuver[idx])
    train_maneuver = np.asarray(windows.maneuver[labelled(windows, ("train",))])
    runs: dict[str, list[dict[str, Any]]] = {n: [] for n in order}
    squared_5s: dict[str, list[np.ndarray]] = {n: [] for n in order}  # per seed, per window
    for seed in seeds:
        cfg = replace(config, seed=seed)
        full: TrainResult | None = None
        for name in (["full"] if need_full else []) + [n for n in order if n != "full" or not need_full]:
            v = table[name]
            if v.training == "sampled":
                assert full is not None  # trained first whenever a variant needs it
                model, card, seconds = full.model, full.card, 0.0
                fc = predict_variant(
                    model,
                    card,
                    None,
                    inputs,
                    present,
                    maneuver=sample_sequences(train_maneuver, len(idx), seed),
                    use_classifier=False,
                )
            else:
                log(f"ablation: seed {seed}, training {v.label.lower()}")
                result = train_variant(windows, v, cfg, full=full.model if full is not None else None)
                model, card = result.model, result.card
                seconds = float(card["training"]["train_seconds"])
                if name == "full":
                    full = result
                fc = predict_variant(
                    model, card, v.transform(), inputs, present, use_classifier=v.training != "regressor"
                )
            if name in runs:
                runs[name].append({"seed": seed, "train_seconds": seconds, **score(fc, future, maneuver)})
                squared_5s[name].append(displacement_errors(fc.offsets, future)[:, -1] ** 2)
    out_variants: dict[str, Any] = {}
    for name in order:
        v = table[name]
        figures = [{k: r[k] for k in r if k not in ("seed", "train_seconds")} for r in runs[name]]
        mean, std = mean_std(figures)
        out_variants[name] = {
            "label": v.label,
            "parameters": variant_parameters(v),
            "inputs": v.inputs.describe(),
            "training": v.training,
            "paper_rmse": list(PAPER_TABLE_II[name]),
            "mean": mean,
            "std": std,
            "runs": runs[name],
        }
    return {
        "variants": out_variants,
        "seeds": list(seeds),
        "scored_on": {
            "split": split,
            "windows": len(idx),
            "lane_change_windows": int(lane_change_windows(maneuver).sum()),
        },
        "train_config": config.to_dict(),
        "headline": headline(out_variants, {n: np.mean(squared_5s[n], axis=0) for n in order}),
        "rmse": "per window, sqrt(mean over windows of the squared Euclidean error), m, at 1-5 s",
        "paper": "Table II of Mersch et al., IROS 2021 (highD)",
    }
