"""bench_texture's coverage comparison: counts per distance band, and coverage at another label mix."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest

from benchmarks import bench_texture
from benchmarks.bench_texture import BANDS_M, band_counts, coverage_at_mix
from roadbev_core.config import GridSpec

GRID = bench_texture.WINDOW.with_overrides(base_height=bench_texture.CAMERA_HEIGHT_M)


def _rows_of_band(grid: GridSpec, band: int) -> np.ndarray:
    lo, hi = BANDS_M[band]
    x = grid.x_centres()
    return np.flatnonzero((x >= lo) & (x < hi))


def test_band_counts_count_answered_labelled_cells_per_band_and_ignore_answers_without_a_label() -> None:
    truth = np.full(GRID.shape, np.nan, np.float32)
    estimate = np.full(GRID.shape, np.nan, np.float32)
    near, far = _rows_of_band(GRID, 0), _rows_of_band(GRID, 3)
    truth[near[:2], :10] = 0.0  # 20 labelled near cells, 15 of them answered
    estimate[near[:2], :5] = 0.01
    estimate[near[0], 5:10] = 0.01
    truth[far[0], :4] = 0.0  # 4 labelled far cells, none answered
    estimate[far[1], :] = 0.02  # answers where nothing is labelled do not count
    answered, labelled = band_counts(estimate, truth, GRID)
    assert answered.tolist() == [15, 0, 0, 0]
    assert labelled.tolist() == [20, 0, 0, 4]


def test_coverage_at_mix_weights_each_band_by_the_other_layouts_label_counts() -> None:
    per_band = [90.0, 60.0, 30.0, 10.0]
    # labels spread evenly: the plain mean; crowded near: close to the near band's coverage
    assert coverage_at_mix(per_band, [100, 100, 100, 100]) == pytest.approx(47.5)
    assert coverage_at_mix(per_band, [1000, 100, 0, 0]) == pytest.approx((90_000 + 6000) / 1100)
    assert math.isnan(coverage_at_mix(per_band, [0, 0, 0, 0]))


def test_a_synthetic_layout_with_the_real_coverage_per_band_matches_it_at_the_real_mix() -> None:
    per_band = [95.0, 77.0, 60.0, 48.0]
    mix = [1854, 1506, 974, 752]
    energy = [{"median": 5.0}] * 4
    real: dict[str, Any] = {"band_coverage_pct": {m: per_band for m in bench_texture.MATCHERS},
                            "labelled_cells_per_band": mix, "gradient_energy": energy,
                            "smoothed_gradient_energy": energy}
    synth: dict[str, Any] = {"band_coverage_pct": real["band_coverage_pct"], "gradient_energy": energy,
                             "smoothed_gradient_energy": energy}
    # the same per-band coverage on an even layout: pooled it reads lower, at the real mix the same
    assert coverage_at_mix(per_band, [1200] * 4) < coverage_at_mix(per_band, mix) - 5.0
    check = bench_texture._check(real, synth)
    assert check["coverage_factor"] == {m: pytest.approx(1.0) for m in bench_texture.MATCHERS}
    assert check["tolerances_met"]


def test_view_consistency_is_one_for_a_shared_texture_and_near_zero_for_independent_noise() -> None:
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.normal(0.0, 20.0, (120, 200)).astype(np.float32), (0, 0), 1.2)
    disparity = 7.3
    # the right image sees the same surface 7.3 px to the left (sub-pixel shift by the Fourier theorem)
    freq = np.fft.fftfreq(200)[None, :]
    shifted = np.fft.ifft(np.fft.fft(texture, axis=1) * np.exp(2j * np.pi * freq * disparity), axis=1)
    right = np.asarray(shifted.real, np.float32)
    u = np.linspace(30.0, 170.0, 40)
    v = np.full(40, 60.0)
    shared = bench_texture.view_consistency(texture, right, u, v, u - disparity + 0.3)  # a 0.3 px label error
    assert np.median(shared["view_zncc_mid"]) > 0.95 and np.median(shared["view_zncc_fine"]) > 0.85
    noise = np.asarray(rng.normal(0.0, 20.0, (120, 200)), np.float32)
    alone = bench_texture.view_consistency(texture, noise, u, v, u - disparity)
    assert np.median(np.abs(alone["view_zncc_fine"])) < 0.3
