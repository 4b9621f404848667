"""Constant-velocity and constant-acceleration baselines behind the same ``predict`` interface as the ST-CNN.

Both read only the target row (T) of the physical inputs, positions in the window frame (so a lateral
drift counts as well as the longitudinal motion). The velocity and acceleration at t0 come from a
least-squares polynomial through the last history positions: a line through the last ``span`` frames
for constant velocity, a parabola through the last ``span`` frames for constant acceleration. Each
fit is exact on its own kind of track (no finite-difference lag) and averages out some noise on
real ones. They predict no maneuver: their ``probs``/``maneuver`` are None and their single
"top-K" trajectory has probability 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lanecast.io_adapters.contracts.windows import HORIZON_S, TARGET_ROW
from lanecast.models.predictions import Predictions

#: Sampling interval of the window history (10 Hz).
DT_S = 0.1


def _fit_matrix(span: int, degree: int) -> np.ndarray:
    """Least-squares coefficient operator [degree+1, span] for samples at t = -(span-1)·dt … 0."""
    t = (np.arange(span) - (span - 1)) * DT_S
    vander = np.vander(t, degree + 1, increasing=True)  # [span, degree+1]: 1, t, t²
    return np.linalg.pinv(vander)


def extrapolate(inputs: np.ndarray, *, degree: int, span: int) -> np.ndarray:
    """Polynomial extrapolation of the target's history.

    inputs: float32 [N, 4, 8, 30] physical (x, y in m in the window frame).
    Returns float32 [N, 5, 2]: offsets at t0+1…5 s = p(t0) + v·h (+ a·h²/2 for degree 2), where p(t0)
    is the last history position and v, a are the fitted derivatives at t0.
    """
    if not 1 <= degree <= 2:
        raise ValueError("degree must be 1 (constant velocity) or 2 (constant acceleration)")
    if span < degree + 1 or span > inputs.shape[-1]:
        raise ValueError(f"span must be in [{degree + 1}, {inputs.shape[-1]}], got {span}")
    track = np.asarray(inputs[:, :2, TARGET_ROW, -span:], dtype=np.float64)  # [N, 2, span]
    coef = np.einsum("ks,nds->nkd", _fit_matrix(span, degree), track)  # [N, degree+1, 2]
    h = np.asarray(HORIZON_S)[None, :, None]  # [1, 5, 1]
    out = track[:, None, :, -1] + coef[:, None, 1, :] * h  # [N, 5, 2]
    if degree == 2:
        out = out + coef[:, None, 2, :] * h**2
    return out.astype(np.float32)


#: Reference trajectories a regressor may predict offsets relative to (card: normalisation.future.relative_to).
RELATIVE_TO = ("none", "cv")
CV_SPAN = 5  # history positions of the constant-velocity fit (0.4 s)


def reference_offsets(inputs: np.ndarray, relative_to: str) -> np.ndarray | None:
    """The trajectory a model's regressed offsets are relative to: inputs float32 [N, 4, 8, 30] →
    float32 [N, 5, 2] (``cv``: the constant-velocity extrapolation, :func:`extrapolate` of degree 1
    over the last ``CV_SPAN`` positions), or None for ``none`` (absolute offsets, the paper's)."""
    if relative_to == "none":
        return None
    if relative_to != "cv":
        raise ValueError(f"relative_to must be one of {RELATIVE_TO}, not {relative_to!r}")
    return extrapolate(inputs, degree=1, span=CV_SPAN)


def kinematic_limits(offsets: np.ndarray) -> np.ndarray:
    """Forecast offsets float32 [..., 5, 2] (window frame: x along the road, y to its left) moved
    within what a vehicle can do, in place; returned:

    * forward only: x at least 0 and at least its value at the previous horizon. Vehicles in
      traffic do not roll backwards, yet a network extrapolating a standing car from measured
      inputs can put it a few decimetres behind itself (the real NGSIM Peachtree sample: 72 % of an
      earlier model's 1 s forecasts of standing cars pointed backwards, docs/design.md §3);
    * no sliding sideways: |y| at most x at every horizon (a chord at most 45° off the direction of
      travel; a quarter turn ends exactly at 45°). Wheels roll, they do not slide: a car that
      moves 0.2 m forwards cannot move 0.8 m across, yet a network shown a standing car in a
      neighbourhood it never saw can forecast that (the Peachtree sample's standing cars, with
      some weights). Lane changes are far inside the bound (3.5 m across while tens of metres along).

    The window's x axis follows the road or the history's direction of travel, so neither limit
    removes motion a vehicle on a road makes, except a turn of more than 90° within 5 s."""
    along = offsets[..., 0]
    np.maximum(along, 0.0, out=along)
    np.maximum.accumulate(along, axis=-1, out=along)
    offsets[..., 1] = np.clip(offsets[..., 1], -along, along)
    return offsets


@dataclass(frozen=True)
class PolynomialBaseline:
    """A kinematic baseline: ``degree`` 1 = constant velocity, 2 = constant acceleration."""

    name: str
    degree: int
    span: int

    def predict(
        self, inputs: np.ndarray, present: np.ndarray, *, top_k: int = 3, batch_size: int = 65536
    ) -> Predictions:
        """inputs float32 [N, 4, 8, 30] physical, present bool [N, 8, 30] → Predictions (window frame)."""
        del present, top_k  # kinematics need only the target's positions; one trajectory, probability 1
        n = inputs.shape[0]
        offsets = np.empty((n, len(HORIZON_S), 2), np.float32)
        for start in range(0, n, batch_size):
            offsets[start : start + batch_size] = extrapolate(
                inputs[start : start + batch_size], degree=self.degree, span=self.span
            )
        return Predictions(
            offsets=offsets,
            probs=None,
            maneuver=None,
            top_sequences=None,
            top_probs=np.ones((n, 1), np.float32),
            top_offsets=offsets[:, None],
        )


def constant_velocity(span: int = 5) -> PolynomialBaseline:
    """Constant velocity from a line through the last ``span`` positions (default 0.4 s)."""
    return PolynomialBaseline("cv", 1, span)


def constant_acceleration(span: int = 10) -> PolynomialBaseline:
    """Constant acceleration from a parabola through the last ``span`` positions (default 0.9 s)."""
    return PolynomialBaseline("ca", 2, span)
