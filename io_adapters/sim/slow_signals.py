"""Smooth random signals per vehicle, for the simulator's realism (in-lane weave, tracker errors).

One primitive: each vehicle (or track) gets a sum of a few sinusoids with random periods and
phases. It is smooth (bounded derivatives, unlike white noise), deterministic for a given
generator, and a function of (vehicle, time) only, so it does not depend on the order of the rows.
"""

from __future__ import annotations

import numpy as np

COMPONENTS = 3


def sinusoid_sum(
    index: np.ndarray,
    time_s: np.ndarray,
    std: float,
    periods_s: tuple[float, float],
    rng: np.random.Generator,
) -> np.ndarray:
    """float64 [n]: for rows of vehicle ``index`` int [n] (0 … V-1) at ``time_s`` [n], the sum of
    ``COMPONENTS`` sinusoids of that vehicle, periods log-uniform in ``periods_s``, random phases,
    equal amplitudes, total std ``std`` (a sinusoid of amplitude A has std A/√2)."""
    n = int(index.max()) + 1 if index.size else 0
    lo, hi = np.log(periods_s[0]), np.log(periods_s[1])
    periods = np.exp(rng.uniform(lo, hi, size=(n, COMPONENTS)))
    phases = rng.uniform(0.0, 2 * np.pi, size=(n, COMPONENTS))
    out = np.zeros(time_s.size)
    for k in range(COMPONENTS):  # a few vectorised passes over all rows
        out += np.sin(2 * np.pi * time_s / periods[index, k] + phases[index, k])
    return std * np.sqrt(2.0 / COMPONENTS) * out
