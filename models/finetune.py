"""Fine-tuning that keeps what the base model knows (``lanecast train --init``).

Plain fine-tuning on a user's recording erases the base model's skills: on a congested freeway
excerpt without lane changes it taught the classifier never to change lanes and the regressor to
forget free flow and arterial queues. Three guards, each optional (``FinetuneOptions``):

* **replay** (rehearsal): training batches mix the new windows with a compact replay set of the
  base model's training distribution (``<stem>.replay.npz`` beside the weights, made from the
  card's recipe by ``benchmarks/replay_set.py``), ``replay_share`` of the training windows, and
  the best epoch is chosen on both validation sets;
* **l2sp**: a penalty ``weight · Σ (w − w_base)²`` over each network's parameters (L2-SP, Li et
  al. 2018) keeps the weights near the base instead of near zero (weight decay would pull them
  towards an untrained network);
* **the classifier on its own terms**: new data with (almost) no lane change says nothing about
  when vehicles change lanes; trained on it the classifier learns "never". By default the base
  classifier is kept (frozen, decision offsets included); ``classifier="auto"`` fine-tunes it
  where the new training windows hold at least ``min_lane_change_windows`` lane changes.

The fine-tuned card records its base (name, weights checksum), the data added, how the base was
kept, and an out-of-distribution range that covers the base's training data and the new data.
"""

from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import torch

from lanecast.io_adapters.contracts.windows import INDEX_SCHEMA, Windows, concat_windows, labelled, subset
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.models import ood
from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, file_sha256, read_card, resolve
from lanecast.models.stcnn import STCNN
from lanecast.models.train import TrainConfig, TrainResult, train

#: ways of keeping the base model: rehearsal and the penalty together, either alone, or neither
KEEP_BASE = ("l2sp+replay", "replay", "l2sp", "none")
CLASSIFIER = ("auto", "train", "freeze")
#: the replay set of a model ``<stem>.safetensors`` is ``<stem>.replay.npz`` beside it
REPLAY_SUFFIX = ".replay.npz"
#: the recording name replay windows carry (in the mixed training set only)
REPLAY_RECORDING = "replay"


@dataclass(frozen=True)
class FinetuneOptions:
    """How ``train --init`` keeps the base model (defaults chosen on benchmarks/finetune.py)."""

    keep_base: str = "l2sp+replay"
    #: L2-SP weight: the penalty is weight · Σ (w − w_base)², added to each network's loss
    l2sp_weight: float = 0.1
    #: share of the training windows drawn from the replay set (sampled with replacement when the
    #: replay set holds fewer); the same share of the validation windows
    replay_share: float = 0.5
    #: "freeze": keep the base classifier (benchmarks/finetune.py: fine-tuned, even with replay
    #: and the penalty, on a recording with 657 lane-change windows it gained 0.02 macro-F1 there
    #: and lost up to 0.17 elsewhere); "auto": fine-tune it where the new training windows hold at
    #: least ``min_lane_change_windows`` windows with a lane-change step; "train"
    classifier: str = "freeze"
    min_lane_change_windows: int = 50

    def __post_init__(self) -> None:
        if self.keep_base not in KEEP_BASE:
            raise ValueError(f"keep_base must be one of {KEEP_BASE}, not {self.keep_base!r}")
        if self.classifier not in CLASSIFIER:
            raise ValueError(f"classifier must be one of {CLASSIFIER}, not {self.classifier!r}")
        if not (np.isfinite(self.l2sp_weight) and self.l2sp_weight >= 0):
            raise ValueError(f"l2sp_weight must be a number >= 0, not {self.l2sp_weight}")
        if not 0 <= self.replay_share < 1:
            raise ValueError(f"replay_share must be in [0, 1), not {self.replay_share}")

    @property
    def replay(self) -> bool:
        return "replay" in self.keep_base and self.replay_share > 0

    @property
    def l2sp(self) -> bool:
        return "l2sp" in self.keep_base and self.l2sp_weight > 0


#: fine-tuning's learning rate and epochs where the user gives none (benchmarks/finetune.py: the
#: base's 1e-3 erased more of the base at no gain on the new data; cosine to 0 as the base's)
FINETUNE_LR = 3e-4
FINETUNE_EPOCHS = 6


