"""The window frame: a window's coordinates (origin at the target at t0, x along its heading)
to and from the source frame of the track table it was cut from (docs/design.md §2)."""

from __future__ import annotations

import numpy as np


def to_source_frame(
    xy: np.ndarray, origin_x: np.ndarray, origin_y: np.ndarray, heading: np.ndarray
) -> np.ndarray:
    """Window-frame points [N, ..., 2] to the source frame: origin + R(heading) @ xy (float64)."""
    c = np.cos(heading).reshape((-1,) + (1,) * (xy.ndim - 2))
    s = np.sin(heading).reshape(c.shape)
    x = xy[..., 0].astype(np.float64)
    y = xy[..., 1].astype(np.float64)
    ox = np.asarray(origin_x, dtype=np.float64).reshape(c.shape)
    oy = np.asarray(origin_y, dtype=np.float64).reshape(c.shape)
    return np.stack([ox + c * x - s * y, oy + s * x + c * y], axis=-1)


def to_window_frame(
    xy: np.ndarray, origin_x: np.ndarray, origin_y: np.ndarray, heading: np.ndarray
) -> np.ndarray:
    """Source-frame points [N, ..., 2] to the window frame: R(-heading) @ (xy - origin) (float64).

    The inverse of :func:`to_source_frame`.
    """
    c = np.cos(heading).reshape((-1,) + (1,) * (xy.ndim - 2))
    s = np.sin(heading).reshape(c.shape)
    dx = xy[..., 0] - np.asarray(origin_x, dtype=np.float64).reshape(c.shape)
    dy = xy[..., 1] - np.asarray(origin_y, dtype=np.float64).reshape(c.shape)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
