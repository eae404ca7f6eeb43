"""The BEV window mean shared by the sweep's cost aggregation and the models' photometric channel."""

from __future__ import annotations

import pytest
import torch

from roadbev_core.box_filter import box_mean, window_shape


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


def test_a_window_of_rows_and_columns_averages_that_rectangle() -> None:
    volume = torch.rand(4, 30, 20)
    tall = box_mean(volume, (7, 3))
    assert torch.allclose(tall[:, 10, 10], volume[:, 7:14, 9:12].mean(dim=(1, 2)), atol=1e-6)
    # At the border the window keeps the cells inside the grid: rows 0..3, columns 0..1.
    assert torch.allclose(tall[:, 0, 0], volume[:, 0:4, 0:2].mean(dim=(1, 2)), atol=1e-6)
    assert torch.allclose(box_mean(volume, (5, 5)), box_mean(volume, 5))
    assert torch.allclose(box_mean(volume.clone().requires_grad_(True), (7, 3)).detach(), tall, atol=1e-5)
    assert window_shape(9) == (9, 9) and window_shape([21, 9]) == (21, 9)
    for bad in ((4, 3), (3,), (3, 3, 3), 0, (True, 3), 2.0):
        with pytest.raises(ValueError, match="odd positive"):
            window_shape(bad)  # type: ignore[arg-type]


def test_box_mean_keeps_gradients_with_the_same_result() -> None:
    volume = torch.rand(3, 20, 12)
    leaf = volume.clone().requires_grad_(True)
    pooled = box_mean(leaf, 5)
    torch.testing.assert_close(pooled, box_mean(volume, 5), atol=1e-5, rtol=0)
    pooled.sum().backward()
    assert leaf.grad is not None and float(leaf.grad.abs().sum()) > 0
