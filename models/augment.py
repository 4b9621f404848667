"""Training-batch augmentation: the measurement faults of real data, put into simulated windows.

Simulated windows are exact; real ones are not: trackers jitter, speeds and accelerations are
differentiated from noisy positions and flicker, neighbours go missing. A network that never saw
these trusts its inputs where real data does not deserve it (docs/design.md §2). Every function
works in place on a batch of physical (not yet normalised) inputs float32 [B, 4, 8, T] (x, y, speed,
acceleration; 8 vehicles, T frames) and their presence bool [B, 8, T]; absent entries stay 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lanecast.io_adapters.contracts.windows import TARGET_ROW

#: std of an acceleration outlier (m/s²) and of a speed outlier's magnitude (m/s): NGSIM's standing
#: cars flicker v_Vel 0 → 0.12 m/s → 0 with v_Acc ±1.5 m/s² within one frame
OUTLIER_ACC_MPS2 = 1.5
OUTLIER_SPEED_MPS = 0.2


@dataclass(frozen=True)
class Augmentation:
    """What is done to a training batch (all 0: nothing; ``TrainConfig`` documents each)."""

    position_noise_m: float = 0.0
    speed_noise_mps: float = 0.0
    acc_noise_mps2: float = 0.0
    neighbour_dropout: float = 0.0
    derivative_outliers: float = 0.0
    derivative_noise_spread: float = 0.0


def augment(inputs: np.ndarray, present: np.ndarray, aug: Augmentation, rng: np.random.Generator) -> None:
    """Apply ``aug`` to a batch in place, in a fixed order of random draws (same seed, same batch):

    1. a share ``neighbour_dropout`` of the windows loses every neighbour (the target alone);
    2. Gaussian jitter on present x, y (``position_noise_m``), speed and acceleration;
    3. a share ``derivative_outliers`` of the present entries gets an acceleration outlier
       N(0, 1.5 m/s²) and a speed outlier |N(0, 0.2 m/s)|;
    4. speeds kept >= 0 where they were jittered.

    With ``derivative_noise_spread`` s > 0, each window's speed and acceleration jitter and its share
    of outliers (2, 3) are scaled by its own factor drawn from U(1 − s, 1 + s), drawn after the
    position jitter: windows as clean as a simulation's beside windows as noisy as a real tracker's,
    for the network to tell from a window's look whether its derivatives deserve trust (measured in
    BENCHMARKS.md, "Zero-shot": it did not help the real sample; not the shipped recipe).
    """
    batch = len(inputs)
    if aug.neighbour_dropout > 0:
        alone = rng.random(batch) < aug.neighbour_dropout
        neighbours = np.arange(present.shape[1]) != TARGET_ROW
        present[np.ix_(alone, neighbours)] = False
        inputs *= present[:, None]  # absent entries are zero (docs/design.md §2)
    if aug.position_noise_m > 0:
        jitter = rng.normal(0.0, aug.position_noise_m, size=(batch, 2, *present.shape[1:]))
        inputs[:, :2] += jitter.astype(np.float32) * present[:, None]
    scale: float | np.ndarray = 1.0  # per window [B, 1, 1] with a spread
    if aug.derivative_noise_spread > 0:
        spread = aug.derivative_noise_spread
        scale = rng.uniform(1.0 - spread, 1.0 + spread, size=(batch, 1, 1))
    for channel, std in ((2, aug.speed_noise_mps), (3, aug.acc_noise_mps2)):
        if std > 0:
            noise = rng.normal(0.0, std, size=present.shape) * scale
            inputs[:, channel] += noise.astype(np.float32) * present
    if aug.derivative_outliers > 0:
        hit = (rng.random(present.shape) < aug.derivative_outliers * scale) & present
        inputs[:, 3] += hit * rng.normal(0.0, OUTLIER_ACC_MPS2, present.shape).astype(np.float32)
        inputs[:, 2] += hit * np.abs(rng.normal(0.0, OUTLIER_SPEED_MPS, present.shape)).astype(np.float32)
    if max(aug.speed_noise_mps, aug.acc_noise_mps2) > 0:
        np.maximum(inputs[:, 2], 0.0, out=inputs[:, 2])
