from __future__ import annotations

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.geometry import Attitude, road_to_camera
from roadbev_core.labels import (
    cell_index,
    cell_means,
    class_to_elevation,
    elevation_map,
    elevation_map_from_camera,
    elevation_to_class,
    one_hot,
    two_hot,
)

G = GridSpec()


def _reference_loop(points: np.ndarray, grid: GridSpec) -> np.ndarray:
    """A plain per-point loop, as the reference release labelled cells."""
    sums = np.zeros(grid.shape)
    counts = np.zeros(grid.shape)
    for x, y, z in points:
        r = int(np.floor((grid.x_max - x) / grid.resolution))
        c = int(np.floor((grid.y_max - y) / grid.resolution))
        if 0 <= r < grid.n_rows and 0 <= c < grid.n_cols:
            sums[r, c] += z
            counts[r, c] += 1
    out = np.full(grid.shape, np.nan)
    out[counts > 0] = sums[counts > 0] / counts[counts > 0]
    return out


def test_mean_of_points_per_cell() -> None:
    x0, y0 = G.x_centres()[10], G.y_centres()[5]
    pts = np.array([[x0, y0, 0.01], [x0 + 0.01, y0 - 0.01, 0.03], [G.x_centres()[0], G.y_centres()[0], -0.05]])
    lab = elevation_map(pts, G)
    assert lab.elevation[10, 5] == pytest.approx(0.02)
    assert lab.elevation[0, 0] == pytest.approx(-0.05)
    assert lab.count[10, 5] == 2
    assert lab.mask.sum() == 2
    assert np.isnan(lab.elevation[~lab.mask]).all()


def test_matches_reference_loop_on_random_points() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform([2.0, -1.1, -0.2], [7.3, 1.2, 0.2], size=(20_000, 3))
    lab = elevation_map(pts, G)
    ref = _reference_loop(pts, G)
    np.testing.assert_allclose(lab.elevation, ref, atol=1e-6, equal_nan=True)


def test_nonfinite_and_outside_points_are_ignored() -> None:
    pts = np.array([[4.0, 0.0, np.nan], [100.0, 0.0, 0.1], [4.0, 0.0, 0.05]])
    lab = elevation_map(pts, G)
    assert lab.mask.sum() == 1
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        elevation_map(np.zeros((4, 2)), G)


def test_clip_z_drops_points_outside_the_range() -> None:
    pts = np.array([[4.0, 0.0, 0.5], [4.0, 0.0, 0.1]])
    assert np.nanmax(elevation_map(pts, G).elevation) == pytest.approx(0.3)
    assert np.nanmax(elevation_map(pts, G, clip_z=True).elevation) == pytest.approx(0.1)


def test_one_binning_averages_several_values_per_cell() -> None:
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(G.x_min - 0.5, G.x_max + 0.5, 4000),
                           rng.uniform(G.y_min - 0.5, G.y_max + 0.5, 4000), rng.uniform(-0.3, 0.3, 4000)])
    pts[::50, 2] = np.nan
    flat = cell_index(pts, G, clip_z=True)
    assert flat.shape == (4000,)
    n_cells = G.n_rows * G.n_cols
    outside = (pts[:, 0] < G.x_min) | (pts[:, 0] >= G.x_max) | ~np.isfinite(pts[:, 2]) | (np.abs(pts[:, 2]) > 0.2)
    assert np.all(flat[outside] == n_cells) and np.all(flat[~outside & (pts[:, 1] < G.y_max)
                                                           & (pts[:, 1] > G.y_min)] < n_cells)
    count, (mean_z, mean_sq) = cell_means(flat, G, pts[:, 2], np.square(pts[:, 2]))
    label = elevation_map(pts, G, clip_z=True)
    np.testing.assert_array_equal(count, label.count)
    np.testing.assert_array_equal(mean_z, label.elevation)
    squared = pts.copy()
    squared[:, 2] = np.square(pts[:, 2])
    squared[~np.isfinite(pts[:, 2]) | (np.abs(pts[:, 2]) > 0.2), 2] = np.nan  # the clip, applied to z
    np.testing.assert_allclose(mean_sq, elevation_map(squared, G).elevation, rtol=1e-6, equal_nan=True)
    assert mean_sq.dtype == np.float32 and count.dtype == np.int32


def test_camera_frame_points_give_the_same_map() -> None:
    rng = np.random.default_rng(2)
    pts = rng.uniform([2.0, -1.0, -0.1], [7.0, 1.0, 0.1], size=(5000, 3))
    att = Attitude.from_degrees(-1.2, 19.5)
    from_cam = elevation_map_from_camera(road_to_camera(pts, att, G.base_height), att, G)
    np.testing.assert_allclose(from_cam.elevation, elevation_map(pts, G).elevation, atol=1e-6, equal_nan=True)


def test_class_bins_round_trip() -> None:
    e = np.array([-0.2, -0.1975, -0.0001, 0.0, 0.0049, 0.1999, 0.35])
    idx = elevation_to_class(e, G)
    assert idx.tolist() == [0, 0, 39, 40, 40, 79, 79]
    assert np.all(np.abs(class_to_elevation(idx[1:-1], G) - e[1:-1]) <= G.class_resolution / 2 + 1e-12)


def test_one_hot_and_two_hot() -> None:
    e = np.array([[0.0123, -0.15]])
    oh = one_hot(e, G)
    assert oh.shape == (80, 1, 2)
    assert np.all(oh.sum(axis=0) == 1)
    th = two_hot(e, G)
    np.testing.assert_allclose(th.sum(axis=0), 1.0, atol=1e-6)
    expect = np.tensordot(G.class_centres(), th, axes=1)
    np.testing.assert_allclose(expect, e, atol=1e-6)
    assert (th > 0).sum(axis=0).max() <= 2
