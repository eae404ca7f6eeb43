"""evaluate(): metrics against known answers, coverage, timing groups, JSON keys, errors."""

from __future__ import annotations

import json
import math
from typing import NamedTuple

import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame
from roadbev_core.geometry import Attitude
from roadbev_lab.evaluation.frames import (
    CONTRACT_KEYS,
    EvaluationError,
    common_cell_errors,
    evaluate,
    format_table,
    stage_group,
)

GRID = GridSpec().scaled(2)  # 82 x 32
CAMERA = StereoCamera.rsrd_half().scaled(0.25)


class _Labelled(NamedTuple):
    frame: Frame
    truth: np.ndarray | None


class OffsetBackend:
    """Answers truth + offset (looked up by stamp), NaN in the first ``holes`` rows."""

    name = "offset"
    needs_stereo = False

    def __init__(self, truths: dict[int, np.ndarray], offset: float, holes: int = 0) -> None:
        self.grid = GRID
        self.truths = truths
        self.offset = offset
        self.holes = holes

    def estimate(self, frame: Frame) -> Estimate:
        elevation = self.truths[frame.stamp_ns] + np.float32(self.offset)
        elevation[: self.holes] = np.nan
        return Estimate(
            elevation, np.full_like(elevation, 0.01), {"preprocess": 1.0, "projection": 2.0, "cost": 3.0, "post": 4.0}
        )


def _frames(n: int) -> tuple[list[_Labelled], dict[int, np.ndarray]]:
    rng = np.random.default_rng(0)
    image = np.zeros((CAMERA.height, CAMERA.width), dtype=np.uint8)
    samples, truths = [], {}
    for i in range(n):
        truth = rng.normal(0.0, 0.03, GRID.shape).astype(np.float32)
        truth[:, 0] = np.nan  # unlabelled column
        truths[i] = truth
        samples.append(_Labelled(Frame(image, image, CAMERA, Attitude(), stamp_ns=i), truth))
    return samples, truths


def test_known_offset_gives_known_metrics() -> None:
    samples, truths = _frames(3)
    result = evaluate(OffsetBackend(truths, 0.004), samples)
    m = result.metrics
    assert set(CONTRACT_KEYS) <= set(m)
    assert m["backend"] == "offset" and m["frames"] == 3
    assert m["abs_err_cm"] == pytest.approx(0.4, abs=1e-4)
    assert m["rmse_cm"] == pytest.approx(0.4, abs=1e-4)
    assert m["gt_0p5cm_pct"] == 0.0
    assert m["coverage_pct"] == pytest.approx(100.0)
    assert m["cells"] == 3 * GRID.n_rows * (GRID.n_cols - 1)
    assert len(m["band_abs_err_cm"]) == 15
    assert m["band_abs_err_cm"] == pytest.approx([0.4] * 15, abs=1e-4)
    assert m["fps"] > 0 and m["timed_frames"] == 2  # frame 0 is the warm-up
    assert len(result.per_frame) == 3 and result.estimates is None


def test_missing_estimates_lower_coverage_not_error() -> None:
    samples, truths = _frames(2)
    holes = GRID.n_rows // 2
    m = evaluate(OffsetBackend(truths, 0.01, holes=holes), samples).metrics
    assert m["coverage_pct"] == pytest.approx(100.0 * (GRID.n_rows - holes) / GRID.n_rows)
    assert m["abs_err_cm"] == pytest.approx(1.0, abs=1e-4)
    assert m["gt_0p5cm_pct"] == pytest.approx(100.0)
    # The far bands (rows 0.. holes) got no estimate: NaN, which the JSON writes as null.
    assert math.isnan(m["band_abs_err_cm"][-1]) and not math.isnan(m["band_abs_err_cm"][0])
    text = json.dumps(evaluate(OffsetBackend(truths, 0.01, holes=holes), samples).to_dict(), allow_nan=False)
    assert json.loads(text)["band_abs_err_cm"][-1] is None


def test_stage_groups_and_table() -> None:
    samples, truths = _frames(3)
    result = evaluate(OffsetBackend(truths, 0.0), samples, keep_estimates=True)
    stages = result.metrics["stage_ms"]
    assert stages["projection"] == pytest.approx(2.0)
    assert stages["cost_network"] == pytest.approx(3.0)
    assert stages["post"] == pytest.approx(4.0)
    assert stages["decode"] >= 1.0  # bag decoding + the backend's preprocess
    assert result.estimates is not None and len(result.estimates) == 3
    assert stage_group("matching") == "cost_network" and stage_group("mystery") == "other"
    table = format_table([result.to_dict()])
    assert "offset" in table and "0.000" in table


def test_frames_without_truth_are_timed_not_scored() -> None:
    samples, truths = _frames(3)
    samples[1] = _Labelled(samples[1].frame, None)
    calls: list[int] = []
    m = evaluate(OffsetBackend(truths, 0.002), samples, progress=calls.append).metrics
    assert m["frames"] == 3 and m["frames_with_truth"] == 2 and calls == [1, 1, 1]
    assert evaluate(OffsetBackend(truths, 0.002), samples, max_frames=1).metrics["frames"] == 1


def test_plain_pairs_and_label_objects_are_accepted() -> None:
    samples, truths = _frames(2)

    class Label(NamedTuple):
        elevation: np.ndarray

    pairs = [(s.frame, Label(s.truth)) for s in samples if s.truth is not None]
    assert len(pairs) == len(samples)
    assert evaluate(OffsetBackend(truths, 0.001), pairs).metrics["abs_err_cm"] == pytest.approx(0.1, abs=1e-4)


