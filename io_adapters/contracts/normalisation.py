"""Normalisation of the network inputs (docs/design.md §2): per channel, statistics from the
training windows only. Mean and std are taken over *present* entries, so that the zeros of absent
neighbours do not bias them; after normalisation absent entries are exactly 0 again ("zero means
absent")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import CHUNK
from lanecast.io_adapters.errors import InputError


@dataclass(frozen=True)
class NormStats:
    """Per-channel mean and std (float32 [4], channels x, y, v, a; physical units)."""

    mean: np.ndarray
    std: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {
            "channels": ["x", "y", "v", "a"],
            "mean": [float(v) for v in self.mean],
            "std": [float(v) for v in self.std],
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> NormStats:
        try:
            mean = np.asarray(doc["mean"], dtype=np.float32)
            std = np.asarray(doc["std"], dtype=np.float32)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                None, f"bad normalisation statistics {doc!r}", expected="{mean: [4], std: [4]}"
            ) from exc
        if mean.shape != (4,) or std.shape != (4,) or not (np.all(np.isfinite(std)) and np.all(std > 0)):
            raise InputError(
                None, f"bad normalisation statistics {doc!r}", expected="4 means and 4 positive stds"
            )
        return cls(mean, std)


def compute_stats(inputs: np.ndarray, present: np.ndarray, rows: np.ndarray | None = None) -> NormStats:
    """Mean and std per channel over present entries.

    inputs float32 [N, 4, 8, 30], present bool [N, 8, 30]; ``rows`` int [M]: only these windows
    (ascending; e.g. the training split), read chunk by chunk so that a memory-mapped dataset is
    never loaded whole. Sums in float32 within a chunk of 1024 windows and in float64 across
    chunks (relative error ~1e-7). A channel with zero spread gets std 1.
    """
    if inputs.ndim != 4 or inputs.shape[1] != 4 or present.shape != (inputs.shape[0], *inputs.shape[2:]):
        raise InputError(
            None, f"inputs {inputs.shape} / present {present.shape}", expected="[N,4,8,30] / [N,8,30]"
        )
    total = np.zeros(4)
    total_sq = np.zeros(4)
    count = 0
    n = inputs.shape[0] if rows is None else len(rows)
    for start in range(0, n, CHUNK):
        sel: slice | np.ndarray = (
            slice(start, start + CHUNK) if rows is None else np.asarray(rows[start : start + CHUNK])
        )
        m = np.asarray(present[sel])
        x = (np.asarray(inputs[sel]) * m[:, None]).reshape(m.shape[0], 4, -1)
        count += int(np.count_nonzero(m))
        # float32 sums over one chunk (<= 250k values per channel), float64 across chunks
        total += np.einsum("ncj->c", x).astype(np.float64)
        total_sq += np.einsum("ncj,ncj->c", x, x).astype(np.float64)
    if count == 0:
        raise InputError(
            None, "no present entries to compute normalisation statistics from", expected="training windows"
        )
    mean = total / count
    var = np.maximum(total_sq / count - mean**2, 0.0)
    std = np.sqrt(var)
    std[std < 1e-6] = 1.0
    return NormStats(mean.astype(np.float32), std.astype(np.float32))


def normalise(inputs: np.ndarray, present: np.ndarray, stats: NormStats) -> np.ndarray:
    """(inputs - mean) / std per channel; absent entries exactly 0. float32 [N, 4, 8, 30]."""
    x = np.asarray(inputs, dtype=np.float32)
    out = (x - stats.mean[None, :, None, None]) / stats.std[None, :, None, None]
    out *= np.asarray(present)[:, None, :, :]
    return out.astype(np.float32, copy=False)


def denormalise(normalised: np.ndarray, present: np.ndarray, stats: NormStats) -> np.ndarray:
    """Inverse of :func:`normalise` (absent entries 0). float32 [N, 4, 8, 30]."""
    out = normalised * stats.std[None, :, None, None] + stats.mean[None, :, None, None]
    out *= np.asarray(present)[:, None, :, :]
    return out.astype(np.float32, copy=False)