class L2SP:
    """The penalty weight · Σ (w − w_base)² of a network (``"classifier"`` or ``"regressor"``)."""

    def __init__(self, base: STCNN, weight: float) -> None:
        self.weight = weight
        self.anchor = {
            name: {k: v.detach().clone() for k, v in getattr(base, name).named_parameters()}
            for name in ("classifier", "regressor")
        }

    def __call__(self, name: str, network: torch.nn.Module) -> torch.Tensor:
        anchor = self.anchor[name]
        total = torch.zeros(())
        for key, param in network.named_parameters():
            total = total + torch.sum((param - anchor[key].to(param.device)) ** 2)
        return self.weight * total


def interpolate_regressor(base: STCNN, tuned: STCNN, share: float) -> STCNN:
    """A copy of ``base`` whose regressor's floating-point tensors are moved ``share`` of the way to
    ``tuned``'s (0: the base, 1: the tuned one); the classifier stays the base's.

    Weight-space ensembling of a fine-tune and its start (Wortsman et al., CVPR 2022): fine-tuned
    from the base, the weights stay in its basin, so their average is a working network between the
    two (the shipped regressor's robust stage, ``benchmarks/robust_regressor.py``).
    """
    if not 0 <= share <= 1:
        raise ValueError(f"share must be in [0, 1], not {share}")
    out = copy.deepcopy(base)
    b, t = base.regressor.state_dict(), tuned.regressor.state_dict()
    out.regressor.load_state_dict(
        {k: (1 - share) * b[k] + share * t[k] if b[k].is_floating_point() else b[k] for k in b}
    )
    return out


def lane_change_windows(windows: Windows, rows: np.ndarray) -> int:
    """How many of the windows ``rows`` hold a lane-change step (left or right)."""
    return int(np.count_nonzero(np.any(np.asarray(windows.maneuver[rows]) > 0, axis=1)))


def replay_path(weights: Path) -> Path:
    """Where the replay set of the model with weights file ``weights`` lies."""
    return weights.with_name(weights.stem + REPLAY_SUFFIX)


def save_replay(windows: Windows, rows: np.ndarray, path: Path, recipe: dict[str, Any]) -> Path:
    """Write the windows ``rows`` as a replay set (npz, inputs float16, atomically) with ``recipe``."""
    index = windows.index.take(pa.array(rows, pa.int64()))
    arrays = {
        "inputs": np.asarray(windows.inputs[rows]).astype(np.float16),
        "present": np.asarray(windows.present[rows]),
        "future": np.asarray(windows.future[rows], dtype=np.float32),
        "maneuver": np.asarray(windows.maneuver[rows]).astype(np.int8),
        "split": index.column("split").to_numpy(zero_copy_only=False).astype("U5"),
        "recipe": np.array(json.dumps(recipe)),
    }
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


def load_replay(path: Path) -> Windows:
    """The replay set at ``path`` as windows (recording ``replay``, split train/val as stored)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            inputs = z["inputs"].astype(np.float32)
            present, future = z["present"].astype(bool), z["future"].astype(np.float32)
            maneuver, split = z["maneuver"].astype(np.int64), z["split"].astype(str)
            recipe = json.loads(str(z["recipe"]))
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(path, f"unreadable replay set: {exc}", expected="a replay .npz") from exc
    n = len(inputs)
    index = pa.table(
        {
            "recording": pa.array([REPLAY_RECORDING] * n),
            "track_id": pa.array(np.arange(n), pa.int64()),
            "t0_ns": pa.array(np.zeros(n, np.int64)),
            "split": pa.array(split),
            "origin_x": pa.array(np.zeros(n)),
            "origin_y": pa.array(np.zeros(n)),
            "origin_heading": pa.array(np.zeros(n)),
        },
        schema=INDEX_SCHEMA,
    )
    windows = Windows(inputs, present, future, maneuver, index, {"replay": recipe})
    windows.check(path)
    return windows


def _sample(rows: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` of ``rows``: without replacement where there are enough, else all and some again."""
    if n <= 0 or rows.size == 0:
        return rows[:0]
    if n <= rows.size:
        return np.sort(rng.choice(rows, n, replace=False))
    return np.sort(np.concatenate([rows, rng.choice(rows, n - rows.size, replace=True)]))


