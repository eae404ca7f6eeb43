"""sgbm / bm: disparity window, accuracy on rendered frames, offsets caught, NaN handling, the far field."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from roadbev_core.backends import BackendError, RefinedBackend, create
from roadbev_core.backends.image_view import (
    ImageViewStereo,
    PlaneParallaxPair,
    disparity_road_points,
    grid_bands,
    match_window,
    parallax_disparity,
    plane_disparity,
    plane_parallax_pair,
    refine_disparity,
    warped_bands,
)
from roadbev_core.config import FarFieldConfig, GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude, project_points, project_voxels, road_to_camera
from roadbev_core.labels import cell_index
from roadbev_lab.evaluation.frames import evaluate

from ._frames import right_of

CAMERA = StereoCamera.rsrd_half().scaled(0.5)  # 480 x 264
GRID = GridSpec().scaled(2)  # 82 x 32 cells of 6 cm


@pytest.fixture(scope="module")
def samples() -> list[tuple[Frame, np.ndarray]]:
    """Two rendered half-resolution frames (same scenes as the bev_sweep tests)."""
    from roadbev_lab.synth import RoadConfig, make_sample

    road = RoadConfig(road_class="C", features=("pothole",), surface="asphalt", noise_sigma=1.0)
    return [
        (s.frame, s.truth.elevation)
        for s in (make_sample(seed, camera=CAMERA, grid=GRID, road=road) for seed in (11, 12))
    ]


@pytest.mark.parametrize(("roll_deg", "pitch_deg", "far"), [(0.0, 19.0, False), (2.5, 15.0, False),
                                                            (-3.0, 23.0, False), (1.0, 17.0, True)])
def test_the_grid_bands_hold_every_pixel_whose_point_can_land_in_the_grid(roll_deg: float, pitch_deg: float,
                                                                          far: bool) -> None:
    """Every pixel of the matched crop whose point, at any disparity the search can give, lands in
    the grid (heights within its range) lies in a band; the bands leave a good share of the crop out."""
    camera, attitude = StereoCamera.rsrd_half(), Attitude.from_degrees(roll_deg, pitch_deg)
    grid = FarFieldConfig().grid(GridSpec()) if far else GridSpec()
    window = match_window(grid, camera, attitude, margin_px=4, block_size=11)
    h, w = window.bottom - window.top, window.right - window.left
    kept = np.zeros((h, w), bool)
    bands = grid_bands(window, grid, camera, attitude)
    for rows, cols in bands:
        assert not kept[rows, cols].any()  # no pixel twice
        kept[rows, cols] = True
    assert [b[0].start for b in bands] == sorted(b[0].start for b in bands)  # top to bottom
    lands = np.zeros((h, w), bool)
    for d in np.linspace(window.min_disparity, window.min_disparity + window.num_disparities, 400):
        points, _ = disparity_road_points(np.full((h, w), d, np.float32), np.ones((h, w), bool), window, camera,
                                          attitude, grid.base_height)
        lands |= (cell_index(points, grid, clip_z=True) < grid.n_rows * grid.n_cols).reshape(h, w)
    assert lands.sum() > 1000
    assert not (lands & ~kept).any()
    assert kept.mean() < 0.85


@pytest.mark.parametrize(("roll_deg", "pitch_deg", "far"), [(0.0, 19.0, False), (2.5, 15.0, False),
                                                            (-3.0, 23.0, True)])
def test_a_warped_pairs_bands_hold_every_warped_pixel_whose_point_can_land_in_the_grid(
        roll_deg: float, pitch_deg: float, far: bool) -> None:
    """As the grid's bands for the crop, for a plane-warped pair (whose pixels are the left image's
    half the plane's disparity to the right), at any parallax the search can give."""
    camera, attitude, height = StereoCamera.rsrd_half(), Attitude.from_degrees(roll_deg, pitch_deg), 1.1
    grid = FarFieldConfig().grid(GridSpec()) if far else GridSpec()
    window = match_window(grid, camera, attitude, margin_px=4, block_size=11)
    h, w = window.bottom - window.top, window.right - window.left
    image = np.zeros((camera.height, camera.width), np.uint8)
    pair = plane_parallax_pair(image, image, window, camera, attitude, height)
    kept = np.zeros((h, w), bool)
    for rows, cols in warped_bands(grid_bands(window, grid, camera, attitude), pair):
        assert not kept[rows, cols].any()
        kept[rows, cols] = True
    lands = np.zeros((h, w), bool)
    for r in np.linspace(-16.0, 16.0, 129):
        disparity, left_cols = parallax_disparity(np.full((h, w), r, np.float32), pair,
                                                  np.arange(window.left, window.right))
        points, _ = disparity_road_points(disparity, disparity > 0.5, window, camera, attitude, height, left_cols)
        lands |= (cell_index(points, grid, clip_z=True) < grid.n_rows * grid.n_cols).reshape(h, w)
    assert lands.sum() > 1000
    assert not (lands & ~kept).any()
    assert kept.mean() < 0.9


