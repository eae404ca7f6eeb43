"""Bin targets, masked cross-entropy (paper eq. 3) and soft-argmin."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch

from roadbev_core.config import GridSpec
from roadbev_core.labels import one_hot, two_hot
from roadbev_core.models.loss import class_targets, masked_cross_entropy, soft_argmin

GRID = GridSpec()


@pytest.mark.parametrize(("label", "reference"), [("one_hot", one_hot), ("two_hot", two_hot)])
def test_targets_match_the_label_module(
    label: str, reference: Callable[[np.ndarray, GridSpec], np.ndarray]
) -> None:
    rng = np.random.default_rng(1)
    elev = rng.uniform(-0.25, 0.25, size=(2, 5, 4)).astype(np.float32)
    elev[0, 0, 0] = np.nan
    target, mask = class_targets(torch.from_numpy(elev), GRID, label)
    assert target.shape == (2, GRID.n_classes, 5, 4)
    assert not mask[0, 0, 0] and int(mask.sum()) == 39
    assert float(target[0, :, 0, 0].abs().sum()) == 0.0
    for b in range(2):
        expected = reference(elev[b], GRID)
        got = target[b].numpy()
        valid = np.isfinite(elev[b])
        np.testing.assert_allclose(got[:, valid], expected[:, valid], atol=1e-6)
    with pytest.raises(ValueError, match="two_hot"):
        class_targets(torch.zeros(1, 2, 2), GRID, "three_hot")


def test_soft_argmin_recovers_two_hot_elevation_and_its_spread() -> None:
    elev = torch.tensor([[[0.0123, -0.1577], [0.0, 0.19]]])
    target, _ = class_targets(elev, GRID, "two_hot")
    centres = torch.tensor(GRID.class_centres(), dtype=torch.float32)
    mean, std = soft_argmin(torch.log(target.clamp_min(1e-12)), centres)
    torch.testing.assert_close(mean, elev, atol=1e-5, rtol=0)
    assert float(std.max()) <= 0.5 * GRID.class_resolution + 1e-5
    sharp = torch.full((1, GRID.n_classes, 1, 1), -30.0)
    sharp[0, 10] = 30.0
    mean, std = soft_argmin(sharp, centres)
    assert abs(float(mean) - GRID.class_centres()[10]) < 1e-6 and float(std) < 1e-6
    flat_mean, flat_std = soft_argmin(torch.zeros(1, GRID.n_classes, 1, 1), centres)
    assert abs(float(flat_mean)) < 1e-6 and abs(float(flat_std) - 0.4 / np.sqrt(12)) < 1e-3  # uniform bins


def test_cross_entropy_counts_labelled_cells_only() -> None:
    torch.manual_seed(0)
    logits = torch.randn(1, GRID.n_classes, 3, 3)
    elev = torch.full((1, 3, 3), float("nan"))
    elev[0, 1, 1] = 0.05
    target, mask = class_targets(elev, GRID, "one_hot")
    loss = masked_cross_entropy(logits, target, mask)
    expected = -torch.log_softmax(logits[0, :, 1, 1], 0)[int((0.05 + 0.2) / 0.005)]
    torch.testing.assert_close(loss, expected)
    garbage = logits.clone()
    garbage[0, :, 0, 0] = 1e4  # unlabelled cells cannot change the loss
    torch.testing.assert_close(masked_cross_entropy(garbage, target, mask), loss)
    empty = torch.zeros_like(mask)
    assert float(masked_cross_entropy(logits, target, empty)) == 0.0