def mix_replay(windows: Windows, replay: Windows, share: float, seed: int) -> tuple[Windows, dict[str, int]]:
    """The labelled train and val windows of ``windows`` with replay windows added, ``share`` of
    each split from the replay set; and the counts of each."""
    rng = np.random.default_rng(seed)
    parts, counts = [], {}
    new_rows = {s: labelled(windows, (s,)) for s in ("train", "val")}
    parts.append(subset(windows, np.concatenate(list(new_rows.values()))))
    for s, rows in new_rows.items():
        wanted = round(rows.size * share / (1 - share))
        picked = _sample(labelled(replay, (s,)), wanted, rng)
        counts[f"new_{s}"], counts[f"replay_{s}"] = int(rows.size), int(picked.size)
        parts.append(subset(replay, picked))
    mixed = concat_windows(parts, manifest=dict(windows.manifest))
    return mixed, counts


def merged_distribution(
    base: dict[str, Any], n_base: int, added: dict[str, Any], n_added: int
) -> dict[str, dict[str, float]]:
    """The training distribution of base and added windows together, from the two summaries: the
    envelope of their percentiles (lower ones the smaller, upper ones the larger, the median
    weighted by windows: an approximation) and the pooled mean and std (exact). The out-of-
    distribution range (``ood.RANGE``) then covers both."""
    out: dict[str, dict[str, float]] = {}
    for name in sorted(set(base) | set(added)):
        a, b = base.get(name), added.get(name)
        if not a or not b:
            out[name] = dict(a or b or {})
            continue
        wa, wb = n_base / max(n_base + n_added, 1), n_added / max(n_base + n_added, 1)
        row: dict[str, float] = {}
        for p in ood.PERCENTILES:
            key = f"p{p:g}"
            if p < 50:
                row[key] = min(a[key], b[key])
            elif p > 50:
                row[key] = max(a[key], b[key])
            else:
                row[key] = round(wa * a[key] + wb * b[key], 4)
        mean = wa * a["mean"] + wb * b["mean"]
        var = wa * (a["std"] ** 2 + (a["mean"] - mean) ** 2) + wb * (b["std"] ** 2 + (b["mean"] - mean) ** 2)
        row.update(mean=round(mean, 4), std=round(float(np.sqrt(var)), 4))
        out[name] = row
    return out


def finetune(
    windows: Windows,
    config: TrainConfig,
    base: tuple[STCNN, dict[str, Any]],
    *,
    base_name: str,
    base_sha256: str | None,
    replay: Windows | None = None,
    options: FinetuneOptions | None = None,
    data_card: dict[str, Any] | None = None,
) -> TrainResult:
    """Fine-tune ``base`` (model, card) on ``windows`` keeping its skills as ``options`` say.

    ``replay``: the base's replay set (needed for ``keep_base`` with replay; without it the run
    falls back to the penalty alone and the card says so). The result's card gains a ``finetune``
    section and a training distribution merged from the base's and the new data's."""
    options = options or FinetuneOptions()
    model, base_card = base
    config = dataclasses.replace(config, model=model.config)
    train_rows = labelled(windows, ("train",))
    if len(train_rows) == 0:
        raise InputError(
            None, "no labelled training windows (split 'train')", expected="windows with known futures"
        )
    n_changes = lane_change_windows(windows, train_rows)
    freeze = options.classifier == "freeze" or (
        options.classifier == "auto" and n_changes < options.min_lane_change_windows
    )
    notes = []
    use_replay = options.replay and replay is not None
    if options.replay and replay is None:
        notes.append("no replay set for this base model: replay skipped")
    data, counts = windows, dict[str, int]()
    if use_replay:
        assert replay is not None
        data, counts = mix_replay(windows, replay, options.replay_share, config.seed)
    penalty = L2SP(model, options.l2sp_weight) if options.l2sp else None
    result = train(
        data,
        config,
        data_card=data_card,
        classifier_from=model if freeze else None,
        init_from=base,
        penalty=penalty,
    )
    added = ood.distribution(windows.inputs[:, :, :, -1:][train_rows], windows.present[:, :, -1:][train_rows])
    base_data = base_card.get("training", {}).get("data", {})
    base_dist = base_data.get("distribution") or {}
    n_base = int(base_data.get("train_windows") or 0)
    training = result.card["training"]
    training["data"]["distribution"] = merged_distribution(base_dist, n_base, added, len(train_rows))
    training["data"]["distribution_added"] = added
    training["data"]["distribution_base"] = base_dist
    held = f"frozen: the new training windows hold {n_changes:,} with a lane change"
    why = (
        f"{held}; the base's kept (--classifier auto or train fine-tunes it)"
        if options.classifier == "freeze"
        else f"{held} (fewer than {options.min_lane_change_windows}), which would teach it never to change lanes"
        if freeze
        else f"fine-tuned on {n_changes} new lane-change windows"
    )
    result.card["finetune"] = {
        "base": {
            "name": base_name,
            "weights_sha256": base_sha256,
            "training_data": base_data.get("kind"),
            "train_windows": n_base,
        },
        "added": {
            **{k: v for k, v in (data_card or {}).items() if k != "init"},
            "train_windows": len(train_rows),
            "val_windows": len(labelled(windows, ("val",))),
            "lane_change_train_windows": n_changes,
        },
        "keep_base": options.keep_base if use_replay or options.keep_base in ("l2sp", "none") else "l2sp",
        "options": dataclasses.asdict(options),
        "replay": (
            {"windows": counts, "recipe": replay.manifest.get("replay")} if use_replay and replay else None
        ),
        "classifier": why,
        "notes": notes,
        "ood_range": "covers the base model's training data and the added data",
    }
    return result


