"""Model checkpoints: weights in safetensors plus a JSON card; loading never unpickles anything.

A checkpoint is two files with one stem, ``<stem>.safetensors`` and ``<stem>.json``, usually alone in
a model directory (``lanecast train --out MODEL_DIR`` writes ``stcnn.*``). The card holds what is
needed to use the weights (architecture config, input and output normalisation) and what is needed
to trust them (training data, parameters, history, validation and test metrics, version).
The shipped model is ``models/weights/stcnn-sumo.*``, the default wherever a model is optional.
Paths and cards are ``lanecast.models.card`` (torch-free; re-exported here).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.models.card import FORMAT as FORMAT
from lanecast.models.card import FORMAT_VERSION as FORMAT_VERSION
from lanecast.models.card import SHIPPED_STEM as SHIPPED_STEM
from lanecast.models.card import WEIGHTS_DIR as WEIGHTS_DIR
from lanecast.models.card import file_sha256, write_card
from lanecast.models.card import lanecast_version as lanecast_version
from lanecast.models.card import read_card as read_card
from lanecast.models.card import resolve as resolve
from lanecast.models.card import set_card_section as set_card_section
from lanecast.models.stcnn import STCNN, STCNNConfig, count_parameters


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
    weights_path = directory / f"{stem}.safetensors"
    with atomic_path(weights_path) as tmp:
        write_safetensors(tmp, tensors, {"format": FORMAT, "format_version": str(FORMAT_VERSION)})
        tmp.chmod(0o644)  # package data: readable by everyone
    # the pair is two renames: the card names its weights, so that a run stopped between them (new
    # weights, old card) is refused on loading instead of serving weights under another card
    full["weights_sha256"] = file_sha256(weights_path)
    card_path = directory / f"{stem}.json"
    write_card(card_path, full)
    return card_path


#: safetensors dtype names (https://huggingface.co/docs/safetensors, "Format").
_DTYPES = {
    torch.float64: "F64",
    torch.float32: "F32",
    torch.float16: "F16",
    torch.bfloat16: "BF16",
    torch.int64: "I64",
    torch.int32: "I32",
    torch.int16: "I16",
    torch.int8: "I8",
    torch.uint8: "U8",
    torch.bool: "BOOL",
}


def write_safetensors(path: Path, tensors: Mapping[str, torch.Tensor], metadata: Mapping[str, str]) -> None:
    """Write ``tensors`` in the safetensors format, byte-identical for equal tensors and metadata.

    ``safetensors.torch.save_file`` writes ``__metadata__`` from a hash map, in an order that changes
    from process to process. Here: 8-byte little-endian header length, compact JSON header with
    ``__metadata__`` first (keys sorted), then the tensors in data order (larger elements first, then
    by name: aligned, and the library's order for one dtype), the header padded with spaces to a
    multiple of 8, then each tensor's raw little-endian bytes.
    """
    order = sorted(tensors, key=lambda name: (-tensors[name].element_size(), name))
    header: dict[str, Any] = {"__metadata__": dict(sorted(metadata.items()))} if metadata else {}
    blobs: list[bytes] = []
    offset = 0
    for name in order:
        tensor = tensors[name]
        if tensor.dtype not in _DTYPES or tensor.layout != torch.strided:
            raise ValueError(f"cannot write tensor {name!r} ({tensor.dtype}, {tensor.layout})")
        raw = tensor.detach().to("cpu").contiguous().reshape(-1).view(torch.uint8)
        if sys.byteorder != "little":
            raw = raw.reshape(-1, tensor.element_size()).flip(-1).reshape(-1)
        blobs.append(raw.numpy().tobytes())
        header[name] = {
            "dtype": _DTYPES[tensor.dtype],
            "shape": list(tensor.shape),
            "data_offsets": [offset, offset + len(blobs[-1])],
        }
        offset += len(blobs[-1])
    text = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
    text += b" " * (-len(text) % 8)
    with open(path, "wb") as f:
        f.write(len(text).to_bytes(8, "little"))
        f.write(text)
        for blob in blobs:
            f.write(blob)


def load_checkpoint(model: Path | str | None = None) -> tuple[STCNN, dict[str, Any]]:
    """Load (network in eval mode on the CPU, card); ``None`` loads the shipped model."""
    weights_path, card_path = resolve(model)
    card = read_card(card_path)
    try:
        config = STCNNConfig.from_dict(card["architecture"]["config"])
        net = STCNN(config)
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise InputError(card_path, f"bad architecture: {exc}", column="architecture") from exc
    try:
        state = load_file(str(weights_path), device="cpu")
    except (SafetensorError, OSError) as exc:
        raise InputError(weights_path, f"unreadable weights: {exc}", expected="safetensors") from exc
    for name, tensor in state.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise InputError(
                weights_path, f"tensor {name!r} holds NaN or infinite values", expected="finite weights"
            )
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise InputError(weights_path, f"weights do not fit the card's architecture: {exc}") from exc
    expected = card.get("weights_sha256")
    if expected is not None and expected != file_sha256(weights_path):
        raise InputError(
            card_path,
            f"{weights_path.name} is not the weights file this card was written with (another run's, "
            "or a run stopped between writing the two)",
            column="weights_sha256",
            expected=f"weights with SHA-256 {str(expected)[:16]}…",
        )
    net.eval()
    return net, card


def torch_device(name: str = "auto") -> torch.device:
    """``auto`` = the GPU when there is one, else the CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
