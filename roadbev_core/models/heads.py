"""Elevation heads: a reduced EfficientNet-B0 2-D head (mono) and a 3-D hourglass head (stereo)."""

from __future__ import annotations

from typing import cast

import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.models.efficientnet import ConvBnAct, MBConv

__all__ = ["Hourglass3d", "MonoHead", "StereoHead"]


class MonoHead(nn.Module):
    """BEV features [B, C*Nz, Ny, Nx] -> class logits [B, Nc, Ny, Nx] (reduced EfficientNet-B0).

    A 1x1 stem, two MBConv blocks at full BEV resolution, two at half resolution (wider), an
    upsampling skip back to full resolution, and a 3x3 classifier.
    """

    def __init__(self, in_channels: int, width: int, n_classes: int) -> None:
        super().__init__()
        self.stem = ConvBnAct(in_channels, width, 1)
        self.full = nn.Sequential(MBConv(width, width, 3, 1, 4), MBConv(width, width, 3, 1, 4))
        self.coarse = nn.Sequential(MBConv(width, 2 * width, 3, 2, 4), MBConv(2 * width, 2 * width, 3, 1, 4))
        self.up = ConvBnAct(2 * width, width, 1)
        self.classify = nn.Conv2d(width, n_classes, 3, padding=1)

    def forward(self, bev: torch.Tensor) -> torch.Tensor:
        full = self.full(self.stem(bev))  # [B, W, Ny, Nx]
        coarse = self.coarse(full)  # [B, 2W, Ny/2, Nx/2]
        up = F.interpolate(coarse, size=full.shape[-2:], mode="bilinear", align_corners=False)
        return cast("torch.Tensor", self.classify(full + self.up(up)))  # [B, Nc, Ny, Nx]


def _conv3d(c_in: int, c_out: int, stride: int = 1) -> ConvBnAct:
    return ConvBnAct(c_in, c_out, 3, stride, act="relu", dims=3)


class Hourglass3d(nn.Module):
    """Two stride-2 reductions and back, with skips (PSMNet-style, trilinear upsampling)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        wide = 2 * channels
        self.down1 = nn.Sequential(_conv3d(channels, wide, 2), _conv3d(wide, wide))
        self.down2 = nn.Sequential(_conv3d(wide, wide, 2), _conv3d(wide, wide))
        self.up2 = ConvBnAct(wide, wide, 3, act=None, dims=3)
        self.up1 = ConvBnAct(wide, channels, 3, act=None, dims=3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        d1 = self.down1(x)  # [B, 2C, Nz/2, Ny/2, Nx/2]
        d2 = self.down2(d1)  # [B, 2C, Nz/4, Ny/4, Nx/4]
        u2 = F.relu(d1 + self.up2(F.interpolate(d2, size=d1.shape[-3:], mode="trilinear", align_corners=False)))
        return F.relu(x + self.up1(F.interpolate(u2, size=x.shape[-3:], mode="trilinear", align_corners=False)))


class StereoHead(nn.Module):
    """Cost volume [B, C, Nz, Ny, Nx] -> occupancy score [B, Nz, Ny, Nx].

    Six 3-D conv layers (an entry pair C -> W, then two residual pairs at width W), three stacked
    hourglass modules with stride-2 reductions, and two convs down to one channel.
    """

    def __init__(self, channels: int, width: int) -> None:
        super().__init__()
        self.entry = nn.Sequential(_conv3d(channels, width), _conv3d(width, width))
        self.residual = nn.ModuleList(
            nn.Sequential(_conv3d(width, width), ConvBnAct(width, width, 3, act=None, dims=3)) for _ in range(2)
        )
        self.hourglasses = nn.ModuleList(Hourglass3d(width) for _ in range(3))
        self.out = nn.Sequential(_conv3d(width, width), nn.Conv3d(width, 1, 3, padding=1))

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        x = self.entry(volume)  # [B, W, Nz, Ny, Nx]
        for pair in self.residual:
            x = F.relu(x + pair(x))
        for hourglass in self.hourglasses:
            x = hourglass(x)
        return cast("torch.Tensor", self.out(x)[:, 0])  # [B, Nz, Ny, Nx]
