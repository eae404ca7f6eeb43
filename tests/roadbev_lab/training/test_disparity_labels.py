"""Disparity labels: a ray meets a labelled plane where geometry says, and the first surface it meets."""

from __future__ import annotations

import math

import numpy as np

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, ray_terms
from roadbev_lab.training.disparity_labels import surface_depth, surface_height

CAMERA = StereoCamera.rsrd_half()
GRID = GridSpec()
ATTITUDE = Attitude(0.01, math.radians(16.0))
ROWS, COLS = np.arange(100, 520, 7), np.arange(0, 960, 11)


def _plane(height: float, grade: float = 0.0, cross: float = 0.0) -> np.ndarray:
    """[n_rows, n_cols] label of the plane z = height + grade x + cross y at the cell centres."""
    x, y = GRID.x_centres(), GRID.y_centres()
    return (height + grade * x[:, None] + cross * y[None, :]).astype(np.float32)


def test_rays_meet_a_labelled_plane_where_it_is() -> None:
    height, grade, cross = 0.03, 0.01, -0.015
    depth = surface_depth(_plane(height, grade, cross), GRID, CAMERA, ATTITUDE, ROWS, COLS)  # [h, w]
    ray = ray_terms(CAMERA, ATTITUDE, ROWS, COLS).rays()  # [h, w, 3]
    # analytic: h + Z r_z = height + grade Z r_x + cross Z r_y
    exact = (height - GRID.base_height) / (ray[..., 2] - grade * ray[..., 0] - cross * ray[..., 1])
    x, y = exact * ray[..., 0], exact * ray[..., 1]
    # inside the grid by more than a cell's half (the label's outer centres) the ray meets it
    inner = ((x > GRID.x_min + GRID.resolution) & (x < GRID.x_max - GRID.resolution)
             & (y > GRID.y_min + GRID.resolution) & (y < GRID.y_max - GRID.resolution))
    assert inner.sum() > 1000
    np.testing.assert_allclose(depth[inner], exact[inner], rtol=1e-4)
    outside = (x < GRID.x_min - 0.05) | (x > GRID.x_max + 0.05) | (y < GRID.y_min - 0.05) | (y > GRID.y_max + 0.05)
    assert outside.any() and np.all(np.isnan(depth[outside]))


def test_a_bump_hides_the_road_behind_it() -> None:
    label = _plane(0.0)
    rows_bump = (GRID.x_centres() > 4.0) & (GRID.x_centres() < 4.3)
    label[rows_bump, :] = 0.15  # a 15 cm step across the road, 30 cm long
    col = np.array([480])
    rows = np.arange(200, 520)
    depth = surface_depth(label, GRID, CAMERA, ATTITUDE, rows, col)[:, 0]
    ray = ray_terms(CAMERA, ATTITUDE, rows, col).rays()[:, 0]
    x = depth * ray[:, 0]
    ok = np.isfinite(x)
    # no ray lands on the road just behind the bump: it meets the bump's front or top first
    shadow_start = 4.3
    shadow_end = 4.3 + 0.15 * 4.3 / (GRID.base_height - 0.15)  # where the bump's back edge's shadow ends
    assert not np.any((x[ok] > shadow_start + 0.02) & (x[ok] < shadow_end - 0.05))
    on_bump = ok & (x > 4.02) & (x < 4.26)  # the top, between its outer cell centres
    assert on_bump.sum() > 5
    np.testing.assert_allclose(GRID.base_height + depth[on_bump] * ray[on_bump, 2], 0.15, atol=2e-3)


def test_surface_height_interpolates_between_centres_and_is_nan_outside() -> None:
    label = _plane(0.0, grade=0.02)
    x = np.array([GRID.x_centres()[10], 0.5 * (GRID.x_centres()[10] + GRID.x_centres()[11]), GRID.x_max + 0.1])
    y = np.zeros(3)
    got = surface_height(label, GRID, x, y)
    np.testing.assert_allclose(got[:2], 0.02 * x[:2], atol=1e-6)
    assert np.isnan(got[2])
