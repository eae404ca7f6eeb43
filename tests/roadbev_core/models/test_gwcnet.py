"""GwcNet-lite: its 3-D convolution is a Conv3d's, the correlation volume and the soft argmin
compute what they say, and the network's shapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from roadbev_core.config import ConfigError
from roadbev_core.models.gwcnet import (
    GwcNetConfig,
    GwcNetLite,
    VolumeConv,
    VolumeNorm,
    group_correlation,
    shift_right,
    soft_argmin,
)


@pytest.mark.parametrize("stride", [1, 2])
def test_volume_conv_equals_conv3d_with_its_weights(stride: int) -> None:
    torch.manual_seed(0)
    reference = nn.Conv3d(4, 5, 3, stride, 1, bias=True)
    conv = VolumeConv(4, 5, stride, bias=True)
    conv.weight.data.copy_(reference.weight.data)
    assert conv.bias is not None and reference.bias is not None
    conv.bias.data.copy_(reference.bias.data)
    x = torch.randn(2, 4, 7, 9, 10)  # [B, C, D, H, W]
    got = conv(x.transpose(1, 2)).transpose(1, 2)  # the volume disparity-major and back
    torch.testing.assert_close(got, reference(x), atol=1e-5, rtol=1e-5)


def test_volume_norm_is_batchnorm3d_over_the_disparities() -> None:
    torch.manual_seed(1)
    x = torch.randn(2, 3, 4, 5, 6)  # [B, C, D, H, W]
    reference, norm = nn.BatchNorm3d(3).train(), VolumeNorm(3).train()
    got = norm(x.transpose(1, 2).contiguous()).transpose(1, 2)
    torch.testing.assert_close(got, reference(x), atol=1e-5, rtol=1e-5)


def test_group_correlation_matches_a_shifted_copy_at_its_disparity() -> None:
    torch.manual_seed(2)
    right = torch.randn(1, 8, 4, 20)
    left = torch.zeros_like(right)
    left[..., 3:] = right[..., :-3]  # left(u) = right(u - 3): disparity 3
    volume = group_correlation(left, right, groups=2, disparities=6)  # [B, D, G, h, w]
    assert volume.shape == (1, 6, 2, 4, 20)
    expected = (left.view(1, 2, 4, 4, 20) ** 2).mean(dim=2)  # self-correlation
    torch.testing.assert_close(volume[:, 3, :, :, 3:], expected[..., 3:])
    assert torch.all(volume[:, 5, :, :, :5] == 0)  # no right pixel left of the image
    torch.testing.assert_close(volume[:, 1, :, :, 1:], (left.view(1, 2, 4, 4, 20)[..., 1:]
                                                       * right.view(1, 2, 4, 4, 20)[..., :-1]).mean(dim=2))


def test_soft_argmin_of_a_peaked_cost_is_the_peak_with_a_small_spread() -> None:
    cost = torch.full((1, 10, 2, 2), -50.0)
    cost[:, 7] = 0.0
    disparity, sigma = soft_argmin(cost)
    torch.testing.assert_close(disparity, torch.full((1, 2, 2), 7.0))
    assert torch.all(sigma < 0.01)
    flat = soft_argmin(torch.zeros(1, 10, 1, 1))  # no preference: the middle, a wide spread
    assert float(flat[0]) == pytest.approx(4.5)
    assert float(flat[1]) == pytest.approx(np.sqrt((100 - 1) / 12.0), rel=1e-4)


def test_network_shapes_and_sides() -> None:
    torch.manual_seed(3)
    net = GwcNetLite(GwcNetConfig(max_disparity=16, features=16, groups=4, volume_channels=4)).eval()
    left = torch.randint(0, 255, (2, 3, 32, 48), dtype=torch.uint8)
    with torch.inference_mode():
        disparity, sigma = net(left, left)
    assert disparity.shape == sigma.shape == (2, 32, 48)
    assert torch.all((disparity >= 0) & (disparity <= 15)) and torch.all(sigma > 0)
    with pytest.raises(ValueError, match="multiples of 8"):
        net(left[..., :30], left[..., :30])


def test_config_is_checked_and_round_trips() -> None:
    config = GwcNetConfig(max_disparity=32)
    assert GwcNetConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ConfigError, match="multiple of 8"):
        GwcNetConfig(max_disparity=20)
    with pytest.raises(ConfigError, match="multiple of groups"):
        GwcNetConfig(features=30, groups=8)
    with pytest.raises(ConfigError, match="unknown"):
        GwcNetConfig.from_dict({"depth": 3})


def test_shift_right_puts_a_match_at_the_disparity_less_the_first() -> None:
    right = np.arange(20, dtype=np.uint8).reshape(1, 20)
    shifted = shift_right(right, 5)
    # a left pixel u matched at disparity 5 + k sees right(u - 5 - k) = shifted(u - k)
    u, k = 12, 2
    assert shifted[0, u - k] == right[0, u - 5 - k]
    assert np.all(shifted[0, :5] == 0)
    assert shift_right(right, 0) is right