def summary(card: dict[str, Any]) -> str:
    """One line on how a fine-tuned model kept its base (for ``lanecast train``'s output)."""
    f = card.get("finetune")
    if not f:
        return ""
    replay = f.get("replay") or {}
    mixed = replay.get("windows", {})
    how = {
        "l2sp+replay": "replay of the base's training data and an L2-SP penalty",
        "replay": "replay of the base's training data",
        "l2sp": "an L2-SP penalty",
        "none": "nothing (plain fine-tune)",
    }[f["keep_base"]]
    extra = (
        f" ({mixed.get('replay_train', 0):,} replay windows beside {mixed.get('new_train', 0):,} new)"
        if mixed
        else ""
    )
    sha = (f["base"].get("weights_sha256") or "?")[:12]
    return (
        f"fine-tuned from {f['base']['name']} ({sha}) keeping it by {how}{extra}; classifier {f['classifier']}"
        + "".join(f"; {n}" for n in f.get("notes", []))
    )


def find_replay(weights: Path, card: dict[str, Any]) -> Path | None:
    """The replay set of a base model: beside its weights, else (a model fine-tuned from the shipped
    one) the shipped model's; None when there is none."""
    own = replay_path(weights)
    if own.is_file():
        return own
    shipped = WEIGHTS_DIR / f"{SHIPPED_STEM}{REPLAY_SUFFIX}"
    root = (card.get("finetune") or {}).get("base", {}).get("root_sha256")
    if shipped.is_file() and root is not None:
        if read_card(WEIGHTS_DIR / f"{SHIPPED_STEM}.json").get("weights_sha256") == root:
            return shipped
    return None


def finetune_from(
    init: str, windows: Windows, config: TrainConfig, options: FinetuneOptions, data_card: dict[str, Any]
) -> TrainResult:
    """``lanecast train --init INIT``: fine-tune the model ``init`` ("default": the shipped one)."""
    from lanecast.models.checkpoint import load_checkpoint

    path = None if init == "default" else init
    weights, _ = resolve(path)
    base = load_checkpoint(path)
    sha = base[1].get("weights_sha256") or file_sha256(weights)
    where = find_replay(weights, base[1]) if options.replay else None
    result = finetune(
        windows,
        config,
        base,
        base_name="shipped model" if path is None else str(init),
        base_sha256=sha,
        replay=None if where is None else load_replay(where),
        options=options,
        data_card=data_card,
    )
    # the model at the root of a chain of fine-tunes (whose replay set a later fine-tune rehearses)
    root = (base[1].get("finetune") or {}).get("base", {}).get("root_sha256") or sha
    result.card["finetune"]["base"]["root_sha256"] = root
    return result
