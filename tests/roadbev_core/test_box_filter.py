"""The BEV window mean shared by the sweep's cost aggregation and the models' photometric channel."""

from __future__ import annotations

import pytest
import torch

from roadbev_core.box_filter import box_mean


def test_box_mean_is_the_mean_over_the_cells_inside_the_grid() -> None:
    volume = torch.rand(40, 82, 32) * 2.0 - 1.0
    for size in (3, 15, 25):
        reference = torch.nn.functional.avg_pool2d(
            volume[:, None], size, stride=1, padding=size // 2, count_include_pad=False
        )[:, 0]
        assert torch.allclose(box_mean(volume, size), reference, atol=1e-5)
    assert box_mean(volume, 1) is volume
    with pytest.raises(ValueError, match="odd"):
        box_mean(volume, 4)


def test_box_mean_keeps_gradients_with_the_same_result() -> None:
    volume = torch.rand(3, 20, 12)
    leaf = volume.clone().requires_grad_(True)
    pooled = box_mean(leaf, 5)
    torch.testing.assert_close(pooled, box_mean(volume, 5), atol=1e-5, rtol=0)
    pooled.sum().backward()
    assert leaf.grad is not None and float(leaf.grad.abs().sum()) > 0
