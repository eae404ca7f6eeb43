from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.metrics import BandAccumulator, MetricAccumulator, distance_bands

G = GridSpec()


def test_metrics_by_hand() -> None:
    truth = np.full(G.shape, np.nan, dtype=np.float32)
    est = np.full(G.shape, np.nan, dtype=np.float32)
    truth[-1, 0], est[-1, 0] = 0.0, 0.01  # nearest row: 1 cm error
    truth[0, 0], est[0, 0] = 0.0, -0.002  # farthest row: 0.2 cm error
    truth[50, 3] = 0.05  # labelled, no estimate: missing, not zero error
    est[60, 3] = 0.3  # estimate without label: ignored
    acc = MetricAccumulator(G)
    acc.add(est, truth)
    m = acc.result()
    assert m.frames == 1 and m.cells == 2 and m.labelled_cells == 3
    assert m.abs_err_cm == pytest.approx(0.6, abs=1e-5)
    assert m.rmse_cm == pytest.approx(math.sqrt((1.0 + 0.04) / 2), abs=1e-5)
    assert m.gt_0p5cm_pct == pytest.approx(50.0)
    assert m.coverage_pct == pytest.approx(200 / 3)
    assert m.band_abs_err_cm[0] == pytest.approx(1.0, abs=1e-5)
    assert m.band_abs_err_cm[-1] == pytest.approx(0.2, abs=1e-5)
    assert all(math.isnan(b) for b in m.band_abs_err_cm[1:-1])
    bands = m.to_dict()["band_abs_err_cm"]
    assert isinstance(bands, list) and len(bands) == 15


def test_accumulates_over_frames_and_checks_shapes() -> None:
    rng = np.random.default_rng(0)
    acc = MetricAccumulator(G)
    errs = []
    for _ in range(3):
        t = rng.normal(0, 0.02, G.shape).astype(np.float32)
        e = t + rng.normal(0, 0.005, G.shape).astype(np.float32)
        acc.add(e, t)
        errs.append(np.abs(e - t).ravel() * 100)
    every = np.concatenate(errs)
    m = acc.result()
    assert m.abs_err_cm == pytest.approx(every.mean(), rel=1e-4)
    # percentiles from the 0.001 cm histogram: within half a bin of numpy's order statistics
    assert m.median_abs_err_cm == pytest.approx(np.quantile(every, 0.5, method="inverted_cdf"), abs=6e-4)
    assert m.p95_abs_err_cm == pytest.approx(np.quantile(every, 0.95, method="inverted_cdf"), abs=6e-4)
    assert m.to_dict()["median_abs_err_cm"] == m.median_abs_err_cm
    with pytest.raises(ValueError, match="must match grid"):
        acc.add(np.zeros((3, 3)), np.zeros((3, 3)))


def test_no_estimates_gives_nan_not_zero() -> None:
    acc = MetricAccumulator(G)
    acc.add(np.full(G.shape, np.nan), np.zeros(G.shape))
    m = acc.result()
    assert math.isnan(m.abs_err_cm) and m.coverage_pct == 0.0
    assert math.isnan(m.median_abs_err_cm) and math.isnan(m.p95_abs_err_cm)


def test_percentiles_see_a_heavy_tail_that_the_mean_mixes_in() -> None:
    truth = np.zeros(G.shape, dtype=np.float32)
    est = np.full(G.shape, 0.001, dtype=np.float32)  # 0.1 cm everywhere ...
    est[:8] = 0.5  # ... and 50 cm (more than the histogram holds) on 8 of 164 rows (4.9 %)
    acc = MetricAccumulator(G)
    acc.add(est, truth)
    m = acc.result()
    assert m.median_abs_err_cm == pytest.approx(0.1, abs=6e-4)
    assert m.p95_abs_err_cm == pytest.approx(0.1, abs=6e-4)
    assert m.abs_err_cm > 2.0
    est[:9] = 1.5  # 150 cm: beyond the histogram's range, counted in its top bin
    acc = MetricAccumulator(G)
    acc.add(est, truth)
    assert acc.result().p95_abs_err_cm > 99.0


def test_reliability_curve_of_an_honest_gaussian_sigma_lies_on_the_diagonal() -> None:
    from roadbev_lab.evaluation.metrics import reliability_curve, reliability_histogram

    rng = np.random.default_rng(1)
    sigma = rng.choice([0.15, 0.4, 1.2], 200_000)  # cm
    error = np.abs(rng.normal(0.0, sigma))
    counts, sigma_sum = reliability_histogram(error, sigma)
    curve = reliability_curve(counts, sigma_sum)
    assert [round(b["mean_sigma_cm"], 2) for b in curve] == [0.15, 0.4, 1.2]
    for b in curve:
        assert b["q68_abs_err_cm"] == pytest.approx(b["mean_sigma_cm"], rel=0.06, abs=0.01)
        assert b["q95_abs_err_cm"] == pytest.approx(2 * b["mean_sigma_cm"], rel=0.06, abs=0.01)
    # an overconfident sigma lies above it
    counts, sigma_sum = reliability_histogram(3 * error, sigma)
    assert all(b["q68_abs_err_cm"] > 2 * b["mean_sigma_cm"] for b in reliability_curve(counts, sigma_sum))


