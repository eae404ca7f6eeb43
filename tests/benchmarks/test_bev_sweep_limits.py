"""bev_sweep_limits: the smoothing floor of a plane is nothing, and the measurement runs through the
registry's backends (the visibility and sigma step included) on a rendered frame."""

from __future__ import annotations

import numpy as np

from benchmarks.bev_sweep_limits import measure, zone_smoothed
from roadbev_core.backends import RefinedBackend, create
from roadbev_core.backends.bev_sweep import BevSweep
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_lab.synth import make_sample

GRID = GridSpec()


def test_a_tilted_plane_is_its_own_window_mean_away_from_the_border() -> None:
    sweep = create("bev_sweep", GRID)
    assert isinstance(sweep, RefinedBackend) and isinstance(sweep.inner, BevSweep)
    rows, cols = np.mgrid[0 : GRID.shape[0], 0 : GRID.shape[1]].astype(np.float64)
    plane = 0.01 * rows / GRID.shape[0] + 0.02 * cols / GRID.shape[1]  # [R, C] m
    smoothed = zone_smoothed(plane, sweep.inner)
    inner = (slice(20, -20), slice(10, -10))  # a window reaching past the border is cut short there
    np.testing.assert_allclose(smoothed[inner], plane[inner], atol=1e-9)


def test_the_measurement_scores_both_matchers_through_the_registry() -> None:
    sample = make_sample(100_000, camera=StereoCamera.rsrd_half().scaled(0.5), grid=GRID)
    record = measure([sample], GRID)
    assert 0.0 <= record["smoothing_floor_cm"] < record["bev_sweep_abs_err_cm"] < 5.0
    assert set(record["tail"]) == {"bev_sweep", "bm"}
    shares = [row["bev_sweep"]["share_of_error_pct"] or 0.0 for row in record["relief"]]
    assert abs(sum(shares) - 100.0) < 1e-3  # the relief bins split the whole error (float32 sums)
