"""Window means over the BEV plane of a stack of maps (the cost-aggregation filter)."""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["WindowSize", "box_mean", "window_shape"]

_BOX_CHANNELS = 32  # cv2 filters images of at most a few dozen channels at once

WindowSize = int | tuple[int, int]
"""A window's side in cells (square), or its (rows, columns)."""


def window_shape(size: WindowSize | list[int]) -> tuple[int, int]:
    """(rows, columns) of a window given as one side or a pair (a list from YAML too); odd, positive.

    Raises:
        ValueError: not an odd positive integer or a pair of them.
    """
    pair = tuple(size) if isinstance(size, (tuple, list)) else (size, size)
    if len(pair) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 and v % 2 for v in pair):
        raise ValueError(f"a window is an odd positive integer or a pair (rows, columns) of them, got {size!r}")
    return pair[0], pair[1]


def box_mean(volume: torch.Tensor, size: WindowSize) -> torch.Tensor:
    """Mean over a centred window of the last two axes of [K, R, C] float32.

    Args:
        volume: [K, R, C] maps.
        size: the window, odd: one side (square) or (rows, columns).

    Windows shrink at the borders (the mean over the cells inside the grid). OpenCV's box filter
    (running sums, SIMD) costs the same for any window size and is many times faster than pooling
    on a CPU; tensors on another device, that need gradients or that an ONNX export traces take
    torch's pooling (same result).
    A 1 x 1 window returns ``volume`` itself.
    """
    rows, cols = window_shape(size)
    if rows == cols == 1:
        return volume
    if volume.device.type != "cpu" or volume.requires_grad or torch.jit.is_tracing():  # (ONNX export)
        pooled = F.avg_pool2d(
            volume[:, None], (rows, cols), stride=1, padding=(rows // 2, cols // 2), count_include_pad=False
        )
        return pooled[:, 0]
    n_k, n_rows, n_cols = volume.shape
    planes = np.ascontiguousarray(volume.permute(1, 2, 0).numpy())  # [R, C, K] channels last
    sums = np.empty_like(planes)
    for start in range(0, n_k, _BOX_CHANNELS):
        chunk = np.ascontiguousarray(planes[:, :, start : start + _BOX_CHANNELS])
        out = cv2.boxFilter(chunk, -1, (cols, rows), normalize=False, borderType=cv2.BORDER_CONSTANT)
        sums[:, :, start : start + _BOX_CHANNELS] = out.reshape(n_rows, n_cols, -1)
    ones = np.ones((n_rows, n_cols), np.float32)
    count = cv2.boxFilter(ones, -1, (cols, rows), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return torch.from_numpy(sums / count[:, :, None]).permute(2, 0, 1)
