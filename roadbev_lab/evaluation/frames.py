"""Run the pipeline over frames with ground truth and report the paper's metrics and the timing.

Shared by ``roadbev eval``, the demo and the benchmarks, so a number in one is the number in
all: every frame goes through :class:`roadbev_core.pipeline.Pipeline` (recorded IMU samples
through :class:`roadbev_core.pipeline.ImuFeed`, the node's attitude path). Accuracy comes from
:class:`roadbev_lab.evaluation.metrics.MetricAccumulator` (labelled cells only; a labelled cell without an
estimate lowers ``coverage_pct`` and never counts as zero error). Time is wall time on this
machine:

* ``decode``: getting the next sample from the iterable (reading and decoding a bag's messages)
  plus the backend's own image preparation (``preprocess``: colour conversion, tensors);
* ``projection``: voxel/point geometry;
* ``cost_network``: sampling, matching costs, aggregation, or the network;
* ``post``: decisions, reprojection, binning, uncertainty.

With the far field on (``far_field.enabled``) and samples that carry its truth (``far_truth``),
the far-field grid is scored too: the ``far_field`` key (:func:`far_field_metrics`: the metrics of
the whole far grid and per band of 1 m); without far truth the key is absent.

``fps`` is frames per second of the whole pipeline (decode + attitude + estimate + preview). The first frame is a
warm-up (lazy initialisation, allocator growth): when more than one frame runs, it counts for the
accuracy but not for the timing.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import PurePath
from typing import Any, cast, overload

import numpy as np

from roadbev_core.attitude import ImuSample
from roadbev_core.backends import Backend
from roadbev_core.config import GridSpec, RoadbevConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame
from roadbev_core.pipeline import CameraInput, ImuFeed, OdometryFeed, Pipeline, PipelineOutput
from roadbev_lab.evaluation.metrics import (
    BandAccumulator,
    MetricAccumulator,
    Metrics,
    SigmaAccumulator,
)

__all__ = [
    "CONTRACT_KEYS",
    "STAGE_GROUPS",
    "TIMING_KEYS",
    "EvalResult",
    "EvalSums",
    "EvaluationError",
    "common_cell_errors",
    "evaluate",
    "far_field_metrics",
    "format_table",
    "json_safe",
    "stage_group",
    "to_json",
    "without_timing",
]

# Keys every metrics dict carries (docs/interface/evaluation.md: roadbev eval --json).
CONTRACT_KEYS: tuple[str, ...] = (
    "backend",
    "frames",
    "cells",
    "abs_err_cm",
    "rmse_cm",
    "gt_0p5cm_pct",
    "band_abs_err_cm",
    "fps",
    "coverage_pct",
)

# Keys of a metrics dict that are wall time on the machine that ran it: everything else is a
# function of the frames and the settings, the same wherever and alongside whatever it ran.
TIMING_KEYS: tuple[str, ...] = ("fps", "pipeline_ms", "stage_ms", "backend_stage_ms")

# Backend stage names (Estimate.timings_ms keys) -> the four reported groups.
STAGE_GROUPS: dict[str, tuple[str, ...]] = {
    "decode": ("decode", "preprocess"),
    "projection": ("projection",),
    "cost_network": ("sampling", "cost", "aggregation", "matching", "network", "backbone", "head", "features"),
    "post": ("post", "reprojection", "binning", "postprocess"),
}


class EvaluationError(RoadbevError, ValueError):
    """Samples that cannot be evaluated (none at all, or truth on another grid)."""


def stage_group(stage: str) -> str:
    """The reported group of a backend stage name (``other`` when unknown)."""
    for group, names in STAGE_GROUPS.items():
        if stage in names:
            return group
    return "other"


def without_timing(metrics: dict[str, Any]) -> dict[str, Any]:
    """``metrics`` without the :data:`TIMING_KEYS`: what two runs of the same evaluation agree on."""
    return {k: v for k, v in metrics.items() if k not in TIMING_KEYS}


@dataclass
class EvalSums:
    """What an evaluation's metrics are computed from, as sums that add up over evaluations: the
    metrics of several evaluations pooled (:meth:`merge`) are those of all their frames at once,
    never an average of their means.

    Attributes:
        backend: the backend's name.
        accuracy: the accuracy sums and error histogram (:class:`MetricAccumulator`).
        sigma: the uncertainty sums and reliability histograms (:class:`SigmaAccumulator`).
        frames: frames evaluated.
        timed_frames: frames timed (each evaluation's first frame is its warm-up).
        decode_ms_sum, estimate_ms_sum: milliseconds summed over the timed frames.
        stage_ms_sum: the backend's stage name -> milliseconds summed over the timed frames.
    """

    backend: str
    accuracy: MetricAccumulator
    sigma: SigmaAccumulator
    frames: int
    timed_frames: int
    decode_ms_sum: float
    estimate_ms_sum: float
    stage_ms_sum: dict[str, float] = field(default_factory=dict)

    def merge(self, other: EvalSums) -> EvalSums:
        """These sums and ``other``'s added, as a new object.

        Raises:
            ValueError: another backend, or accuracy on another grid.
        """
        if other.backend != self.backend:
            raise ValueError(f"cannot pool backend {other.backend!r} into {self.backend!r}")
        accuracy = MetricAccumulator.from_state(self.accuracy.grid, self.accuracy.state())
        accuracy.merge(other.accuracy)
        sigma = SigmaAccumulator.from_state(self.sigma.state())
        sigma.merge(other.sigma)
        stages = dict(self.stage_ms_sum)
        for stage, ms in other.stage_ms_sum.items():
            stages[stage] = stages.get(stage, 0.0) + ms
        return EvalSums(self.backend, accuracy, sigma, self.frames + other.frames,
                        self.timed_frames + other.timed_frames, self.decode_ms_sum + other.decode_ms_sum,
                        self.estimate_ms_sum + other.estimate_ms_sum, stages)

    def metrics(self) -> dict[str, Any]:
        """The metrics dict of :class:`EvalResult` (the interface's keys, timing and uncertainty)."""
        scored = self.accuracy.result()
        metrics = _metrics(self.backend, scored, self.frames, self.timed_frames, self.decode_ms_sum,
                           self.estimate_ms_sum, self.stage_ms_sum)
        # Calibration of the reported 1-sigma uncertainty: a Gaussian would put 68.3 / 95.4 / 99.7 % inside.
        metrics.update(self.sigma.result())
        return metrics


@dataclass
class EvalResult:
    """What :func:`evaluate` measured.

    Attributes:
        accuracy: the accuracy metrics, typed (the same type the online evaluation reports).
        metrics: the interface's keys (:data:`CONTRACT_KEYS`) plus ``labelled_cells``,
            ``frames_with_truth``, ``timed_frames``, ``pipeline_ms`` (mean per timed frame),
            the calibration of the uncertainty (``sigma_cells`` with a finite uncertainty,
            ``within_1sigma_pct`` / ``within_2sigma_pct`` of them with the error inside 1 / 2
            sigma; NaN without any),
            ``stage_ms`` (the four groups + ``other``) and ``backend_stage_ms`` (the backend's own
            stage names).
        sums: the sums the metrics were computed from (to pool them with other evaluations').
        per_frame: one dict per frame: ``stamp_ns``, ``abs_err_cm``, ``coverage_pct`` (NaN
            without truth), ``decode_ms``, ``estimate_ms``.
        estimates: the backend's estimates, in order (only with ``keep_estimates``).
        outputs: the pipeline's outputs (estimate + preview), in order (only with ``keep_estimates``).
        first: the first frame's output (always kept: its frame as decoded, with the attitude the
            pipeline gave it, and its estimate; ``roadbev eval``'s self-check looks at it).
        refused: reason -> frames the pipeline refused (no attitude, a malformed frame); they
            count as missing for the metrics.
    """

    metrics: dict[str, Any]
    accuracy: Metrics
    sums: EvalSums
    per_frame: list[dict[str, float]] = field(default_factory=list)
    estimates: list[Estimate] | None = None
    outputs: list[PipelineOutput] | None = None
    refused: dict[str, int] = field(default_factory=dict)
    first: PipelineOutput | None = None

    def to_dict(self, *, per_frame: bool = False) -> dict[str, Any]:
        """JSON-able metrics (NaN becomes null), optionally with the per-frame records."""
        out = json_safe(dict(self.metrics))
        if per_frame:
            out["per_frame"] = json_safe(self.per_frame)
        return cast("dict[str, Any]", out)


@overload
def json_safe(value: dict[Any, Any]) -> dict[str, Any]: ...


@overload
def json_safe(value: list[Any] | tuple[Any, ...]) -> list[Any]: ...


@overload
def json_safe(value: object) -> object: ...


def json_safe(value: object) -> object:
    """NaN/inf -> None, numpy scalars and arrays -> Python, paths -> text, recursively (strict JSON
    has no NaN)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def to_json(value: object) -> str:
    """Strict JSON text of a result (NaN/inf as null, numpy scalars as numbers), indented: the one
    serialiser of every result the project writes."""
    return json.dumps(json_safe(value), indent=2, default=str) + "\n"


def common_cell_errors(
    first: Iterable[np.ndarray], second: Iterable[np.ndarray], truths: Iterable[np.ndarray | None]
) -> tuple[int, float, float]:
    """Mean abs. error (cm) of two backends over the cells both estimated and the truth labels.

    A backend that leaves hard cells empty scores better on its own cells than one that fills
    them; on the common cells the two are compared on the same ground.

    Args:
        first, second: per-frame [n_rows, n_cols] elevation (m, NaN = no estimate), same frames.
        truths: per-frame truth (m, NaN = unlabelled; None = a frame without truth, skipped).

    Returns:
        (cells, abs. err. of ``first`` in cm, abs. err. of ``second`` in cm); NaN errors when no
        cell is common.
    """
    cells, sum_first, sum_second = 0, 0.0, 0.0
    for a, b, truth in zip(first, second, truths, strict=True):
        if truth is None:
            continue
        both = np.isfinite(a) & np.isfinite(b) & np.isfinite(truth)  # [R, C]
        cells += int(both.sum())
        sum_first += float(np.abs(a[both] - truth[both]).astype(np.float64).sum())
        sum_second += float(np.abs(b[both] - truth[both]).astype(np.float64).sum())
    if cells == 0:
        return 0, math.nan, math.nan
    return cells, 100.0 * sum_first / cells, 100.0 * sum_second / cells


def _label_array(truth: Any) -> np.ndarray | None:
    """A truth as [n_rows, n_cols] float32 metres (an ``ElevationLabel``'s elevation), or None."""
    if truth is not None and hasattr(truth, "elevation"):
        truth = truth.elevation
    return None if truth is None else np.asarray(truth, dtype=np.float32)


def _unpack(sample: Any) -> tuple[CameraInput, Frame | None, np.ndarray | None, np.ndarray | None]:
    """(camera set, frame when its attitude is known, truth [n_rows, n_cols] or None, far-field
    truth or None) of a sample: a (frame or camera set, truth) pair or an object with
    ``.frame``/``.inputs`` and ``.truth`` (and maybe ``.far_truth``: an ``EvalSample``, a synthetic
    ``DriveSample`` whose truths are ``ElevationLabel``s)."""
    far_truth = None
    if hasattr(sample, "truth") and (hasattr(sample, "frame") or hasattr(sample, "inputs")):
        item, truth = getattr(sample, "frame", None) or sample.inputs, sample.truth
        far_truth = getattr(sample, "far_truth", None)
    else:
        try:
            item, truth = sample
        except (TypeError, ValueError):
            raise EvaluationError(
                f"a sample must be (frame, truth) or have .frame and .truth, got {type(sample).__name__}"
            ) from None
    if isinstance(item, Frame):
        frame: Frame | None = item
        inputs = CameraInput(item.left, item.right, item.camera, item.stamp_ns)
    elif isinstance(item, CameraInput):
        frame, inputs = None, item
    else:
        raise EvaluationError(f"sample frame must be a Frame or CameraInput, got {type(item).__name__}")
    return inputs, frame, _label_array(truth), _label_array(far_truth)


def pipeline_for(backend: Backend, config: RoadbevConfig | None = None) -> Pipeline:
    """A pipeline around an already built backend (benchmarks and tests that build their own),
    with ``config``'s other settings (the defaults when None) and the backend's grid; the far field
    off (it needs a second backend on its own grid: run a :class:`Pipeline` for it)."""
    base = config or RoadbevConfig()
    config = replace(base, grid=backend.grid, backend=replace(base.backend, name=backend.name),
                     far_field=replace(base.far_field, enabled=False))
    return Pipeline(config, backend_factory=lambda *_args, **_options: backend, configure_process=False)


def evaluate(
    runner: Pipeline | Backend,
    samples: Iterable[Any],
    *,
    imu: Iterable[ImuSample] | None = None,
    progress: Callable[[int], object] | None = None,
    keep_estimates: bool = False,
    max_frames: int | None = None,
    on_output: Callable[[PipelineOutput], object] | None = None,
    odometry: Iterable[PlanarPose] | None = None,
) -> EvalResult:
    """Run the pipeline on every sample and measure accuracy and speed.

    Args:
        runner: a :class:`Pipeline`, or a backend (wrapped by :func:`pipeline_for`).
        samples: (frame or camera set, truth) pairs or objects with ``.frame``/``.inputs`` and
            ``.truth``; truth is [n_rows, n_cols] metres with NaN = no label (or an
            ``ElevationLabel``, or None for a frame without ground truth: it is timed but not
            scored). A :class:`Frame` carries its attitude; a :class:`CameraInput` takes it from
            ``imu``.
        imu: IMU samples in stamp order, fed to the pipeline in time order with the frames.
        odometry: ``base_link`` poses in stamp order, fed likewise (the map's ego-motion).
        progress: called with 1 after each frame (e.g. ``tqdm.update``).
        keep_estimates: keep every :class:`Estimate` and output in the result (memory!).
        max_frames: stop after this many frames (None = all).
        on_output: called with every output (e.g. to write what the node would publish).

    Returns:
        An :class:`EvalResult`.

    Raises:
        EvaluationError: no samples, or truth/estimates not on the pipeline's grid.
    """
    if max_frames is not None and max_frames < 1:
        raise EvaluationError(f"max_frames must be >= 1, got {max_frames}")
    pipeline = runner if isinstance(runner, Pipeline) else pipeline_for(runner)
    grid = pipeline.config.grid
    feed = ImuFeed(imu or ())
    odometry_feed = OdometryFeed(odometry or ())
    accumulator = MetricAccumulator(grid)
    per_frame: list[dict[str, float]] = []
    outputs: list[PipelineOutput] = []
    first: PipelineOutput | None = None
    refused: dict[str, int] = {}
    calibration = SigmaAccumulator()
    far_grid = pipeline.config.far_grid
    far: tuple[MetricAccumulator, SigmaAccumulator, BandAccumulator] | None = None
    stage_timings: list[dict[str, float]] = []
    iterator = iter(samples)
    frames = 0
    while max_frames is None or frames < max_frames:
        start = time.perf_counter()
        try:
            sample = next(iterator)
        except StopIteration:
            break
        inputs, frame, truth, far_truth = _unpack(sample)
        decoded = time.perf_counter()
        try:
            odometry_feed.until(pipeline, frame.stamp_ns if frame is not None else inputs.stamp_ns)
            if frame is not None:
                output = pipeline.process_frame(frame)
            else:
                feed.until(pipeline, inputs.stamp_ns)
                output = pipeline.process(inputs)
        except RoadbevError as exc:  # bad input: counted, the evaluation goes on
            reason = f"{type(exc).__name__}: {exc}"
            refused[reason] = refused.get(reason, 0) + 1
            if progress is not None:
                progress(1)
            continue
        except ValueError as exc:  # Estimate.check_grid: the backend answered on another grid
            raise EvaluationError(f"pipeline {pipeline.backend.name}: {exc}") from None
        done = time.perf_counter()
        if on_output is not None:
            on_output(output)
        if first is None:
            first = output
        estimate = output.estimate
        record = {
            "stamp_ns": int(inputs.stamp_ns),
            "abs_err_cm": math.nan,
            "coverage_pct": math.nan,
            "decode_ms": 1000.0 * (decoded - start),
            "estimate_ms": 1000.0 * (done - decoded),
        }
        if truth is not None:
            if truth.shape != grid.shape:
                raise EvaluationError(f"ground truth is {truth.shape} but the backend's grid is {grid.shape}")
            labelled = np.isfinite(truth)
            both = labelled & np.isfinite(estimate.elevation)
            if both.any():
                record["abs_err_cm"] = float(np.abs(estimate.elevation[both] - truth[both]).mean() * 100.0)
            record["coverage_pct"] = 100.0 * float(both.sum()) / max(int(labelled.sum()), 1)
            accumulator.add(estimate.elevation, truth)
            calibration.add(estimate.elevation, estimate.uncertainty, truth)
        if far_truth is not None and output.far is not None and far_grid is not None:
            if far_truth.shape != far_grid.shape:
                raise EvaluationError(f"far-field ground truth is {far_truth.shape} but the far-field grid is "
                                      f"{far_grid.shape}")
            far = far or (MetricAccumulator(far_grid), SigmaAccumulator(), BandAccumulator(far_grid))
            far[0].add(output.far.elevation, far_truth)
            far[1].add(output.far.elevation, output.far.uncertainty, far_truth)
            far[2].add(output.far.elevation, output.far.uncertainty, far_truth)
        per_frame.append(record)
        stage_timings.append(dict(estimate.timings_ms))
        if keep_estimates:
            outputs.append(output)
        frames += 1
        if progress is not None:
            progress(1)
    if frames == 0:
        detail = f" (refused: {refused})" if refused else ""
        raise EvaluationError(f"no frames to evaluate{detail}")
    first_timed = 1 if frames > 1 else 0  # frame 0 is the warm-up
    stage_sums: dict[str, float] = {}
    for timings in stage_timings[first_timed:]:
        for stage, ms in timings.items():
            stage_sums[stage] = stage_sums.get(stage, 0.0) + ms
    timed = per_frame[first_timed:]
    sums = EvalSums(pipeline.backend.name, accumulator, calibration, len(per_frame), len(timed),
                    sum(r["decode_ms"] for r in timed), sum(r["estimate_ms"] for r in timed), stage_sums)
    metrics = sums.metrics()
    if far is not None and far_grid is not None:
        metrics["far_field"] = far_field_metrics(far_grid, *far)
    return EvalResult(
        metrics=metrics,
        accuracy=accumulator.result(),
        per_frame=per_frame,
        estimates=[o.estimate for o in outputs] if keep_estimates else None,
        outputs=outputs if keep_estimates else None,
        refused=refused,
        first=first,
        sums=sums,
    )


def far_field_metrics(grid: GridSpec, scored: MetricAccumulator, sigma: SigmaAccumulator,
                      bands: BandAccumulator) -> dict[str, Any]:
    """The ``far_field`` key (docs/interface/evaluation.md): the far-field grid, its accuracy and
    uncertainty keys over every cell, and per band of ``bands.band_m`` metres."""
    accuracy = scored.result().to_dict()
    del accuracy["band_abs_err_cm"]  # the far grid's bands are whole metres (below)
    frames = accuracy.pop("frames")
    if not accuracy["labelled_cells"]:
        accuracy["coverage_pct"] = math.nan
    return {"estimated": True, "grid": grid.to_dict(), "frames_with_truth": frames, **accuracy, **sigma.result(),
            "band_m": bands.band_m, "bands": bands.result()}


def _metrics(
    name: str,
    scored: Metrics,
    frames: int,
    n_timed: int,
    decode_ms_sum: float,
    estimate_ms_sum: float,
    stage_sums: dict[str, float],
) -> dict[str, Any]:
    """The metrics dict of :class:`EvalResult` from the accumulated numbers (sums over the timed frames)."""
    decode_ms = decode_ms_sum / n_timed
    estimate_ms = estimate_ms_sum / n_timed
    pipeline_ms = decode_ms + estimate_ms
    backend_stage_ms = {stage: total / n_timed for stage, total in stage_sums.items()}
    groups = {group: 0.0 for group in (*STAGE_GROUPS, "other")}
    groups["decode"] = decode_ms
    for stage, ms in backend_stage_ms.items():
        groups[stage_group(stage)] += ms
    # Time inside estimate() that no stage claimed (Python overhead, result conversion).
    groups["other"] += max(0.0, estimate_ms - sum(backend_stage_ms.values()))
    return {
        "backend": name,
        "frames": frames,
        "cells": scored.cells,
        "abs_err_cm": scored.abs_err_cm,
        "rmse_cm": scored.rmse_cm,
        "gt_0p5cm_pct": scored.gt_0p5cm_pct,
        "band_abs_err_cm": scored.band_abs_err_cm,
        "fps": 1000.0 / pipeline_ms if pipeline_ms > 0 else math.inf,
        "coverage_pct": scored.coverage_pct if scored.labelled_cells else math.nan,
        "median_abs_err_cm": scored.median_abs_err_cm,
        "p95_abs_err_cm": scored.p95_abs_err_cm,
        "labelled_cells": scored.labelled_cells,
        "frames_with_truth": scored.frames,
        "timed_frames": n_timed,
        "pipeline_ms": pipeline_ms,
        "stage_ms": groups,
        "backend_stage_ms": backend_stage_ms,
    }


def _fmt(value: Any, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def format_table(results: Iterable[dict[str, Any]]) -> str:
    """A plain-text table (the paper's Table I columns + coverage and stage times) of metrics dicts."""
    header = (
        f"{'backend':<12} {'frames':>6} {'abs.err cm':>10} {'median cm':>9} {'RMSE cm':>8} {'>0.5cm %':>9} "
        f"{'coverage %':>10} {'FPS':>6} | {'decode':>7} {'proj.':>7} {'cost/net':>8} {'post':>7} ms"
    )
    lines = [header, "-" * len(header)]
    for m in results:
        stages = m.get("stage_ms", {})
        lines.append(
            f"{m['backend']:<12} {m['frames']:>6d} {_fmt(m['abs_err_cm'], 3):>10} "
            f"{_fmt(m.get('median_abs_err_cm'), 3):>9} {_fmt(m['rmse_cm'], 3):>8} "
            f"{_fmt(m['gt_0p5cm_pct'], 1):>9} {_fmt(m['coverage_pct'], 1):>10} {_fmt(m['fps'], 1):>6} | "
            f"{_fmt(stages.get('decode'), 1):>7} {_fmt(stages.get('projection'), 1):>7} "
            f"{_fmt(stages.get('cost_network'), 1):>8} {_fmt(stages.get('post'), 1):>7}"
        )
    return "\n".join(lines)
