from __future__ import annotations

import cv2
import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.visibility import SAMPLES, _rays, fill_holes, fit_road_plane, hidden_cells, line_of_sight
from roadbev_lab.synth.heightfield import SpeedBump

GRID = GridSpec()
CAMERAS = (0.0, -0.12)


def bump_road(height: float, x_centre: float, length: float = 0.5) -> np.ndarray:
    """[R, C] a flat road with a parabolic speed bump across the whole grid (roadbev_lab.synth)."""
    bump = SpeedBump(x=x_centre, y=0.0, length=length, height=height, width=10.0, profile="parabolic")
    profile = bump.along(GRID.x_centres() - x_centre).astype(np.float32)  # [R]
    return np.repeat(profile[:, None], GRID.n_cols, axis=1)


def exact_clearance(height: float, x_centre: float, length: float) -> np.ndarray:
    """[R] the least clearance ratio of each row's line of sight over the true (y-invariant) bump
    profile, densely sampled (1 mm) up to 1.5 cells before the cell: < 0 is strictly hidden."""
    bump = SpeedBump(x=x_centre, y=0.0, length=length, height=height, width=10.0, profile="parabolic")
    H = GRID.base_height
    out = []
    for x in GRID.x_centres():
        xs = np.arange(GRID.x_min, x - 1.5 * GRID.resolution, 0.001)
        if xs.size == 0:
            out.append(np.inf)
            continue
        target = float(bump.along(np.array([x - x_centre]))[0])
        f = xs / x
        ray = H + f * (target - H)
        out.append(float(np.min((ray - bump.along(xs - x_centre)) / ((H - target) * (1 - f)))))
    return np.array(out)


def test_flat_and_gently_sloped_roads_hide_nothing() -> None:
    x = GRID.x_centres()[:, None]
    y = GRID.y_centres()[None, :]
    for road in (np.zeros(GRID.shape, np.float32), (0.01 * x - 0.03 * y - 0.02).astype(np.float32)):
        assert not hidden_cells(road, GRID, CAMERAS).any()


@pytest.mark.parametrize("height", [0.04, 0.07, 0.10])
@pytest.mark.parametrize("x_centre", [3.5, 5.0, 6.3])
def test_the_strip_behind_a_bump_is_hidden_and_nothing_in_front(height: float, x_centre: float) -> None:
    length = 0.3
    truth = bump_road(height, x_centre, length)
    hidden = hidden_cells(truth, GRID, CAMERAS)
    x = GRID.x_centres()
    exact = exact_clearance(height, x_centre, length)  # [R]
    # nothing in front of the crest (the road, the front slope, the crest itself) is hidden
    assert not hidden[x <= x_centre].any()
    # every row strictly hidden is flagged (all columns: the bump spans the grid) ...
    assert (exact < 0).any() or height < 0.05  # a low bump near the camera hides nothing
    assert hidden[exact < 0].all(), x[(exact < 0) & ~hidden.all(axis=1)]
    # ... and no row seen with a clear line of sight is
    assert not hidden[exact > 0.5].any(), x[(exact > 0.5) & hidden.any(axis=1)]


def test_higher_and_farther_bumps_hide_more() -> None:
    counts = {h: hidden_cells(bump_road(h, 4.5), GRID, CAMERAS).sum() for h in (0.04, 0.07, 0.10)}
    assert 0 < counts[0.04] < counts[0.07] < counts[0.10]
    near, far = (hidden_cells(bump_road(0.07, xc), GRID, CAMERAS).sum() for xc in (3.0, 6.0))
    assert near < far


