"""The spatio-temporal CNN of Mersch et al. (IROS 2021): a maneuver classifier and a trajectory regressor.

Two separate networks with the same convolution stack (no shared weights). Input: the normalised
window tensor ``[N, 4, 8, 30]`` (channels x, y, v, a; vehicle rows FL F FR L T R RL RR; time oldest
to t0). Convolutions run over (vehicles x time), stride 1, no padding, every layer with bias, leaky
ReLU after every layer except the last dense one, no normalisation layers.

=====  ============  ==========  ========  =========  ================
layer  out channels  kernel v×t  dilation  output     receptive field
=====  ============  ==========  ========  =========  ================
conv1  24            5×10        1×2       24×4×12    5×19
conv2  40            3×3         1×2       40×2×8     7×23
conv3  56            2×3         1×2       56×1×4     8×27
conv4  24            1×1         1×1       24×1×4     8×27
=====  ============  ==========  ========  =========  ================

The paper's text says conv1 has "dilation of one", but then its stated output (24×4×12) and receptive
field (5×19) are impossible: a 10-frame kernel without dilation gives 30-10+1 = 21 frames. A time
dilation of 2 (effective extent 19) gives 30-19+1 = 12 frames and the stated receptive fields, so that
is what is built. The paper also mentions "zero padding"; without padding every stated shape holds,
with any padding none does, so there is none.

Classifier: flatten 96 → dense 40 → dense 15 = 5×3 logits (32,863 parameters).
Regressor: flatten 96 ⊕ the 5 maneuver indices as numbers (0, 1, 2) = 101 → dense 40 → dense 10 =
5×2 normalised offsets (32,858 parameters). Total 65,721, the paper's figure.
``STCNNConfig(maneuver_input=False)`` is the regression-only ablation (96 → 40 → 10).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import torch
from torch import nn

from lanecast.io_adapters.contracts.windows import CHANNELS, HISTORY, HORIZONS, MANEUVERS, ROWS


@dataclass(frozen=True)
class STCNNConfig:
    """Everything that fixes the architecture (stored in the model card)."""

    channels: int = len(CHANNELS)
    vehicles: int = len(ROWS)
    history: int = HISTORY
    horizon: int = HORIZONS
    classes: int = len(MANEUVERS)
    conv_channels: tuple[int, ...] = (24, 40, 56, 24)
    conv_kernels: tuple[tuple[int, int], ...] = ((5, 10), (3, 3), (2, 3), (1, 1))
    conv_dilations: tuple[tuple[int, int], ...] = ((1, 2), (1, 2), (1, 2), (1, 1))
    hidden: int = 40
    negative_slope: float = 0.01
    maneuver_input: bool = True

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> STCNNConfig:
        """Inverse of ``to_dict`` (JSON lists become tuples); unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown STCNNConfig keys: {sorted(unknown)}")
        conv = {"conv_channels", "conv_kernels", "conv_dilations"}
        kw = {k: (_tuplify(v) if k in conv else v) for k, v in data.items()}
        config = cls(**kw)
        layer_shapes(config)  # ValueError where the kernels leave no output
        return config


def _tuplify(value: Any) -> Any:
    return tuple(_tuplify(v) for v in value) if isinstance(value, (list, tuple)) else value


def layer_shapes(config: STCNNConfig) -> list[tuple[str, tuple[int, int, int]]]:
    """Output shape (channels, vehicles, time) of every conv layer, computed from the kernel arithmetic."""
    v, t = config.vehicles, config.history
    out = []
    for i, (c, (kv, kt), (dv, dt)) in enumerate(
        zip(config.conv_channels, config.conv_kernels, config.conv_dilations, strict=True)
    ):
        v, t = v - dv * (kv - 1), t - dt * (kt - 1)
        if v < 1 or t < 1:
            raise ValueError(f"conv{i + 1} leaves no output ({v}×{t}): kernels too large for the input")
        out.append((f"conv{i + 1}", (c, v, t)))
    return out


def feature_size(config: STCNNConfig) -> int:
    """Length of the flattened conv output (96 for the paper's network)."""
    c, v, t = layer_shapes(config)[-1][1]
    return c * v * t


class ConvStack(nn.Sequential):
    """The four convolutions, each followed by leaky ReLU, then flatten: [N, 4, 8, 30] → [N, 96]."""

    def __init__(self, config: STCNNConfig) -> None:
        layers: list[nn.Module] = []
        c_in = config.channels
        for c_out, kernel, dilation in zip(
            config.conv_channels, config.conv_kernels, config.conv_dilations, strict=True
        ):
            layers += [nn.Conv2d(c_in, c_out, kernel, dilation=dilation), nn.LeakyReLU(config.negative_slope)]
            c_in = c_out
        layers.append(nn.Flatten())
        super().__init__(*layers)


class ManeuverClassifier(nn.Module):
    """Maneuver logits per future step: [N, 4, 8, 30] → [N, 5, 3]."""

    def __init__(self, config: STCNNConfig) -> None:
        super().__init__()
        self.config = config
        self.conv = ConvStack(config)
        self.fc1 = nn.Linear(feature_size(config), config.hidden)
        self.act = nn.LeakyReLU(config.negative_slope)
        self.fc2 = nn.Linear(config.hidden, config.horizon * config.classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.act(self.fc1(self.conv(x)))
        return self.fc2(h).view(-1, self.config.horizon, self.config.classes)


class TrajectoryRegressor(nn.Module):
    """Normalised offsets at the future steps given the maneuvers: ([N, 4, 8, 30], [N, 5]) → [N, 5, 2].

    The maneuver indices enter the first dense layer as plain numbers (0., 1., 2.), as in the paper;
    with ``maneuver_input=False`` they are ignored (regression-only ablation).
    """

    def __init__(self, config: STCNNConfig) -> None:
        super().__init__()
        self.config = config
        self.conv = ConvStack(config)
        extra = config.horizon if config.maneuver_input else 0
        self.fc1 = nn.Linear(feature_size(config) + extra, config.hidden)
        self.act = nn.LeakyReLU(config.negative_slope)
        self.fc2 = nn.Linear(config.hidden, config.horizon * 2)

    def head(self, features: torch.Tensor, maneuver: torch.Tensor | None) -> torch.Tensor:
        """Dense part: features [M, 96] (and maneuvers [M, 5]) → offsets [M, 5, 2]."""
        if self.config.maneuver_input:
            if maneuver is None:
                raise ValueError("this regressor needs the maneuver sequence as input")
            features = torch.cat([features, maneuver.to(features.dtype)], dim=1)
        return self.fc2(self.act(self.fc1(features))).view(-1, self.config.horizon, 2)

    def forward(self, x: torch.Tensor, maneuver: torch.Tensor | None) -> torch.Tensor:
        return self.head(self.conv(x), maneuver)


class STCNN(nn.Module):
    """Both networks; ``forward`` classifies, then regresses with the argmax maneuvers (inference)."""

    def __init__(self, config: STCNNConfig | None = None) -> None:
        super().__init__()
        self.config = config or STCNNConfig()
        self.classifier = ManeuverClassifier(self.config)
        self.regressor = TrajectoryRegressor(self.config)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x [N, 4, 8, 30] normalised → (logits [N, 5, 3], normalised offsets [N, 5, 2])."""
        logits = self.classifier(x)
        return logits, self.regressor(x, logits.argmax(dim=2))


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
