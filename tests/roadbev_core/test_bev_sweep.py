"""bev_sweep: accuracy on rendered frames, geometry sign/offset errors caught, NaN handling, options."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import pytest
import torch

from roadbev_core.backends import BackendError, RefinedBackend, create
from roadbev_core.backends.bev_sweep import BevSweep, SweepParams, _outliers
from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_lab.evaluation.frames import evaluate

from ._frames import right_of

torch.set_flush_denormal(True)

CAMERA = StereoCamera.rsrd_half().scaled(0.5)  # 480 x 264
GRID = GridSpec().scaled(2)  # 82 x 32 cells of 6 cm


@pytest.fixture(scope="module")
def samples() -> list[tuple[Frame, np.ndarray]]:
    """Two rendered half-resolution frames with a textured asphalt road and a pothole."""
    from roadbev_lab.synth import RoadConfig, make_sample

    road = RoadConfig(road_class="C", features=("pothole",), surface="asphalt", noise_sigma=1.0)
    out = []
    for seed in (11, 12):
        s = make_sample(seed, camera=CAMERA, grid=GRID, road=road)
        out.append((s.frame, s.truth.elevation))
    return out


@pytest.fixture(scope="module")
def sweep() -> RefinedBackend:
    backend = create("bev_sweep", GRID)
    assert isinstance(backend, RefinedBackend) and isinstance(backend.inner, BevSweep)  # behind the
    return backend  # registry's visibility/calibration step


def _params(**options: Any) -> SweepParams:
    backend = create("bev_sweep", GRID, raw=True, **options)
    assert isinstance(backend, BevSweep)
    return backend.params


def _abs_err_cm(backend: RefinedBackend, frames: list[tuple[Frame, np.ndarray]]) -> tuple[float, float]:
    m = evaluate(backend, frames).metrics
    return m["abs_err_cm"], m["coverage_pct"]


def test_accurate_on_rendered_frames(sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]) -> None:
    err, coverage = _abs_err_cm(sweep, samples)
    # Predicting a flat road scores ~1.5-2 cm here; the sweep is sub-centimetre on most cells.
    flat = np.nanmean(np.concatenate([np.abs(t).ravel() for _, t in samples])) * 100
    assert flat > 1.0
    assert err < 0.9, err
    assert coverage > 80.0, coverage


def test_half_pixel_shift_of_the_right_image_breaks_the_bound(
    sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]
) -> None:
    """A renderer or rig off by half a pixel in disparity must show up as a clear error."""
    shifted = []
    for frame, truth in samples:
        shift = np.array([[1, 0, 0.5], [0, 1, 0]], np.float32)
        right = cv2.warpAffine(right_of(frame), shift, frame.camera.size, borderMode=cv2.BORDER_REFLECT)
        shifted.append((replace(frame, right=right), truth))
    good, _ = _abs_err_cm(sweep, samples)
    bad, _ = _abs_err_cm(sweep, shifted)
    assert bad > max(1.5 * good, 1.0), (good, bad)


def test_swapped_cameras_fail(sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]) -> None:
    """Left and right exchanged (a mis-signed baseline): no trustworthy surface."""
    swapped = [(replace(f, left=right_of(f), right=f.left), t) for f, t in samples]
    err, coverage = _abs_err_cm(sweep, swapped)
    assert err > 1.5 or coverage < 20.0, (err, coverage)


def test_textureless_images_give_nan(sweep: RefinedBackend) -> None:
    grey = np.full((CAMERA.height, CAMERA.width, 3), 128, dtype=np.uint8)
    estimate = sweep.estimate(Frame(grey, grey.copy(), CAMERA, Attitude.from_degrees(0.0, 19.0)))
    assert np.isnan(estimate.elevation).all()
    assert np.isnan(estimate.uncertainty).all()


def test_cells_outside_the_image_are_nan(sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]) -> None:
    """Crop the bottom of the images: the near rows of the grid fall outside and must be NaN."""
    frame, _ = samples[0]
    keep = CAMERA.height * 2 // 3
    camera = CAMERA.cropped(0, 0, CAMERA.width, keep)
    cropped = Frame(frame.left[:keep], right_of(frame)[:keep], camera, frame.attitude)
    estimate = sweep.estimate(cropped)
    full = sweep.estimate(frame)
    assert np.isfinite(full.elevation[-5:]).mean() > 0.5
    assert np.isnan(estimate.elevation[-5:]).all()  # nearest rows: below the crop
    far = slice(0, GRID.n_rows // 3)  # far rows: still estimated much as before
    assert np.isfinite(estimate.elevation[far]).mean() > 0.7 * np.isfinite(full.elevation[far]).mean()


def test_uncertainty_is_finite_exactly_where_elevation_is(
    sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]
) -> None:
    estimate = sweep.estimate(samples[0][0])
    finite = np.isfinite(estimate.elevation)
    assert np.array_equal(finite, np.isfinite(estimate.uncertainty))
    sigma = estimate.uncertainty[finite]
    assert (sigma > 0).all() and (sigma < 0.2).all()
    # Sanity: the farthest third (small disparity change per cm) is less certain than the nearest.
    rows = estimate.uncertainty.shape[0]
    far = np.nanmedian(estimate.uncertainty[: rows // 3])
    near = np.nanmedian(estimate.uncertainty[-rows // 3 :])
    assert far > near
    assert estimate.elevation.dtype == np.float32 and estimate.elevation.shape == GRID.shape


def test_reports_stage_timings(sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]) -> None:
    timings = sweep.estimate(samples[0][0]).timings_ms
    assert {"projection", "sampling", "cost", "aggregation", "post"} <= set(timings)
    assert all(v >= 0 for v in timings.values())


def test_mono_frame_is_refused(sweep: RefinedBackend, samples: list[tuple[Frame, np.ndarray]]) -> None:
    frame = samples[0][0]
    with pytest.raises(FrameError):
        sweep.estimate(replace(frame, right=None))


def test_options_are_validated() -> None:
    assert _params(patch_cells=5, subsamples=[2, 2]).subsamples == (2, 2)
    with pytest.raises(BackendError, match="unknown bev_sweep option"):
        create("bev_sweep", GRID, patch=3)
    with pytest.raises(BackendError, match="odd"):
        create("bev_sweep", GRID, patch_cells=4)
    with pytest.raises(ConfigError):
        SweepParams(temperature=0.0)
    with pytest.raises(ConfigError, match="z_step"):
        BevSweep(GRID, SweepParams(z_step=0.03))  # 0.40 m is not a whole number of 3 cm steps


def test_occlusion_behind_a_bump() -> None:
    """Cells right behind a 15 cm bump are hidden from the cameras; cells before it are not."""
    sweep = BevSweep(GRID)
    surface = torch.zeros(GRID.shape)
    rows = np.nonzero((GRID.x_centres() > 4.0) & (GRID.x_centres() < 4.3))[0]  # the bump, 4.0-4.3 m
    surface[rows.min() : rows.max() + 1] = 0.15
    hidden = sweep._occluded(surface, CAMERA.baseline).numpy()
    behind = rows.min() - 2  # row 0 is the farthest: smaller row index = further away
    assert hidden[behind].all()
    assert not hidden[rows.max() + 3 :].any()  # nearer than the bump: visible
    assert not hidden[:5].any()  # far beyond the bump the rays clear it again
    assert not sweep._occluded(torch.zeros(GRID.shape), CAMERA.baseline).any()


def test_isolated_wrong_peaks_are_outliers() -> None:
    elevation = torch.zeros(GRID.shape)
    elevation[40, 16] = 0.05
    confident = torch.ones(GRID.shape, dtype=torch.bool)
    out = _outliers(elevation, confident, 0.01)
    assert out[40, 16] and out.sum() == 1


def test_sampling_zones_join_without_seams(samples: list[tuple[Frame, np.ndarray]]) -> None:
    """With one sampling density in every zone, the zoned ZNCC equals a single pass over the grid."""
    from roadbev_core.backends.bev_sweep import _sample_positions, grey_image
    from roadbev_core.backends.common import StageClock

    same: dict[str, Any] = {f"{zone}subsamples": (1, 2) for zone in ("", "far_", "near_")}
    sweep = BevSweep(GRID, SweepParams(**same))
    assert len(sweep._zones) == 3
    frame = samples[0][0]
    greys = np.stack([grey_image(im, 1.0, 4.0) for im in (frame.left, right_of(frame))])
    images = torch.from_numpy(greys - greys.mean(axis=(1, 2), keepdims=True))[:, None]
    planes = sweep._z[:, None, None]
    zoned, zoned_texture = sweep._zncc_zones(images, planes, frame, StageClock())
    single, single_texture = sweep._zncc(images, _sample_positions(GRID, 1, 2), planes, frame, StageClock())
    assert zoned.shape == single.shape == (planes.shape[0], *GRID.shape)
    assert torch.allclose(zoned, single, atol=1e-4)
    assert torch.allclose(zoned_texture, single_texture, atol=1e-3)


def test_default_sweep_step_fits_any_height_range() -> None:
    """z_step None: about 2 cm, always a whole number of steps over the grid's height range."""
    assert BevSweep(GRID).z_step == pytest.approx(0.02)
    odd = replace(GRID, z_min=-0.15, z_max=0.12)  # 27 cm: 14 steps of 1.93 cm
    sweep = BevSweep(odd)
    assert sweep._z.numel() == 14
    assert sweep._z[-1] + sweep.z_step / 2 == pytest.approx(0.12, abs=1e-6)