def test_a_phantom_plateau_is_seen_but_lies_in_the_shadow() -> None:
    # The estimator holds the crest's height over the strip behind the bump: geometrically
    # visible, but the road's own level there would be hidden (lowest_visible above the road).
    height, xc = 0.08, 5.5
    estimate = bump_road(height, xc)
    x = GRID.x_centres()
    plateau = (x > xc) & (x < xc + 0.5)
    estimate[plateau] = height
    assert not hidden_cells(estimate, GRID, CAMERAS)[plateau].any()
    sight = line_of_sight(estimate, estimate, GRID, CAMERAS)
    assert (sight.lowest_visible[plateau] > 0.02).all()
    assert (sight.lowest_visible[x < xc - 0.5] < 0.0).all()


def test_holes_do_not_hide_an_occluder_and_nan_cells_stay_unflagged() -> None:
    truth = bump_road(0.10, 5.0)
    estimate = truth.copy()
    crest = np.abs(GRID.x_centres() - 5.0) < 0.05
    estimate[crest, :] = np.nan  # the crest itself was not estimated
    hidden = hidden_cells(estimate, GRID, CAMERAS)
    assert not hidden[crest].any()
    assert hidden.sum() >= 0.8 * hidden_cells(truth, GRID, CAMERAS).sum()
    assert not hidden_cells(np.full(GRID.shape, np.nan, np.float32), GRID, CAMERAS).any()


def test_road_plane_ignores_a_bump() -> None:
    x = GRID.x_centres()[:, None]
    y = GRID.y_centres()[None, :]
    road = (0.03 + 0.005 * x - 0.02 * y).astype(np.float32) + bump_road(0.08, 5.0)
    plane = fit_road_plane(road, GRID)
    assert plane.offset == pytest.approx(0.03, abs=2e-3)
    assert plane.slope_x == pytest.approx(0.005, abs=1e-3)
    assert plane.slope_y == pytest.approx(-0.02, abs=1e-3)
    assert fit_road_plane(np.full(GRID.shape, np.nan), GRID).cells == 0


def test_fill_holes_uses_neighbours_then_the_fallback() -> None:
    surface = np.full(GRID.shape, 0.05, np.float32)
    known = np.zeros(GRID.shape, bool)
    known[:10] = True
    filled = fill_holes(surface, known, fallback=-1.0)
    assert np.allclose(filled[:40], 0.05)
    assert np.allclose(filled[-50:], -1.0)


def _whole_line_of_sight(surface: np.ndarray, camera_y: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """line_of_sight's clearance and lowest visible height with every sample of every ray at once."""
    n_rows, n_cols = GRID.shape
    height = np.float32(GRID.base_height)
    e = surface.astype(np.float32)[None]
    clearance = np.full(GRID.shape, np.inf, np.float32)
    lowest = np.full(GRID.shape, -np.inf, np.float32)
    for origin_y in camera_y:
        rays = _rays(GRID, float(origin_y))
        ground = cv2.remap(surface.astype(np.float32), rays.map_cols, rays.map_rows, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE).reshape(SAMPLES, n_rows, n_cols)
        ratio = (height + rays.fractions * (e - height) - ground) / np.maximum(
            (height - e) * (1.0 - rays.fractions), 1e-6) + rays.untested
        clearance = np.minimum(clearance, ratio.min(axis=0))
        lowest = np.maximum(lowest, (height - (height - ground) * rays.inverse - rays.untested).max(axis=0))
    return clearance, lowest


@pytest.mark.parametrize("camera_y", [(0.0,), CAMERAS, (0.3, 0.0, -0.2)])
def test_the_rays_sampled_in_chunks_give_what_all_samples_at_once_give(camera_y: tuple[float, ...]) -> None:
    rng = np.random.default_rng(3)
    surface = (bump_road(0.08, 4.0) + 0.01 * rng.standard_normal(GRID.shape)).astype(np.float32)
    sight = line_of_sight(surface, surface, GRID, camera_y)
    clearance, lowest = _whole_line_of_sight(surface, camera_y)
    assert np.isfinite(clearance).any() and (clearance < 0.3).any()  # a bump that hides cells
    np.testing.assert_array_equal(sight.clearance, clearance)
    np.testing.assert_array_equal(sight.lowest_visible, lowest)