def test_bad_input() -> None:
    samples, truths = _frames(1)
    backend = OffsetBackend(truths, 0.0)
    with pytest.raises(EvaluationError, match="no frames"):
        evaluate(backend, [])
    with pytest.raises(EvaluationError, match="ground truth"):
        evaluate(backend, [(samples[0].frame, np.zeros((3, 3), np.float32))])
    with pytest.raises(EvaluationError, match="sample"):
        evaluate(backend, [42])
    with pytest.raises(EvaluationError, match="max_frames"):
        evaluate(backend, samples, max_frames=0)


def test_common_cell_errors_compare_on_the_cells_both_estimated() -> None:
    truth = np.zeros((2, 3), np.float32)
    truth[0, 0] = np.nan  # unlabelled: never counted
    first = np.full((2, 3), 0.01, np.float32)  # 1 cm everywhere
    second = np.full((2, 3), np.nan, np.float32)
    second[1, :] = -0.03  # 3 cm, only on row 1
    second[0, 0] = 0.0  # estimated but unlabelled
    cells, first_cm, second_cm = common_cell_errors([first, first], [second, second], [truth, None])
    assert cells == 3  # row 1 of the first frame; the second frame has no truth
    assert first_cm == pytest.approx(1.0, abs=1e-4) and second_cm == pytest.approx(3.0, abs=1e-4)
    assert np.isnan(common_cell_errors([first], [np.full((2, 3), np.nan)], [truth])[1])
    with pytest.raises(ValueError):
        common_cell_errors([first], [first, first], [truth])


def test_uncertainty_calibration_counts_errors_inside_one_and_two_sigma() -> None:
    samples, truths = _frames(2)  # the backend reports 1 cm everywhere
    inside = evaluate(OffsetBackend(truths, 0.004), samples).metrics
    assert inside["within_1sigma_pct"] == 100.0 and inside["within_2sigma_pct"] == 100.0
    between = evaluate(OffsetBackend(truths, -0.015, holes=4), samples).metrics
    assert between["within_1sigma_pct"] == 0.0 and between["within_2sigma_pct"] == 100.0
    assert between["sigma_cells"] == 2 * (GRID.n_rows - 4) * (GRID.n_cols - 1)
    unscored = evaluate(OffsetBackend(truths, 0.0), [_Labelled(s.frame, None) for s in samples]).metrics
    assert unscored["sigma_cells"] == 0 and math.isnan(unscored["within_1sigma_pct"])


class _FarLabelled(NamedTuple):
    frame: Frame
    truth: np.ndarray | None
    far_truth: np.ndarray | None


class _OneCentimetre:
    """1 cm above the reference plane with a 0.5 cm sigma on any grid, the far-field one too."""

    name = "one_cm"
    needs_stereo = False
    far_field = True

    def __init__(self, grid: GridSpec) -> None:
        self.grid = grid

    def estimate(self, frame: Frame) -> Estimate:
        return Estimate(np.full(self.grid.shape, 0.01, np.float32), np.full(self.grid.shape, 0.005, np.float32))


def test_the_far_field_is_scored_per_band_when_the_samples_carry_its_truth() -> None:
    from roadbev_core.config import RoadbevConfig
    from roadbev_core.pipeline import Pipeline

    def pipeline(far: bool) -> Pipeline:
        config = RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": far})
        return Pipeline(config, backend_factory=lambda name, grid, **o: _OneCentimetre(grid), configure_process=False)

    far_grid = pipeline(True).config.far_grid
    assert far_grid is not None
    image = np.zeros((CAMERA.height, CAMERA.width), dtype=np.uint8)
    far_truth = np.zeros(far_grid.shape, np.float32)
    far_truth[:, 0] = np.nan
    samples = [_FarLabelled(Frame(image, image, CAMERA, Attitude.from_degrees(0.0, 19.0), stamp_ns=i),
                            np.zeros(GridSpec().shape, np.float32), far_truth) for i in range(2)]
    metrics = evaluate(pipeline(True), samples).metrics
    far = metrics["far_field"]
    assert far["estimated"] and far["grid"] == far_grid.to_dict() and far["frames_with_truth"] == 2
    assert far["abs_err_cm"] == pytest.approx(1.0) and far["coverage_pct"] == 100.0
    assert far["labelled_cells"] == 2 * far_grid.n_rows * (far_grid.n_cols - 1)
    assert far["within_2sigma_pct"] == 100.0 and far["confident_wrong_pct"] == 0.0
    assert far["band_m"] == 1.0 and [b["x_from_m"] for b in far["bands"]] == [7.08, *range(8, 15)]
    assert all(b["abs_err_cm"] == pytest.approx(1.0) for b in far["bands"])
    assert metrics["abs_err_cm"] == pytest.approx(1.0)  # the grid's own keys are there as always
    json.dumps(metrics)
    # no far-field truth, or the far field off: no key (the JSON is the one before the far field)
    assert "far_field" not in evaluate(pipeline(True), [(s.frame, s.truth) for s in samples]).metrics
    assert "far_field" not in evaluate(pipeline(False), samples).metrics
    with pytest.raises(EvaluationError, match="far-field ground truth is"):
        evaluate(pipeline(True), [samples[0]._replace(far_truth=far_truth[1:])])
