"""Feature pyramid fusion: multi-scale backbone maps -> one C-channel map at a chosen stride.

As the paper: the 1/2-1/16 maps are interpolated to the target resolution (1/2 for stereo, 1/4 for
mono), concatenated along channels and fused by convolutions into C channels. Each level is first
reduced to C channels by a 1x1 conv at its own resolution, which keeps the fusion at 1/2
resolution cheap on a CPU (a 3x3 conv over all the concatenated backbone channels is not).
"""

from __future__ import annotations

from typing import cast

import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.models.efficientnet import ConvBnAct

__all__ = ["PyramidFusion"]


class PyramidFusion(nn.Module):
    """Reduce every pyramid level to C, resize to ``stride``, concatenate, fuse to ``channels``."""

    def __init__(self, in_channels: list[int], in_strides: list[int], channels: int, stride: int) -> None:
        super().__init__()
        self.in_strides = list(in_strides)
        self.stride = stride
        self.lateral = nn.ModuleList(ConvBnAct(c, channels, 1, act="relu") for c in in_channels)
        self.mix = ConvBnAct(channels * len(in_channels), channels, 1, act="relu")
        self.out = nn.Conv2d(channels, channels, 3, padding=1)

    def forward(self, features: list[torch.Tensor], image_size: tuple[int, int]) -> torch.Tensor:
        """features[i]: [B, C_i, ~H/s_i, ~W/s_i]; image_size (H, W) -> [B, C, ceil(H/s), ceil(W/s)]."""
        h, w = image_size
        size = (-(-h // self.stride), -(-w // self.stride))
        resized = []
        for lateral, f in zip(self.lateral, features, strict=True):
            f = lateral(f)  # [B, C, H/s_i, W/s_i]
            if f.shape[-2:] != size:
                f = F.interpolate(f, size=size, mode="bilinear", align_corners=False)
            resized.append(f)
        return cast("torch.Tensor", self.out(self.mix(torch.cat(resized, dim=1))))  # [B, C, H/s, W/s]