def test_sigma_accumulator_sums_frames_as_one_and_scores_like_sigma_counts() -> None:
    from roadbev_lab.evaluation.metrics import (
        SigmaAccumulator,
        reliability_curve,
        reliability_histogram,
        sigma_counts,
        sigma_metrics,
    )

    rng = np.random.default_rng(3)
    truth = rng.normal(0.0, 0.02, (2, *G.shape))
    sigma = rng.choice([0.001, 0.004, 0.02], (2, *G.shape))
    estimate = truth + rng.normal(0.0, 1.0, truth.shape) * sigma * rng.choice([1.0, 5.0], truth.shape, p=[0.9, 0.1])
    estimate[0, :5] = np.nan  # no estimate
    sigma[1, -3:] = np.nan  # no sigma
    truth[1, 7] = np.nan  # no label
    acc = SigmaAccumulator()
    for k in range(2):
        acc.add(estimate[k], sigma[k], truth[k])
    result = acc.result()
    counts = sigma_counts(estimate[0], sigma[0], truth[0]) + sigma_counts(estimate[1], sigma[1], truth[1])
    assert {k: v for k, v in result.items() if k != "reliability"} == sigma_metrics(counts)
    usable = np.isfinite(estimate) & np.isfinite(sigma) & np.isfinite(truth)
    assert result["sigma_cells"] == int(usable.sum()) == (2 * G.n_rows - 5 - 3 - 1) * G.n_cols
    error_cm = 100.0 * np.abs(estimate[usable] - truth[usable])
    whole = reliability_curve(*reliability_histogram(error_cm, 100.0 * sigma[usable]))  # one frame of both
    assert len(result["reliability"]) == len(whole) == 3  # type: ignore[arg-type]
    for summed, one in zip(result["reliability"], whole, strict=True):  # type: ignore[call-overload]
        assert summed == pytest.approx(one, rel=1e-12)
    assert 0.0 < float(result["confident_wrong_pct"]) < 10.0  # type: ignore[arg-type]


def test_sigma_accumulator_without_a_frame_has_no_score_and_refuses_mismatched_maps() -> None:
    from roadbev_lab.evaluation.metrics import SigmaAccumulator

    acc = SigmaAccumulator()
    result = acc.result()
    assert result["sigma_cells"] == 0 and math.isnan(float(result["within_2sigma_pct"]))  # type: ignore[arg-type]
    assert result["reliability"] == []
    with pytest.raises(ValueError, match="must match"):
        acc.add(np.zeros(G.shape), np.zeros((2, 2)), np.zeros(G.shape))


def test_distance_bands_are_whole_metres_cut_to_the_grid() -> None:
    far = GridSpec(x_min=7.08, x_max=15.0, resolution=0.12, z_min=-0.5, z_max=0.5)
    band_of_row, edges = distance_bands(far)
    assert edges.tolist() == [[7.08, 8.0]] + [[float(x), float(x + 1)] for x in range(8, 15)]
    x = far.x_centres()
    assert band_of_row.tolist() == (np.floor(x) - 7).astype(int).tolist()  # row 0 (farthest) in the last band
    assert distance_bands(G, 2.0)[1].tolist() == [[2.16, 4.0], [4.0, 6.0], [6.0, 7.08]]
    with pytest.raises(ValueError, match="positive"):
        distance_bands(G, 0.0)


def test_band_accumulator_by_hand() -> None:
    far = GridSpec(x_min=7.08, x_max=9.0, resolution=0.12, z_min=-0.5, z_max=0.5)  # 16 rows: 8 in 7.08-8, 8 in 8-9
    acc = BandAccumulator(far)
    truth = np.zeros(far.shape, np.float32)
    estimate = np.full(far.shape, np.nan, np.float32)
    sigma = np.full(far.shape, 0.01, np.float32)
    near_rows, far_rows = far.x_centres() < 8.0, far.x_centres() >= 8.0
    estimate[near_rows] = 0.005  # 0.5 sigma everywhere in 7.08-8 m
    estimate[np.flatnonzero(far_rows)[0], :8] = 0.05  # half a row of 8-9 m: 5 cm at 1 cm sigma, confidently wrong
    truth[np.flatnonzero(far_rows)[-1]] = np.nan  # one row of 8-9 m unlabelled
    for _ in range(2):
        acc.add(estimate, sigma, truth)
    near, farther = acc.result()
    assert (near["x_from_m"], near["x_to_m"], farther["x_from_m"], farther["x_to_m"]) == (7.08, 8.0, 8.0, 9.0)
    assert near["labelled_cells"] == near["cells"] == 2 * 8 * 16 and near["coverage_pct"] == 100.0
    assert near["abs_err_cm"] == pytest.approx(0.5) and near["within_1sigma_pct"] == 100.0
    assert near["confident_wrong_pct"] == 0.0
    assert farther["labelled_cells"] == 2 * 7 * 16 and farther["cells"] == 2 * 8
    assert farther["coverage_pct"] == pytest.approx(100.0 * 8 / (7 * 16))
    assert farther["abs_err_cm"] == pytest.approx(5.0) and farther["confident_wrong_pct"] == 100.0
    empty = BandAccumulator(far).result()[0]
    assert empty["cells"] == 0 and math.isnan(empty["abs_err_cm"]) and math.isnan(empty["coverage_pct"])
    with pytest.raises(ValueError, match="must match"):
        acc.add(estimate[:-1], sigma[:-1], truth[:-1])
