"""Model cards and checkpoint paths, without torch: what every engine (torch, ONNX Runtime) needs to find a model.

A checkpoint is two files with one stem, ``<stem>.safetensors`` and ``<stem>.json`` (the card), usually
alone in a model directory; an exported ``<stem>.onnx`` may sit beside them, described by the card's
``onnx`` section (see ``lanecast.models.onnx_export``). This module reads and writes cards and never
imports torch, so that a process served by ONNX Runtime does not pay for it.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.errors import InputError

FORMAT = "lanecast-stcnn"
FORMAT_VERSION = 1
#: Directory of the shipped weights, the default model of every command.
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SHIPPED_STEM = "stcnn-sumo"


def lanecast_version() -> str:
    """The installed lanecast's version (the package's ``__version__``)."""
    from lanecast import __version__

    return __version__


def resolve(model: Path | str | None) -> tuple[Path, Path]:
    """(weights, card) paths of a model given as a directory, either file, or None (the shipped model)."""
    path = Path(model) if model is not None else WEIGHTS_DIR / f"{SHIPPED_STEM}.json"
    if path.is_dir():
        cards = sorted(p for p in path.glob("*.json") if p.with_suffix(".safetensors").is_file())
        if len(cards) != 1:
            found = ", ".join(p.name for p in cards) or _unpaired(path)
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


def _unpaired(directory: Path) -> str:
    """What a model directory without a model holds: a card or weights missing their other half
    (one file of the two copied), or nothing of a model."""
    halves = {".json": ".safetensors", ".safetensors": ".json"}
    alone = [
        f"{p.name} without {p.stem}{halves[p.suffix]}"
        for p in sorted(directory.iterdir())
        if p.suffix in halves and p.is_file() and not p.with_suffix(halves[p.suffix]).is_file()
    ]
    return "; ".join(alone[:3]) if alone else "none"


def read_card(path: Path) -> dict[str, Any]:
    """Parse and check a model card: every field a model is built or used from, for type and range.

    A card is input: ``format_version: "1"``, ``hidden: 2**40``, a negative channel count or a NaN
    normalisation is an InputError naming the card and the field, before anything is built from it.
    """
    try:
        text = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(path, f"unreadable model card: {exc.strerror or exc}", expected="JSON") from exc
    try:
        card = jf.loads(text, "card")
    except jf.FieldError as exc:
        raise jf.as_input_error(path, "unreadable model card", exc) from exc
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise InputError(path, "not a lanecast model card", column="format", expected=repr(FORMAT))
    try:
        version = jf.get(card, "format_version", "", "count", 0)
        if version > FORMAT_VERSION:
            raise InputError(path, f"card format {version} is newer than this lanecast reads")
        for key in ("architecture", "normalisation"):
            if key not in card:
                raise InputError(path, "incomplete model card", column=key, expected="present")
        check_card_fields(card)
    except jf.FieldError as exc:
        raise jf.as_input_error(path, "bad model card", exc) from exc
    return card


#: Largest sizes a card may state (the paper's network: 4 channels, 8 vehicles, 30 frames, 5 steps,
#: 3 classes, hidden 40, convolutions of at most 56 channels): generous bounds that keep a card from
#: allocating more than a few hundred MB of weights.
_SIZE_LIMITS = {
    "channels": 64,
    "vehicles": 64,
    "history": 1024,
    "horizon": 64,
    "classes": 16,
    "hidden": 4096,
}
_CONV_CHANNELS_MAX = 1024
_CONV_LAYERS = 4  # the network's default (STCNNConfig, not imported: this module stays torch-free)
_KERNEL_MAX = 1024


def check_card_fields(card: dict[str, Any]) -> None:
    """FieldError at the first field of ``architecture.config``, ``normalisation`` or a section read
    when the model is used, of the wrong type or range (absent config fields take the defaults)."""
    arch = jf.get(card, "architecture", "", "object")
    config = jf.get(arch, "config", "architecture", "object")
    check_architecture(config, "architecture.config")
    _check_normalisation(card, config)
    check_usage_sections(card)
    jf.get(card, "weights_sha256", "", "str", None)  # the weights file's, checked when they are loaded


def check_architecture(config: dict[str, Any], where: str) -> None:
    """FieldError at the first key of an ``STCNNConfig`` dict (a card's ``architecture.config``, a
    training config's ``model``) of the wrong type or range; absent keys take the defaults."""
    jf.check(config, where, "object")
    for key, limit in _SIZE_LIMITS.items():
        value = jf.get(config, key, where, "positive_int", None)
        if value is not None and value > limit:
            raise jf.FieldError(f"{where}.{key}", f"{value}", f"an integer from 1 to {limit}")
    channels = jf.get(config, "conv_channels", where, "int_list", None)
    if channels is not None and not all(0 < c <= _CONV_CHANNELS_MAX for c in channels):
        raise jf.FieldError(
            f"{where}.conv_channels", f"{channels}", f"integers from 1 to {_CONV_CHANNELS_MAX}"
        )
    for key in ("conv_kernels", "conv_dilations"):
        pairs = jf.get(config, key, where, "list", None)
        if pairs is not None and not all(
            isinstance(p, list) and len(p) == 2 and all(jf.check_int(v, 1, _KERNEL_MAX) for v in p)
            for p in pairs
        ):
            raise jf.FieldError(
                f"{where}.{key}", f"{pairs}"[:60], f"pairs of integers from 1 to {_KERNEL_MAX}"
            )
    slope = jf.get(config, "negative_slope", where, "number", None)
    if slope is not None and not 0 <= slope <= 1:
        raise jf.FieldError(f"{where}.negative_slope", f"{slope}", "a leaky ReLU slope from 0 to 1")
    jf.get(config, "maneuver_input", where, "bool", None)
    conv = ("conv_channels", "conv_kernels", "conv_dilations")
    layers = [len(config[k]) if k in config else _CONV_LAYERS for k in conv]
    if len(set(layers)) > 1:
        raise jf.FieldError(
            f"{where}.conv_kernels",
            f"{layers} layers",
            "conv_channels, conv_kernels, conv_dilations of one length",
        )


def _check_normalisation(card: dict[str, Any], config: dict[str, Any]) -> None:
    from lanecast.models.baselines import RELATIVE_TO

    norm = jf.get(card, "normalisation", "", "object")
    inputs = jf.get(norm, "inputs", "normalisation", "object")
    for key in ("mean", "std"):
        values = jf.get(inputs, key, "normalisation.inputs", "number_list")
        if len(values) != 4 or not all(_in_range(v, key) for v in values):
            raise jf.FieldError(f"normalisation.inputs.{key}", f"{values}", f"4 numbers, {_RANGE[key]}")
    future = jf.get(norm, "future", "normalisation", "object")
    horizon = config.get("horizon", 5)
    mean = jf.get(future, "mean", "normalisation.future", "list")
    if all(isinstance(row, list) for row in mean):  # [horizon][2], or flat
        mean = [v for row in mean for v in row]
    jf.check(mean, "normalisation.future.mean", "number_list")
    if len(mean) != 2 * horizon or not all(_in_range(v, "mean") for v in mean):
        raise jf.FieldError(
            "normalisation.future.mean", f"{mean}"[:60], f"{2 * horizon} numbers, {_RANGE['mean']}"
        )
    relative_to = jf.get(future, "relative_to", "normalisation.future", "str", "none")
    if relative_to not in RELATIVE_TO:
        raise jf.FieldError("normalisation.future.relative_to", f"{relative_to!r}", f"one of {RELATIVE_TO}")
    std = jf.get(future, "std", "normalisation.future", "number")
    if not _in_range(std, "std"):
        raise jf.FieldError("normalisation.future.std", f"{std}", _RANGE["std"])


#: Longest neighbour range (m) a card may ask windows to be cut with: far beyond any sensor.
_NEIGHBOUR_RANGE_MAX = 10_000.0


def check_usage_sections(card: dict[str, Any]) -> None:
    """FieldError at the first bad field of the optional sections read when a model is used: the
    training distribution (out-of-distribution flags), ``training.config`` (``train --init``),
    ``windows.neighbour_range_m`` (how ``forecast`` and ``explain`` cut windows)."""
    from lanecast.models import ood

    training = jf.get(card, "training", "", "object", None)
    if training is not None:
        jf.get(training, "config", "training", "object", None)
        data = jf.get(training, "data", "training", "object", {})
        distribution: dict[str, Any] = jf.get(data, "distribution", "training.data", "object", None) or {}
        for name in ood.CHECKED if distribution else ():
            where = f"training.data.distribution.{name}"
            quantiles = jf.get(distribution, name, "training.data.distribution", "object", None)
            if not quantiles:
                continue
            low, high = (jf.get(quantiles, key, where, "number") for key in ood.RANGE)
            if low > high:
                raise jf.FieldError(f"{where}.{ood.RANGE[1]}", f"{high}", f">= {ood.RANGE[0]} ({low})")
    windows = jf.get(card, "windows", "", "object", None)
    if windows is not None:
        reach = windows.get("neighbour_range_m")  # null: windows cut without a recorded range
        reach = None if reach is None else jf.check(reach, "windows.neighbour_range_m", "number")
        if reach is not None and not 0 < reach <= _NEIGHBOUR_RANGE_MAX:
            raise jf.FieldError(
                "windows.neighbour_range_m", f"{reach}", f"metres, > 0 and at most {_NEIGHBOUR_RANGE_MAX:g}"
            )


# Normalisation statistics are physical (m, m/s, m/s²): bounds far outside any road, inside float32.
_STAT_LIMIT = 1e6
_RANGE = {"mean": f"within ±{_STAT_LIMIT:g}", "std": f"from {1 / _STAT_LIMIT:g} to {_STAT_LIMIT:g}"}


def _in_range(value: float, key: str) -> bool:
    if key == "std":
        return 1 / _STAT_LIMIT <= value <= _STAT_LIMIT
    return abs(value) <= _STAT_LIMIT


def write_card(card_path: Path, card: dict[str, Any]) -> None:
    """Write a card atomically, readable by everyone (it is package data for the shipped model)."""
    from lanecast.io_adapters.files import atomic_path

    with atomic_path(card_path) as tmp:
        tmp.write_text(
            json.dumps(card, indent=2, allow_nan=False, default=_json_default) + "\n", encoding="utf-8"
        )
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


def provenance(model: Path | str | None) -> dict[str, str]:
    """Which model made a forecast, for every output that holds forecasts: its name (a path, or
    the shipped model's), the sha256 of its weights and what it was trained on, in words."""
    weights, card_path = resolve(model)
    card = read_card(card_path)
    data = card.get("training", {}).get("data", {}) if isinstance(card.get("training"), dict) else {}
    data = data if isinstance(data, dict) else {}
    recordings = data.get("train_recordings")
    if isinstance(recordings, list) and recordings:
        scenarios = sorted({str(r.get("scenario")) for r in recordings if isinstance(r, dict)})
        trained_on = f"{len(recordings)} simulated recordings ({', '.join(scenarios)})"
    elif data.get("windows"):
        trained_on = f"the windows dataset {data['windows']}"
    else:
        trained_on = "data its card does not name"
    if data.get("init"):
        trained_on += f", fine-tuned from {data['init']}"
    name = f"the shipped model ({SHIPPED_STEM})" if model is None else str(card_path)
    sha = card.get("weights_sha256")
    return {
        "model": name,
        "sha256": sha if isinstance(sha, str) and sha else file_sha256(weights),
        "trained_on": trained_on,
    }


def provenance_line(prov: dict[str, str]) -> str:
    """One line of :func:`provenance` for a summary: 'model: … (sha256 1a2b3c4d5e6f), trained on …'."""
    return f"model: {prov['model']} (sha256 {prov['sha256'][:12]}), trained on {prov['trained_on']}"
