"""sgbm / bm: disparity window, accuracy on rendered frames, offsets caught, NaN handling, the far field."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from roadbev_core.backends import BackendError, RefinedBackend, create
from roadbev_core.backends.image_view import ImageViewStereo, match_window, refine_disparity
from roadbev_core.config import FarFieldConfig, GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude, project_voxels
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