@pytest.mark.parametrize("shape", [(1, 32), (82, 1), (2, 2)])
def test_degenerate_grids_run(samples: list[tuple[Frame, np.ndarray]], shape: tuple[int, int]) -> None:
    """A grid of one row or one column (a wheel-track strip) is estimated, not a division by zero."""
    rows, cols = shape
    grid = replace(
        GRID, x_min=GRID.x_max - rows * GRID.resolution, y_min=GRID.y_max - cols * GRID.resolution
    )
    assert grid.shape == shape
    estimate = BevSweep(grid).estimate(samples[0][0])
    assert estimate.elevation.shape == shape
    finite = np.isfinite(estimate.elevation)
    assert np.array_equal(finite, np.isfinite(estimate.uncertainty))
    assert (np.abs(estimate.elevation[finite]) < 0.2).all()


def test_window_check_drops_cells_where_a_small_window_disagrees(samples: list[tuple[Frame, np.ndarray]]) -> None:
    frame = samples[0][0]
    unchecked = np.isfinite(BevSweep(GRID, SweepParams(max_disagreement=0.0)).estimate(frame).elevation)
    strict = np.isfinite(BevSweep(GRID, SweepParams(max_disagreement=0.002)).estimate(frame).elevation)
    assert not (strict & ~unchecked).any()  # the check only removes cells
    assert strict.sum() < 0.9 * unchecked.sum()
    with pytest.raises(ConfigError, match="check_cells"):
        SweepParams(check_cells=4)
    with pytest.raises(ConfigError, match="aggregation_cells"):
        SweepParams(aggregation_cells=(21, 8))
    # Windows are one side or (rows, columns); lists from YAML / JSON become tuples.
    assert _params(far_aggregation_cells=[25, 9]).far_aggregation_cells == (25, 9)
    assert SweepParams(near_aggregation_cells=9).near_aggregation_cells == 9
