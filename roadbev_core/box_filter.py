"""Window means over the BEV plane of a stack of maps (the cost-aggregation filter)."""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["box_mean"]

_BOX_CHANNELS = 32  # cv2 filters images of at most a few dozen channels at once


def box_mean(volume: torch.Tensor, size: int) -> torch.Tensor:
    """Mean over a ``size`` x ``size`` window (odd, centred) of the last two axes of [K, R, C] float32.

    Windows shrink at the borders (the mean over the cells inside the grid). OpenCV's box filter
    (running sums, SIMD) costs the same for any window size and is 5-20x faster than pooling on a
    CPU; tensors on another device or that need gradients take torch's pooling (same result).
    ``size`` 1 returns ``volume`` itself.
    """
    if size == 1:
        return volume
    if size < 1 or size % 2 == 0:
        raise ValueError(f"the window must be odd and positive (centred), got {size}")
    if volume.device.type != "cpu" or volume.requires_grad:
        pooled = F.avg_pool2d(volume[:, None], size, stride=1, padding=size // 2, count_include_pad=False)
        return pooled[:, 0]
    n_k, n_rows, n_cols = volume.shape
    planes = np.ascontiguousarray(volume.permute(1, 2, 0).numpy())  # [R, C, K] channels last
    sums = np.empty_like(planes)
    for start in range(0, n_k, _BOX_CHANNELS):
        chunk = np.ascontiguousarray(planes[:, :, start : start + _BOX_CHANNELS])
        out = cv2.boxFilter(chunk, -1, (size, size), normalize=False, borderType=cv2.BORDER_CONSTANT)
        sums[:, :, start : start + _BOX_CHANNELS] = out.reshape(n_rows, n_cols, -1)
    ones = np.ones((n_rows, n_cols), np.float32)
    count = cv2.boxFilter(ones, -1, (size, size), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return torch.from_numpy(sums / count[:, :, None]).permute(2, 0, 1)
