"""bench_preview_sigma's scoring: the strip behind a bump and what counts as confidently wrong."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.bench_preview_sigma import behind_bumps, score_points


def test_the_strip_behind_a_bump_runs_from_its_centre_to_two_metres_past_it() -> None:
    xy = np.stack([np.array([9.0, 10.0, 10.01, 11.5, 12.0, 12.01, 30.0]), np.zeros(7)], 1)
    assert behind_bumps(xy, np.array([10.0])).tolist() == [False, False, True, True, True, False, False]
    assert behind_bumps(xy, np.array([10.0, 29.0]))[-1]
    assert not behind_bumps(xy, np.array([])).any()


def test_confidently_wrong_is_off_by_more_than_2_cm_at_a_sigma_below_1_cm() -> None:
    error = np.array([0.025, 0.025, -0.03, 0.001, np.nan, 0.05])
    sigma = np.array([0.005, 0.012, 0.009, 0.0001, 0.001, np.nan])
    where = np.array([True, True, True, True, True, True])
    out = score_points(error, sigma, where)
    assert out["samples"] == 4  # the NaN error and the NaN sigma do not count
    assert out["confident_wrong"] == 2 and out["confident_wrong_pct"] == pytest.approx(50.0)
    assert out["max_err_cm_sigma_below_1cm"] == pytest.approx(3.0)
    assert out["outside_3sigma_pct"] == pytest.approx(75.0)  # 0.001 is 10 sigma off, 0.025 at 1.2 cm is not
    only_last = score_points(error, sigma, np.array([False, True, False, False, False, False]))
    assert only_last["confident_wrong"] == 0 and math.isnan(only_last["max_err_cm_sigma_below_1cm"])
