"""The ST-CNN's architecture is the paper's: parameter count, every layer's output, receptive fields."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from lanecast.models.predict import FusedSTCNN, all_sequences, top_k_sequences
from lanecast.models.stcnn import STCNN, STCNNConfig, count_parameters, feature_size, layer_shapes

PAPER_SHAPES = [(24, 4, 12), (40, 2, 8), (56, 1, 4), (24, 1, 4)]


def test_parameter_count_is_the_papers() -> None:
    model = STCNN()
    assert count_parameters(model.classifier) == 32_863
    assert count_parameters(model.regressor) == 32_858
    assert count_parameters(model) == 65_721
    # by hand: convs 24·(4·5·10)+24 + 40·(24·3·3)+40 + 56·(40·2·3)+56 + 24·56+24 = 28,368
    assert count_parameters(model.classifier.conv) == 28_368 == count_parameters(model.regressor.conv)


def test_every_layer_output_shape() -> None:
    model = STCNN()
    seen: list[tuple[str, tuple[int, ...]]] = []
    for net_name, net in (("classifier", model.classifier), ("regressor", model.regressor)):
        convs = [m for m in net.conv if isinstance(m, nn.Conv2d)]
        for i, conv in enumerate(convs):
            conv.register_forward_hook(
                lambda _m, _i, out, n=f"{net_name}.conv{i + 1}": seen.append((n, tuple(out.shape)))
            )
        for name in ("fc1", "fc2"):
            getattr(net, name).register_forward_hook(
                lambda _m, _i, out, n=f"{net_name}.{name}": seen.append((n, tuple(out.shape)))
            )
    logits, offsets = model(torch.zeros(2, 4, 8, 30))
    shapes = dict(seen)
    for net_name in ("classifier", "regressor"):
        assert [shapes[f"{net_name}.conv{i}"][1:] for i in range(1, 5)] == PAPER_SHAPES
    assert shapes["classifier.fc1"] == (2, 40) and shapes["classifier.fc2"] == (2, 15)
    assert shapes["regressor.fc1"] == (2, 40) and shapes["regressor.fc2"] == (2, 10)
    assert model.classifier.fc1.in_features == 96 and model.regressor.fc1.in_features == 101
    assert logits.shape == (2, 5, 3) and offsets.shape == (2, 5, 2)
    assert [s for _, s in layer_shapes(STCNNConfig())] == PAPER_SHAPES
    assert feature_size(STCNNConfig()) == 96


def _receptive_field(model: STCNN, upto: int) -> tuple[int, int]:
    """(vehicles, frames) of the input that influence output (0, 0) of conv ``upto`` (by autograd)."""
    torch.manual_seed(0)
    x = torch.randn(1, 4, 8, 30, requires_grad=True)
    h = x
    convs = [m for m in model.classifier.conv if isinstance(m, nn.Conv2d)][:upto]
    for conv in convs:
        h = nn.functional.leaky_relu(conv(h), 0.01)
    h[0, :, 0, 0].sum().backward()
    assert x.grad is not None
    touched = x.grad.abs().sum(dim=(0, 1)) > 0  # [8, 30]
    rows, cols = np.flatnonzero(touched.any(1)), np.flatnonzero(touched.any(0))
    return int(rows[-1] - rows[0] + 1), int(cols[-1] - cols[0] + 1)


def test_receptive_fields_are_the_papers() -> None:
    model = STCNN()
    assert _receptive_field(model, 1) == (5, 19)  # conv1's time dilation 2: 10 taps over 19 frames
    assert _receptive_field(model, 4) == (8, 27)


def test_leaky_relu_after_every_layer_but_the_last() -> None:
    net = STCNN().classifier
    kinds = [type(m).__name__ for m in net.conv]
    assert kinds == ["Conv2d", "LeakyReLU"] * 4 + ["Flatten"]
    assert all(m.bias is not None for m in net.modules() if isinstance(m, (nn.Conv2d, nn.Linear)))
    # the last dense layer is linear: scaling its input features scales the logits' offset from the bias
    with torch.no_grad():
        h = torch.randn(3, 40)
        out = net.fc2(h) - net.fc2.bias
        np.testing.assert_allclose((net.fc2(-h) - net.fc2.bias).numpy(), -out.numpy(), atol=1e-6)


def test_regressor_uses_the_maneuvers_and_the_ablation_does_not() -> None:
    torch.manual_seed(0)
    x = torch.randn(4, 4, 8, 30)
    straight, left = torch.zeros(4, 5, dtype=torch.int64), torch.ones(4, 5, dtype=torch.int64)
    full = STCNN()
    assert not torch.allclose(full.regressor(x, straight), full.regressor(x, left))
    ablation = STCNN(STCNNConfig(maneuver_input=False))
    assert count_parameters(ablation.regressor) == 32_858 - 5 * 40
    assert torch.equal(ablation.regressor(x, straight), ablation.regressor(x, left))
    with pytest.raises(ValueError, match="maneuver"):
        full.regressor(x, None)


def test_config_round_trip_through_json_lists() -> None:
    cfg = STCNNConfig(maneuver_input=False)
    as_json = {
        k: (list(map(list, v)) if k in ("conv_kernels", "conv_dilations") else v)
        for k, v in cfg.to_dict().items()
    }
    assert STCNNConfig.from_dict(as_json) == cfg
    with pytest.raises(ValueError, match="unknown"):
        STCNNConfig.from_dict({"layers": 5})


def test_fused_inference_equals_the_two_networks() -> None:
    torch.manual_seed(1)
    model = STCNN().eval()
    x = torch.randn(50, 4, 8, 30)
    logits, features = FusedSTCNN(model)(x)
    torch.testing.assert_close(logits, model.classifier(x), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(features, model.regressor.conv(x), atol=1e-5, rtol=1e-5)


def test_top_k_sequences_by_hand() -> None:
    probs = torch.tensor(
        [[[0.6, 0.3, 0.1], [0.9, 0.1, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.5, 0.0]]]
    )
    seqs, p = top_k_sequences(probs.clamp_min(1e-12).log(), 3, all_sequences())
    # 0.6·0.9·0.5 = 0.27 twice (last step straight or left), then 0.3·0.9·0.5 = 0.135 twice
    np.testing.assert_allclose(p[0].numpy(), [0.27, 0.27, 0.135], rtol=1e-5)
    assert {tuple(s) for s in seqs[0, :2].tolist()} == {(0, 0, 0, 0, 0), (0, 0, 0, 0, 1)}
    assert seqs[0, 2, :2].tolist() == [1, 0]
    assert all_sequences().shape == (243, 5)
