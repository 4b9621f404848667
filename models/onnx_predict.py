"""Prediction on ONNX Runtime: the exported graph of ``lanecast.models.onnx_export``, without torch.

One ``session.run`` per batch does the whole library path (normalise, classify, top-K sequences,
regress, de-normalise); Python only slices batches. ``onnx_file`` tells whether a card's ONNX export
still matches its weights (a retrained model leaves a stale file behind: it is never used).

Threads: :func:`lanecast.io_adapters.cores.default_threads` (the free cores, shared among a bulk
run's workers). Idle threads sleep instead of spinning. A single process on an idle machine gets
every core (batch 256 runs faster on two).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lanecast.io_adapters.cores import default_threads
from lanecast.io_adapters.errors import InputError
from lanecast.models.card import file_sha256, normalisation_sha256
from lanecast.models.predictions import Predictions

#: What the exported graph computes, recorded in the card at export: 1 forward-only forecasts, 2 also
#: |y| ≤ x (lanecast.models.baselines.kinematic_limits). An export of another version is stale.
GRAPH_VERSION = 2


def onnx_file(card_path: Path, weights_path: Path, card: dict[str, Any]) -> tuple[Path | None, str]:
    """(the card's ONNX file, "") when it is present and was exported from these weights, else (None, why)."""
    section = card.get("onnx")
    if not isinstance(section, dict) or not isinstance(section.get("file"), str):
        return None, "the model has no ONNX export"
    name = section["file"]
    path = card_path.parent / name
    if Path(name).name != name or path.suffix != ".onnx":
        return None, f"the card's onnx.file {name!r} is not a file name beside it"
    if not path.is_file():
        return None, f"{path.name} is missing"
    if section.get("weights_sha256") != file_sha256(weights_path):
        return None, f"{path.name} is stale: it was exported from other weights than {weights_path.name}"
    if section.get("normalisation_sha256") != normalisation_sha256(card):
        return None, f"{path.name} is stale: the card's normalisation changed since the export"
    if section.get("sha256") != file_sha256(path):
        return None, f"{path.name} was modified after the export"
    if section.get("graph_version", 1) != GRAPH_VERSION:
        return (
            None,
            f"{path.name} is stale: exported by a lanecast whose prediction path differs (lanecast export again)",
        )
    return path, ""


class OnnxForecaster:
    """The exported prediction graph on an ONNX Runtime session (same outputs as ``STCNNForecaster``)."""

    engine = "onnxruntime"

    def __init__(self, session: Any, card: dict[str, Any], name: str = "stcnn") -> None:
        self.session = session
        self.card = card
        self.name = name
        self._outputs = ["probs", "maneuver", "top_sequences", "top_probs", "top_offsets"]
        self._k: dict[int, np.ndarray] = {}  # the graph's ``k`` input per top_k, made once
        # ONNX Runtime's compiled session behind its Python wrapper, whose per-call input-name check
        # (a few µs: the feed here is always the graph's three inputs) is most of a batch-1 call's
        # overhead; the wrapper where a build has no such attribute
        self._compiled: Any = getattr(session, "_sess", None)

    @classmethod
    def from_file(
        cls, path: Path, card: dict[str, Any], name: str = "stcnn", *, threads: int | None = None
    ) -> OnnxForecaster:
        """A session on ``path`` with ``threads`` intra-op threads (None: ``default_threads()``)."""
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or default_threads()
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.log_severity_level = 3
        try:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime's own types (InvalidProtobuf, Fail, …): not importable stably
            raise InputError(
                path, f"ONNX Runtime cannot load it: {exc}", expected="an ONNX model from lanecast export"
            ) from exc
        return cls(session, card, name)

    def _run(self, inputs: np.ndarray, present: np.ndarray, k: np.ndarray) -> list[np.ndarray]:
        """One session call on a batch: the compiled session where there is one."""
        feed = {"inputs": _float32(inputs), "present": _bool(present), "k": k}
        if self._compiled is not None:
            return self._compiled.run(self._outputs, feed, None)
        return self.session.run(self._outputs, feed)

    def predict(
        self, inputs: np.ndarray, present: np.ndarray, *, top_k: int = 3, batch_size: int = 4096
    ) -> Predictions:
        """inputs float32 [N, 4, 8, 30] physical (may be memory-mapped), present bool [N, 8, 30] → Predictions.

        ``top_k`` = 0 still regresses the argmax sequence but returns no alternatives (K = 1 kept).
        """
        n = inputs.shape[0]
        if n == 0:
            return empty_predictions(max(top_k, 1))
        k = self._k.get(top_k)
        if k is None:
            k = self._k[top_k] = np.asarray(max(top_k, 1), np.int64)
        if n <= batch_size:  # one call: no slicing, no concatenation (batch 1 pays about the engine)
            outputs = self._run(inputs, present, k)
        else:
            parts = [
                self._run(inputs[s : s + batch_size], present[s : s + batch_size], k)
                for s in range(0, n, batch_size)
            ]
            outputs = [np.concatenate(p) for p in zip(*parts, strict=True)]
        probs, maneuver, sequences, top_probs, top_offsets = outputs
        return Predictions(
            offsets=top_offsets[:, 0],  # the top sequence is the per-step argmax
            probs=probs,
            maneuver=maneuver,
            top_sequences=sequences,
            top_probs=top_probs,
            top_offsets=top_offsets,
        )


def _float32(a: np.ndarray) -> np.ndarray:
    """``a`` as the C-contiguous float32 array the graph takes (no copy when it is one already)."""
    return a if a.dtype == np.float32 and a.flags.c_contiguous else np.ascontiguousarray(a, np.float32)


def _bool(a: np.ndarray) -> np.ndarray:
    return a if a.dtype == np.bool_ and a.flags.c_contiguous else np.ascontiguousarray(a, np.bool_)


def empty_predictions(k: int, horizon: int = 5, classes: int = 3) -> Predictions:
    """Predictions for no windows (the shapes and dtypes of a non-empty batch)."""
    return Predictions(
        offsets=np.empty((0, horizon, 2), np.float32),
        probs=np.empty((0, horizon, classes), np.float32),
        maneuver=np.empty((0, horizon), np.int64),
        top_sequences=np.empty((0, k, horizon), np.int64),
        top_probs=np.empty((0, k), np.float32),
        top_offsets=np.empty((0, k, horizon, 2), np.float32),
    )
