"""Model checkpoints: weights in safetensors plus a JSON card; loading never unpickles anything.

A checkpoint is two files with one stem, ``<stem>.safetensors`` and ``<stem>.json``, usually alone in
a model directory (``lanecast train --out MODEL_DIR`` writes ``stcnn.*``). The card holds what is
needed to use the weights (architecture config, input and output normalisation) and what is needed
to trust them (training data, parameters, history, validation and test metrics, version).
The shipped model is ``models/weights/stcnn-sumo.*``, the default wherever a model is optional.
"""

from __future__ import annotations

import json
from importlib import metadata
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.models.stcnn import STCNN, STCNNConfig, count_parameters

FORMAT = "lanecast-stcnn"
FORMAT_VERSION = 1
#: Directory of the shipped weights, the default model of every command.
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SHIPPED_STEM = "stcnn-sumo"


def lanecast_version() -> str:
    try:
        return metadata.version("lanecast")
    except metadata.PackageNotFoundError:
        return "unknown"


def architecture_card(model: STCNN) -> dict[str, Any]:
    """The card's ``architecture`` section."""
    return {
        "name": "ST-CNN (Mersch et al., IROS 2021)",
        "variant": "maneuver-based" if model.config.maneuver_input else "regression-only",
        "config": model.config.to_dict(),
        "parameters": {
            "classifier": count_parameters(model.classifier),
            "regressor": count_parameters(model.regressor),
            "total": count_parameters(model),
        },
    }


def save_checkpoint(model: STCNN, card: dict[str, Any], directory: Path, stem: str = "stcnn") -> Path:
    """Write ``<directory>/<stem>.safetensors`` and ``<stem>.json`` (each atomically, card last).

    ``card`` must hold ``normalisation``; ``format``, ``version`` and ``architecture`` are filled in.
    Returns the card's path.
    """
    if "normalisation" not in card:
        raise ValueError("the card needs the normalisation the weights were trained with")
    full = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "lanecast_version": lanecast_version(),
        "architecture": architecture_card(model),
        **{k: v for k, v in card.items() if k not in ("format", "format_version", "architecture")},
    }
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    with atomic_path(directory / f"{stem}.safetensors") as tmp:
        save_file(tensors, str(tmp), metadata={"format": FORMAT, "format_version": str(FORMAT_VERSION)})
        tmp.chmod(0o644)  # package data: readable by everyone
    card_path = directory / f"{stem}.json"
    with atomic_path(card_path) as tmp:
        tmp.write_text(json.dumps(full, indent=2, allow_nan=False, default=_json_default) + "\n")
        tmp.chmod(0o644)
    return card_path


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def resolve(model: Path | str | None) -> tuple[Path, Path]:
    """(weights, card) paths of a model given as a directory, either file, or None (the shipped model)."""
    path = Path(model) if model is not None else WEIGHTS_DIR / f"{SHIPPED_STEM}.json"
    if path.is_dir():
        cards = sorted(p for p in path.glob("*.json") if p.with_suffix(".safetensors").is_file())
        if len(cards) != 1:
            found = ", ".join(p.name for p in cards) or "none"
            raise InputError(path, f"expected one model (<stem>.safetensors + <stem>.json), found {found}")
        path = cards[0]
    if path.suffix not in (".json", ".safetensors"):
        raise InputError(path, "not a model", expected="a model directory, .safetensors or .json file")
    weights, card = path.with_suffix(".safetensors"), path.with_suffix(".json")
    for p in (weights, card):
        if not p.is_file():
            hint = " (the shipped model is missing: reinstall lanecast)" if model is None else ""
            raise InputError(p, f"model file not found{hint}")
    return weights, card


def read_card(path: Path) -> dict[str, Any]:
    """Parse and check a model card."""
    try:
        card = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"unreadable model card: {exc}", expected="JSON") from exc
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise InputError(path, "not a lanecast model card", column="format", expected=repr(FORMAT))
    if card.get("format_version", 0) > FORMAT_VERSION:
        raise InputError(path, f"card format {card['format_version']} is newer than this lanecast reads")
    for key in ("architecture", "normalisation"):
        if key not in card:
            raise InputError(path, "incomplete model card", column=key, expected="present")
    return card


def load_checkpoint(model: Path | str | None = None) -> tuple[STCNN, dict[str, Any]]:
    """Load (network in eval mode on the CPU, card); ``None`` loads the shipped model."""
    weights_path, card_path = resolve(model)
    card = read_card(card_path)
    try:
        config = STCNNConfig.from_dict(card["architecture"]["config"])
        net = STCNN(config)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(card_path, f"bad architecture: {exc}", column="architecture") from exc
    try:
        state = load_file(str(weights_path), device="cpu")
    except (SafetensorError, OSError) as exc:
        raise InputError(weights_path, f"unreadable weights: {exc}", expected="safetensors") from exc
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise InputError(weights_path, f"weights do not fit the card's architecture: {exc}") from exc
    net.eval()
    return net, card


def torch_device(name: str = "auto") -> torch.device:
    """``auto`` = the GPU when there is one, else the CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
