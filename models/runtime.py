"""Which runtime serves a model: ONNX Runtime where its export is fresh and the runtime installed, else torch.

``load_forecaster`` is what the commands that predict call; its ``engine`` keyword names the runtime.
``engine="auto"`` takes ONNX Runtime when the card's ONNX file was exported from these very weights
(``onnx_predict.onnx_file``) and falls back to torch otherwise, saying why on stderr; ``"onnx"``
insists (an error instead of the fallback), ``"torch"`` never tries. torch is imported only when
torch serves.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lanecast.io_adapters.cores import default_threads
from lanecast.io_adapters.errors import InputError
from lanecast.models.card import read_card, resolve
from lanecast.models.onnx_predict import OnnxForecaster, onnx_file
from lanecast.models.predictions import Forecaster

RUNTIMES = ("auto", "onnx", "torch")


def check_model(model: Path | str | None = None, *, engine: str = "auto") -> None:
    """Load the model as the commands that predict will (card, then the ONNX graph or the weights)
    and drop it: an InputError for a bad card, truncated or NaN weights, tensors that do not fit the
    card, before a command creates anything in its output directory. Quiet: a fallback to torch is
    reported when the model is used."""
    load_forecaster(model, engine=engine, quiet=True)


def load_forecaster(
    model: Path | str | None = None,
    name: str = "stcnn",
    *,
    engine: str = "auto",
    threads: int | None = None,
    quiet: bool = False,
) -> Forecaster:
    """A loaded forecaster (``OnnxForecaster`` or ``STCNNForecaster``) for a model (None: the shipped
    one), predicting on ``threads`` threads (None: the free cores, ``io_adapters.cores``) with
    ONNX Runtime or torch."""
    if engine not in RUNTIMES:
        raise InputError(None, f"unknown runtime {engine!r}", expected=", ".join(RUNTIMES))
    weights_path, card_path = resolve(model)
    if engine != "torch":
        card = read_card(card_path)
        path, why = onnx_file(card_path, weights_path, card)
        if path is not None:
            try:
                return OnnxForecaster.from_file(path, card, name, threads=threads)
            except ImportError:
                why = "onnxruntime is not installed"
            except InputError as exc:  # the card vouches for a file ONNX Runtime cannot load
                if engine == "onnx":
                    raise
                why = f"{path.name}: {exc.reason}"
        if engine == "onnx":
            raise InputError(card_path, f"cannot predict with ONNX Runtime: {why}")
        hint = f" (lanecast export {weights_path.parent} --to onnx)" if "installed" not in why else ""
        if not quiet:
            print(f"lanecast: {card_path}: {why}; predicting with torch{hint}", file=sys.stderr)
    import torch

    from lanecast.models.predict import STCNNForecaster

    forecaster = STCNNForecaster.load(weights_path, name)
    torch.set_num_threads(threads or default_threads())  # as ONNX Runtime's: the free cores
    return forecaster