@pytest.mark.parametrize("pitch_deg", [15.0, 19.0, 23.0])
def test_match_window_covers_every_voxel(pitch_deg: float) -> None:
    """Every voxel's disparity lies in the search range, and its pixel in the matched crop."""
    attitude = Attitude.from_degrees(1.0, pitch_deg)
    window = match_window(GridSpec(), StereoCamera.rsrd_half(), attitude, margin_px=0, block_size=5)
    left = project_voxels(GridSpec(), StereoCamera.rsrd_half(), attitude)
    right = project_voxels(GridSpec(), StereoCamera.rsrd_half(), attitude, right=True)
    disparity = left.u - right.u
    assert window.num_disparities % 16 == 0
    assert disparity.min() >= window.min_disparity
    assert disparity.max() <= window.min_disparity + window.num_disparities
    inside = left.inside
    assert left.u[inside].min() >= window.left + window.min_disparity + window.num_disparities - 1
    assert left.u[inside].max() < window.right
    assert left.v[inside].min() >= window.top - 0.5 and left.v[inside].max() < window.bottom


@pytest.mark.parametrize(("name", "bound_cm", "min_coverage"), [("bm", 1.2, 80.0), ("sgbm", 2.5, 70.0)])
def test_accurate_on_rendered_frames(
    name: str, bound_cm: float, min_coverage: float, samples: list[tuple[Frame, np.ndarray]]
) -> None:
    backend = create(name, GRID)
    assert isinstance(backend, RefinedBackend) and isinstance(backend.inner, ImageViewStereo)
    assert backend.name == name
    m = evaluate(backend, samples).metrics
    assert m["abs_err_cm"] < bound_cm, m["abs_err_cm"]
    assert m["coverage_pct"] > min_coverage, m["coverage_pct"]


def test_half_pixel_disparity_offset_breaks_the_bound(samples: list[tuple[Frame, np.ndarray]]) -> None:
    backend = create("bm", GRID)
    good = evaluate(backend, samples).metrics["abs_err_cm"]
    shift = np.array([[1, 0, 0.5], [0, 1, 0]], np.float32)
    shifted = [
        (replace(f, right=cv2.warpAffine(right_of(f), shift, f.camera.size, borderMode=cv2.BORDER_REFLECT)), t)
        for f, t in samples
    ]
    bad = evaluate(backend, shifted).metrics["abs_err_cm"]
    assert bad > 1.5 * good and bad > 1.2, (good, bad)


def test_uncertainty_and_nan(samples: list[tuple[Frame, np.ndarray]]) -> None:
    estimate = create("bm", GRID).estimate(samples[0][0])
    finite = np.isfinite(estimate.elevation)
    assert np.array_equal(finite, np.isfinite(estimate.uncertainty))
    assert (estimate.uncertainty[finite] > 0).all()
    assert {"matching", "projection", "post"} <= set(estimate.timings_ms)
    flat = np.full((CAMERA.height, CAMERA.width), 90, dtype=np.uint8)  # grey, texture-less
    blank = create("sgbm", GRID).estimate(Frame(flat, flat.copy(), CAMERA, samples[0][0].attitude))
    assert np.isnan(blank.elevation).all()


