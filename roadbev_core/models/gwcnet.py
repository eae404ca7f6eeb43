"""GwcNet-lite: a learned image-view stereo matcher, the paper's Table I image-view class.

Follows Guo et al., "Group-wise Correlation Stereo Network" (GwcNet, CVPR 2019), scaled to the
size of the project's ``lite`` RoadBEV models:

* a shared 2-D feature extractor, 1/4 of the input resolution (residual blocks);
* the group-wise correlation cost volume: the features split into ``groups`` groups, each
  correlated (mean product) between the left pixel and the right pixel ``d`` to its left, for
  every disparity ``d`` of the search at 1/4 resolution;
* 3-D aggregation: two 3-D convolutions and one hourglass (encoder-decoder with a skip);
* the cost upsampled to the input's disparities, a softmax over them and the soft argmin (the
  expected disparity, GC-Net's regression), with the distribution's spread about it as the
  match's own 1-sigma, both upsampled bilinearly to the input's pixels. (GwcNet upsamples the
  cost to the input's pixels first; on a CPU that and the softmax over it cost as much as the
  rest of the network.)

The search covers ``max_disparity`` disparities from ``min_disparity`` (an input, per frame:
the image-view backends search only the disparities the grid's volume can produce), by
comparing the left image with the right one shifted ``min_disparity`` pixels (the caller's job:
:func:`shift_right`). Images are RGB, ``uint8`` scaled to [-1, 1] inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.config import ConfigError
from roadbev_core.models.settings import StoredSettings

__all__ = ["GwcNetConfig", "GwcNetLite", "VolumeConv", "VolumeNorm", "group_correlation", "shift_right", "soft_argmin"]


@dataclass(frozen=True)
class GwcNetConfig(StoredSettings):
    """What defines a GwcNet-lite network (stored in its checkpoint).

    Attributes:
        max_disparity: disparities searched (input pixels), a multiple of 4 * 2 (the volume is
            at 1/4 and its hourglass halves it once more); the grid's volume spans 48 on the RSRD
            half rig, and the soft argmin is biased next to either end of its range.
        features: channels of the 1/4-resolution features (``groups`` x channels per group).
        groups: correlation groups (the cost volume's channels).
        volume_channels: width of the 3-D aggregation.
    """

    SETTINGS: ClassVar[str] = "GwcNet"

    max_disparity: int = 56
    features: int = 64
    groups: int = 8
    volume_channels: int = 8

    def __post_init__(self) -> None:
        if self.max_disparity < 8 or self.max_disparity % 8:
            raise ConfigError(f"max_disparity must be a positive multiple of 8, got {self.max_disparity}")
        if self.groups < 1 or self.features % self.groups:
            raise ConfigError(f"features ({self.features}) must be a multiple of groups ({self.groups})")
        if self.volume_channels < 1:
            raise ConfigError(f"volume_channels must be >= 1, got {self.volume_channels}")


def _conv_bn(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class VolumeConv(nn.Module):
    """A 3 x 3 x 3 convolution over a cost volume, computed as the sum of three 2-D convolutions,
    one per disparity tap (padding 1 on every axis, the same stride on every axis).

    The function and the weights [C_out, C_in, 3, 3, 3] are a :class:`torch.nn.Conv3d`'s; the
    volume is kept disparity-major, [B, D, C, H, W], so that every disparity plane is an image
    for the 2-D kernels, which run several times faster on a CPU than torch's 3-D ones.
    """

    def __init__(self, cin: int, cout: int, stride: int = 1, bias: bool = False) -> None:
        super().__init__()
        reference = nn.Conv3d(cin, cout, 3, stride, 1, bias=bias)  # its initialisation
        self.weight = nn.Parameter(reference.weight.detach().clone())
        self.bias = nn.Parameter(reference.bias.detach().clone()) if bias and reference.bias is not None else None
        self.stride = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """[B, D, C_in, H, W] -> [B, D', C_out, H', W'] (D' = ceil(D / stride), likewise H', W')."""
        b, d, c, h, w = x.shape
        s = self.stride
        d_out = (d - 1) // s + 1
        padded = F.pad(x, (0, 0, 0, 0, 0, 0, 1, 1))  # [B, D + 2, C, H, W]
        out: torch.Tensor | None = None
        for tap in range(3):
            planes = padded[:, tap: tap + s * (d_out - 1) + 1: s].reshape(b * d_out, c, h, w)
            y = F.conv2d(planes, self.weight[:, :, tap], None, s, 1)  # [B * D', C_out, H', W']
            out = y if out is None else out + y
        assert out is not None
        if self.bias is not None:
            out = out + self.bias.view(1, -1, 1, 1)
        return out.view(b, d_out, out.shape[1], out.shape[2], out.shape[3])


class VolumeNorm(nn.Module):
    """BatchNorm3d of a disparity-major volume [B, D, C, H, W]: a BatchNorm2d of its planes
    (the same per-channel statistics, over B, D, H and W)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.norm = nn.BatchNorm2d(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, d, c, h, w = x.shape
        return self.norm(x.reshape(b * d, c, h, w)).view(b, d, c, h, w)  # type: ignore[no-any-return]


def _conv3d_bn(cin: int, cout: int, stride: int = 1, relu: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = [VolumeConv(cin, cout, stride), VolumeNorm(cout)]
    if relu:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class _Residual(nn.Module):
    """A 2-D basic residual block (PSMNet / GwcNet's feature extractor)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(_conv_bn(channels, channels), nn.Conv2d(channels, channels, 3, 1, 1, bias=False),
                                  nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class _Features(nn.Module):
    """[B, 3, H, W] -> [B, features, H/4, W/4]."""

    def __init__(self, features: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            _conv_bn(3, 16, 2), _conv_bn(16, 16), _Residual(16),  # 1/2
            _conv_bn(16, 32, 2), _Residual(32), _Residual(32),  # 1/4
            nn.Conv2d(32, features, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)  # type: ignore[no-any-return]


class _Hourglass(nn.Module):
    """[B, D, C, H, W] -> same: down to 1/2 on every axis and back, with a skip (one of GwcNet's
    stacked hourglasses; the way up is a trilinear upsampling and a 3-D convolution)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.down = nn.Sequential(_conv3d_bn(channels, 2 * channels, 2), _conv3d_bn(2 * channels, 2 * channels))
        self.up = _conv3d_bn(2 * channels, channels, relu=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.down(x)  # [B, D/2, 2C, H/2, W/2]
        size = (x.shape[1], x.shape[3], x.shape[4])
        y = F.interpolate(y.transpose(1, 2), size=size, mode="trilinear", align_corners=False).transpose(1, 2)
        return F.relu(self.up(y.contiguous()) + x)


def group_correlation(left: torch.Tensor, right: torch.Tensor, groups: int, disparities: int) -> torch.Tensor:
    """The group-wise correlation volume of GwcNet.

    Args:
        left, right: [B, C, h, w] features (C a multiple of ``groups``).
        disparities: D, the disparities of the volume (in feature pixels).

    Returns:
        [B, D, groups, h, w] (disparity-major, as :class:`VolumeConv` takes it): for disparity d,
        the mean over each group's channels of left(u) * right(u - d); zero where u - d < 0.
    """
    b, c, h, w = left.shape
    lg = left.view(b, groups, c // groups, h, w)
    rg = right.view(b, groups, c // groups, h, w)
    planes = []
    for d in range(disparities):
        shifted = F.pad(rg[..., : w - d], (d, 0)) if 0 < d < w else (rg if d == 0 else torch.zeros_like(rg))
        planes.append((lg * shifted).mean(dim=2))  # [B, G, h, w]; zero where u < d (padded)
    return torch.stack(planes, dim=1)


def soft_argmin(cost: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected disparity and spread of a cost volume [B, D, H, W] (higher = better match).

    Returns:
        disparity [B, H, W] and its 1-sigma [B, H, W], both in disparity steps from 0.
    """
    prob = torch.softmax(cost, dim=1)  # [B, D, H, W]
    steps = torch.arange(cost.shape[1], dtype=cost.dtype, device=cost.device).view(1, -1, 1, 1)
    mean = (prob * steps).sum(dim=1)
    variance = (prob * (steps - mean.unsqueeze(1)) ** 2).sum(dim=1)
    return mean, torch.sqrt(variance.clamp_min(1e-6))


class GwcNetLite(nn.Module):
    """Group-wise correlation stereo (see the module docstring)."""

    # the input's sides must be multiples of this (features at 1/4, the hourglass halves again)
    stride = 8

    def __init__(self, config: GwcNetConfig | None = None) -> None:
        super().__init__()
        self.config = config or GwcNetConfig()
        c = self.config
        self.features = _Features(c.features)
        v = c.volume_channels
        self.entry = nn.Sequential(_conv3d_bn(c.groups, v), _conv3d_bn(v, v))
        self.hourglass = _Hourglass(v)
        self.classify = nn.Sequential(_conv3d_bn(v, v), VolumeConv(v, 1, bias=True))

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Disparity and its 1-sigma (input pixels, from 0 at the shifted right image).

        Args:
            left, right: [B, 3, H, W] uint8 or float in [0, 255] (H, W multiples of :attr:`stride`);
                ``right`` already shifted by the search's first disparity.

        Returns:
            disparity [B, H, W] and sigma [B, H, W] (float32, pixels).
        """
        b, _, h, w = left.shape
        if h % self.stride or w % self.stride:
            raise ValueError(f"GwcNet-lite needs sides that are multiples of {self.stride}, got {h} x {w}")
        both = torch.cat([left, right], dim=0).float() * (2.0 / 255.0) - 1.0  # [2B, 3, H, W]
        feats = self.features(both)  # [2B, F, H/4, W/4]
        d4 = self.config.max_disparity // 4
        volume = group_correlation(feats[:b], feats[b:], self.config.groups, d4)  # [B, D/4, G, H/4, W/4]
        x = self.entry(volume)
        x = self.hourglass(x)
        cost = self.classify(x)  # [B, D/4, 1, H/4, W/4]
        h4, w4 = cost.shape[-2:]
        cost = F.interpolate(cost.transpose(1, 2), size=(self.config.max_disparity, h4, w4), mode="trilinear",
                             align_corners=False)  # [B, 1, D, H/4, W/4]
        disparity, sigma = soft_argmin(cost[:, 0])  # [B, H/4, W/4] each
        both = F.interpolate(torch.stack([disparity, sigma], dim=1), size=(h, w), mode="bilinear",
                             align_corners=False)  # [B, 2, H, W]
        return both[:, 0], both[:, 1]


def shift_right(right: np.ndarray, min_disparity: int) -> np.ndarray:
    """[H, W, ...] the right image moved ``min_disparity`` pixels to the right (zeros enter at the
    left), so that a match at disparity ``min_disparity + k`` lies at ``k`` in it."""
    if min_disparity <= 0:
        return right
    out = np.zeros_like(right)
    out[:, min_disparity:] = right[:, :-min_disparity]
    return out
