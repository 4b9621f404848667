"""Model cards and checkpoint paths, without torch: what every engine (torch, ONNX Runtime) needs to find a model.

A checkpoint is two files with one stem, ``<stem>.safetensors`` and ``<stem>.json`` (the card), usually
alone in a model directory; an exported ``<stem>.onnx`` may sit beside them, described by the card's
``onnx`` section (see ``lanecast.models.onnx_export``). This module reads and writes cards and never
imports torch, so that a process served by ONNX Runtime does not pay for it.
"""

from __future__ import annotations

import hashlib
import json
from importlib import metadata
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path

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


def resolve(model: Path | str | None) -> tuple[Path, Path]:
    """(weights, card) paths of a model given as a directory, either file, or None (the shipped model)."""
    path = Path(model) if model is not None else WEIGHTS_DIR / f"{SHIPPED_STEM}.json"
    if path.is_dir():
        cards = sorted(p for p in path.glob("*.json") if p.with_suffix(".safetensors").is_file())
        if len(cards) != 1:
            found = ", ".join(p.name for p in cards) or "none"
            raise InputError(path, f"expected one model (<stem>.safetensors + <stem>.json), found {found}")
        path = cards[0]
    if path.suffix not in (".json", ".safetensors", ".onnx"):
        raise InputError(path, "not a model", expected="a model directory, .safetensors, .json or .onnx file")
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


def write_card(card_path: Path, card: dict[str, Any]) -> None:
    """Write a card atomically, readable by everyone (it is package data for the shipped model)."""
    with atomic_path(card_path) as tmp:
        tmp.write_text(json.dumps(card, indent=2, allow_nan=False, default=_json_default) + "\n")
        tmp.chmod(0o644)


def set_card_section(card_path: Path, key: str, value: Any) -> None:
    """Replace one top-level section of an existing card (atomically), e.g. ``metrics`` after a test run."""
    card = read_card(card_path)
    card[key] = value
    write_card(card_path, card)


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (how an exported ONNX file names the weights it came from)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def normalisation_sha256(card: dict[str, Any]) -> str:
    """Hex SHA-256 of the card's normalisation section (canonical JSON): what an export baked in."""
    text = json.dumps(card.get("normalisation"), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")