def _textured_pair(shift_px: float) -> tuple[np.ndarray, np.ndarray]:
    """A random-texture left image [120, 200] and its right image: the left shifted by
    ``shift_px`` to the left (every pixel's disparity ``shift_px``), the right one with another
    gain and offset, as two cameras have."""
    rng = np.random.default_rng(5)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (120, 260)).astype(np.float32), (0, 0), 1.2)
    left = texture[:, 30:230]
    shift = np.array([[1, 0, shift_px], [0, 1, 0]], np.float32)  # right(u) = left(u + d)
    right = cv2.warpAffine(texture, shift, (260, 120), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)[:, 30:230]
    right = 0.8 * right + 20.0
    return np.clip(left, 0, 255).astype(np.uint8), np.clip(right, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("true_px", [7.0, 7.3, 7.5, 7.8])
def test_the_refinement_recovers_the_sub_pixel_part(true_px: float) -> None:
    left, right = _textured_pair(true_px)
    valid = np.ones(left.shape, bool)
    inner = (slice(20, -20), slice(40, -20))
    for start in (np.floor(true_px), np.round(true_px), true_px - 0.4):  # a locked or a poor sub-pixel fit
        disparity = np.full(left.shape, start, np.float32)
        error = np.median(np.abs(refine_disparity(left, right, disparity, valid, (21, 3))[inner] - true_px))
        assert error < 0.1 and (error < 0.5 * abs(start - true_px) or error < 0.02), (start, error)
    # a step of a pixel or more would be another match, not a sub-pixel part: none is taken
    far_off = np.full(left.shape, true_px + 3.0, np.float32)
    out = refine_disparity(left, right, far_off, valid, (21, 3))
    assert np.all(np.abs(out - far_off) < 1.0) and np.any(out == far_off)
    none = refine_disparity(left, right, far_off, np.zeros_like(valid), (21, 3))
    np.testing.assert_array_equal(none, far_off)


def test_the_refinement_lowers_sgbm_error_on_rendered_frames(samples: list[tuple[Frame, np.ndarray]]) -> None:
    plain = evaluate(create("sgbm", GRID), samples).metrics
    refined = evaluate(create("sgbm", GRID, refine_width=21), samples).metrics
    assert refined["abs_err_cm"] < plain["abs_err_cm"], (plain["abs_err_cm"], refined["abs_err_cm"])
    assert refined["coverage_pct"] >= plain["coverage_pct"] - 1.0


@pytest.mark.parametrize(("roll_deg", "pitch_deg"), [(0.0, 17.0), (1.5, 19.0), (-2.0, 14.0)])
def test_the_plane_disparity_is_the_reference_planes(roll_deg: float, pitch_deg: float) -> None:
    camera, attitude, height = StereoCamera.rsrd_half(), Attitude.from_degrees(roll_deg, pitch_deg), 1.1
    x, y = np.meshgrid(np.linspace(2.0, 15.0, 9), np.linspace(-1.5, 1.5, 7), indexing="ij")
    road = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=-1)  # [N, 3] on z = 0
    u, v, depth = project_points(road_to_camera(road, attitude, height), camera)
    plane = np.array([plane_disparity(camera, attitude, height, np.array([vi]), np.array([ui]))[0, 0]
                      for ui, vi in zip(u, v, strict=True)])
    np.testing.assert_allclose(plane, camera.fx * camera.baseline / depth, rtol=1e-5)
    # a column's and a row's term: along a row the plane's disparity changes by the pair's slope
    rows, cols = np.arange(300, 303), np.arange(100, 110)
    grid = plane_disparity(camera, attitude, height, rows, cols)
    window = match_window(GridSpec(), camera, attitude, margin_px=4, block_size=7)
    blank = np.zeros((camera.height, camera.width), np.uint8)
    pair = plane_parallax_pair(blank, blank, window, camera, attitude, height)
    np.testing.assert_allclose(np.diff(grid, axis=1), pair.slope, atol=1e-4)
    level = Attitude.from_degrees(0.0, 2.0)  # the top rows look above the horizon: no plane there
    assert plane_disparity(camera, level, height, np.array([0]), np.array([480]))[0, 0] == 0.0


def test_a_warped_pairs_matches_map_back_to_the_left_image() -> None:
    plane = np.array([[8.0, 8.2], [12.0, 12.4]], np.float32)
    pair = PlaneParallaxPair(np.zeros((2, 2), np.uint8), np.zeros((2, 2), np.uint8), plane, 0.2)
    residual = np.array([[0.0, 1.0], [-2.0, 0.5]], np.float32)
    disparity, cols = parallax_disparity(residual, pair, np.array([100, 101]))
    # r + (p(u) + p(u - r)) / 2 with p(u - r) = p(u) - slope r; the left pixel at u + p(u) / 2
    np.testing.assert_allclose(disparity, residual + plane - 0.1 * residual, rtol=1e-6)
    np.testing.assert_allclose(cols, np.array([[104.0, 105.1], [106.0, 107.2]]), rtol=1e-6)


