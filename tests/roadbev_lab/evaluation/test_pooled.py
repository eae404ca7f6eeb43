"""Pooling: accumulators merged are one accumulator of all the frames; the sums survive a store."""

from __future__ import annotations

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.arrival import WheelErrors, summarise_errors
from roadbev_lab.evaluation.frames import EvalSums, json_safe
from roadbev_lab.evaluation.metrics import MetricAccumulator, SigmaAccumulator
from roadbev_lab.evaluation.pooled import BagSums, PoolingError

GRID = GridSpec().scaled(2)


def _frames(seed: int, n: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        truth = rng.normal(0, 0.02, GRID.shape).astype(np.float32)
        truth[rng.random(GRID.shape) < 0.2] = np.nan
        estimate = (truth + rng.normal(0, 0.01, GRID.shape)).astype(np.float32)
        estimate[rng.random(GRID.shape) < 0.1] = np.nan
        out.append((estimate, np.full(GRID.shape, 0.008, np.float32), truth))
    return out


def _sums(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> EvalSums:
    accuracy, sigma = MetricAccumulator(GRID), SigmaAccumulator()
    for estimate, s, truth in frames:
        accuracy.add(estimate, truth)
        sigma.add(estimate, s, truth)
    return EvalSums("bm", accuracy, sigma, len(frames), len(frames) - 1, 10.0, 20.0, {"matching": 5.0})


def test_merged_sums_are_the_sums_of_all_frames() -> None:
    a, b = _frames(1, 3), _frames(2, 4)
    merged = _sums(a).merge(_sums(b)).metrics()
    whole = _sums(a + b).metrics()
    exact = ("frames", "cells", "labelled_cells", "median_abs_err_cm", "p95_abs_err_cm", "sigma_cells",
             "reliability", "frames_with_truth")
    assert {k: merged[k] for k in exact} == {k: whole[k] for k in exact}  # counts and histograms add exactly
    for key in ("abs_err_cm", "rmse_cm", "gt_0p5cm_pct", "coverage_pct", "within_1sigma_pct", "mean_sigma_cm"):
        assert merged[key] == pytest.approx(whole[key], rel=1e-12), key
    np.testing.assert_allclose(merged["band_abs_err_cm"], whole["band_abs_err_cm"], rtol=1e-12)
    assert merged["timed_frames"] == 5 and merged["pipeline_ms"] == pytest.approx(60.0 / 5)


def test_sums_survive_their_arrays_and_refuse_another_grid() -> None:
    wheels = {"front_left": WheelErrors(np.array([0.01, np.nan]), np.array([0.02, np.nan]), np.array([True, False]),
                                        np.array([True, True]), np.array([True, False]), np.array([0.02, np.nan]))}
    sums = BagSums(_sums(_frames(3, 2)), lost_frames=1, map_enabled=True, map_skipped={"no odometry": 2},
                   lead_time_s=0.1, wheels=wheels, map_rows={"abs_err_cm": [1.0, 3.0]}, map_windows=2)
    back = BagSums.from_arrays(sums.to_arrays())
    assert back.metrics() == sums.metrics()
    twice = sums.merge(back).metrics()
    assert twice["lost_frames"] == 2 and twice["map_skipped"] == {"no odometry": 4}
    assert twice["preview_at_arrival"]["points"] == 4 and twice["map"]["windows"] == 4
    assert twice["preview_at_arrival"] == json_safe(summarise_errors(
        {"front_left": wheels["front_left"].concat(wheels["front_left"])}, 0.1))
    other = MetricAccumulator(GridSpec())
    with pytest.raises(ValueError, match="cannot pool"):
        MetricAccumulator(GRID).merge(other)
    with pytest.raises(PoolingError, match="not the sums"):
        BagSums.from_arrays({"scalars": np.array("{}")})
    # sums stored before the points carried the preview's sigma: the same errors, no sigma to score
    older = {k: v for k, v in sums.to_arrays().items() if not k.endswith(".sigma")}
    arrival = BagSums.from_arrays(older).metrics()["preview_at_arrival"]
    assert arrival["abs_err_cm"] == sums.metrics()["preview_at_arrival"]["abs_err_cm"]
    assert arrival["sigma_points"] == 0 and arrival["within_1sigma_pct"] is None