def test_a_plane_warped_pair_has_no_disparity_on_the_plane() -> None:
    """A textured level road: the pair warped by the plane's disparity lines up (no parallax left)."""
    camera, attitude, height = StereoCamera.rsrd_half(), Attitude.from_degrees(0.5, 18.0), 1.1
    window = match_window(GridSpec(), camera, attitude, margin_px=4, block_size=7)
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (camera.height, 4 * camera.width)).astype(np.float32), (0, 0), 2.0)
    rows, cols = np.arange(camera.height), np.arange(camera.width)
    plane = plane_disparity(camera, attitude, height, rows, cols)  # [H, W]
    u = np.broadcast_to(cols.astype(np.float32), plane.shape) + camera.width
    v = np.ascontiguousarray(np.broadcast_to(rows.astype(np.float32)[:, None], plane.shape))
    # the right image sees the road a plane's disparity to the left
    left = cv2.remap(texture, np.ascontiguousarray(u), v, cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
    right = cv2.remap(texture, np.ascontiguousarray(u + plane), v, cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
    pair = plane_parallax_pair(left, right, window, camera, attitude, height)
    inner = (slice(5, -5), slice(window.min_disparity + window.num_disparities, -5))
    diff = pair.left.astype(np.float32)[inner] - pair.right.astype(np.float32)[inner]
    unwarped = left[window.top:window.bottom, window.left:window.right].astype(np.float32)[inner] - \
        right[window.top:window.bottom, window.left:window.right].astype(np.float32)[inner]
    assert np.abs(diff).mean() < 0.1 * np.abs(unwarped).mean()


def test_plane_parallax_matching_answers_more_of_the_road(samples: list[tuple[Frame, np.ndarray]]) -> None:
    for name in ("bm", "sgbm"):
        plain = evaluate(create(name, GRID), samples).metrics
        parallax = evaluate(create(name, GRID, plane_parallax_px=16), samples).metrics
        assert parallax["coverage_pct"] > plain["coverage_pct"], name
        assert parallax["abs_err_cm"] < 1.25 * plain["abs_err_cm"], (name, plain["abs_err_cm"], parallax["abs_err_cm"])


def test_errors() -> None:
    with pytest.raises(BackendError, match="unknown option"):
        create("bm", GRID, window=9)
    with pytest.raises(BackendError, match="block_size"):
        create("bm", GRID, block_size=4)
    with pytest.raises(BackendError, match="mode"):
        create("sgbm", GRID, mode="fast")
    with pytest.raises(BackendError, match="odd sides"):
        create("sgbm", GRID, refine_width=20)
    with pytest.raises(BackendError, match="refine_height"):
        create("sgbm", GRID, refine_width=21, refine_height=-1)
    with pytest.raises(BackendError, match="multiple of 8"):
        create("bm", GRID, plane_parallax_px=12)
    with pytest.raises(BackendError, match="plane_parallax_px"):
        create("bm", GRID, plane_parallax_px=-8)
    frame = Frame(np.zeros((CAMERA.height, CAMERA.width), np.uint8), None, CAMERA, Attitude())
    with pytest.raises(FrameError, match="right image"):
        create("sgbm", GRID).estimate(frame)


FAR_GRID = FarFieldConfig(enabled=True, resolution=0.24).grid(GRID)  # 33 x 8 cells of 24 cm, 7.08-15 m


@pytest.fixture(scope="module")
def far_samples() -> list[tuple[Frame, np.ndarray, np.ndarray]]:
    """Two rendered half-resolution frames with the far-field truth (features in both windows)."""
    from roadbev_lab.synth import RoadConfig, make_sample

    road = RoadConfig(road_class="B", features=("speed_bump",), surface="asphalt", noise_sigma=1.0)
    out = []
    for seed in (21, 22):
        s = make_sample(seed, camera=CAMERA, grid=GRID, road=road, far_grid=FAR_GRID)
        assert s.far_truth is not None
        out.append((s.frame, s.truth.elevation, s.far_truth.elevation))
    return out


@pytest.mark.parametrize(("name", "bound_cm", "min_coverage"), [("bm", 3.5, 40.0), ("sgbm", 3.5, 40.0)])
def test_the_far_field_from_its_own_window_and_disparities(
    name: str, bound_cm: float, min_coverage: float, far_samples: list[tuple[Frame, np.ndarray, np.ndarray]]
) -> None:
    backend = create(name, FAR_GRID)
    assert getattr(backend, "far_field", False)  # answers a far-field grid
    frame = far_samples[0][0]
    near_window = match_window(GRID, CAMERA, frame.attitude, margin_px=4, block_size=11)
    far_window = match_window(FAR_GRID, CAMERA, frame.attitude, margin_px=4, block_size=11)
    # the far rows lie above the grid's and need smaller disparities than its search reaches
    assert far_window.top < near_window.top and far_window.min_disparity < near_window.min_disparity
    m = evaluate(backend, [(f, far) for f, _, far in far_samples]).metrics
    assert m["abs_err_cm"] < bound_cm, m["abs_err_cm"]
    assert m["coverage_pct"] > min_coverage, m["coverage_pct"]
    assert m["confident_wrong_pct"] < 2.0, m["confident_wrong_pct"]


def test_the_ensemble_of_image_view_backends_answers_the_far_field_and_others_do_not() -> None:
    assert getattr(create("ensemble", FAR_GRID, members="bm+sgbm"), "far_field", False)
    assert not getattr(create("bev_sweep", GRID), "far_field", False)
