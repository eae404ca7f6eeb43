"""Offline evaluation of a bag: what ``roadbev eval`` runs, also for the demo (no DDS).

:func:`evaluate_bag` reads an evaluation bag (docs/interface/bags.md) with the user's settings (one
:class:`roadbev_core.config.RoadbevConfig`, whose topics read the bag), completes them with the
bag's grid (the ground truth's GridMap info) into the :class:`roadbev_core.pipeline.Pipeline`'s
config, mounts the camera from ``/tf_static`` where the bag has it, runs every frame (with the
bag's odometry: the fused map when it is on) and returns the metrics as ``roadbev eval --json``
writes them; on a drive bag with ground truth also the ``preview_at_arrival`` (and,
with the map, ``map``) keys (:func:`drive_keys`). The command only adds printing, the self-check
hint and ``--json``; the demo evaluates its drive with the map on and off through the same
function, so its numbers are ``roadbev eval``'s.

A bag with far-field truth (``/ground_truth/elevation_far``) turns the far field on, on the grid of
that truth, and the metrics carry the ``far_field`` key; a backend that does not estimate the far
field runs without it and the key says so (``estimated`` false, with the reason).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roadbev_core.config import ConfigError, FarFieldConfig, GridSpec, RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.pipeline import Pipeline, PipelineOutput, check_config
from roadbev_core.selfcheck import MIN_COVERAGE_PCT, self_check
from roadbev_lab.evaluation.arrival import ArrivalError, map_summary, map_window_rows, per_frame_previews
from roadbev_lab.evaluation.drivebag import is_drive_bag, read_drive_truth, score_preview_errors
from roadbev_lab.evaluation.evalbag import EvalBag, EvalSample, read_eval_bag
from roadbev_lab.evaluation.frames import EvalResult, evaluate, json_safe
from roadbev_lab.evaluation.pooled import BagSums

__all__ = [
    "BagEvaluation",
    "OfflineEvalError",
    "PreparedBag",
    "coverage_hint",
    "drive_keys",
    "eval_record",
    "evaluate_bag",
    "far_field_params",
    "prepare_bag",
    "run_prepared",
]


class OfflineEvalError(RoadbevError, ValueError):
    """The bag cannot be evaluated (unreadable, no frames, --map without odometry...); one line."""


@dataclass
class BagEvaluation:
    """What :func:`evaluate_bag` measured.

    Attributes:
        metrics: the JSON keys of ``roadbev eval`` (without ``bag``, ``grid``,
            ``backend_options`` and ``params_file``, which the command adds).
        result: the typed evaluation (its ``outputs`` kept on drive bags; its ``first`` output
            for the self-check).
        pipeline: the pipeline that ran (its config, its map's state).
        bag: the opened bag.
        drive: whether the bag is a drive bag (ground-truth poses and road map).
        sums: what the metrics were computed from, to pool them with other bags'
            (:mod:`roadbev_lab.evaluation.pooled`).
    """

    metrics: dict[str, Any]
    result: EvalResult
    pipeline: Pipeline
    bag: EvalBag
    drive: bool
    sums: BagSums


def _read_failures(samples: Iterable[EvalSample], path: Path) -> Iterator[EvalSample]:
    """Re-raise bag read/decode failures during iteration as a one-line OfflineEvalError."""
    iterator = iter(samples)
    while True:
        try:
            sample = next(iterator)
        except StopIteration:
            return
        except Exception as exc:  # rosbags/mcap raise many types for a damaged bag
            raise OfflineEvalError(f"cannot read bag {path}: {type(exc).__name__}: {exc}") from exc
        yield sample


def drive_keys(path: Path, config: RoadbevConfig, result: EvalResult, lead_time_s: float) -> dict[str, Any]:
    """The pipeline's previews at the wheels' arrival (per frame or from the map: each message
    says which) and, when the map ran, the fused map against the true road map: the
    ``preview_at_arrival`` and ``map`` keys of docs/interface/evaluation.md.

    Raises:
        OfflineEvalError: the drive's truth cannot score the previews.
    """
    return _drive_scores(path, config, result, lead_time_s)[0]


def _drive_scores(path: Path, config: RoadbevConfig, result: EvalResult,
                  lead_time_s: float) -> tuple[dict[str, Any], BagSums]:
    """:func:`drive_keys` and the drive's part of the bag's sums (wheel points, map window scores)."""
    stamps = [int(r["stamp_ns"]) for r in result.per_frame]
    outputs = result.outputs or []
    try:
        truth = read_drive_truth(path, base_frame=config.topics.base_frame, odom_topic=config.topics.odom)
        arrival, wheels = score_preview_errors(truth, per_frame_previews(outputs), stamps, config,
                                               lead_time_s=lead_time_s)
        windows = [o.map for o in outputs if o.map is not None]
        rows = (map_window_rows(windows, truth.road_map, truth.trajectory, config.vehicle, truth.odometry)
                if windows else None)
    except (ArrivalError, ValueError) as exc:
        raise OfflineEvalError(f"preview at arrival on {path}: {exc}") from exc
    keys: dict[str, Any] = {"preview_at_arrival": json_safe(arrival)}
    if rows is not None:
        keys["map"] = json_safe(map_summary(rows, len(windows)))
    return keys, BagSums(result.sums, lead_time_s=float(lead_time_s), wheels=wheels, map_rows=rows,
                         map_windows=len(windows))


@dataclass
class PreparedBag:
    """A bag opened for evaluation, with the pipeline its parameters and grid make.

    Attributes:
        path: the bag.
        bag: the opened bag.
        config: the pipeline's config (the user's settings, the map switch, the bag's grid).
        pipeline: the pipeline (the camera mounted from ``/tf_static`` where the bag has it).
        drive: whether the bag is a drive bag (ground-truth poses and road map).
    """

    path: Path
    bag: EvalBag
    config: RoadbevConfig
    pipeline: Pipeline
    drive: bool

    @property
    def far_refused(self) -> str:
        """Why the bag's far-field truth is not estimated (the backend has no far field), or ""."""
        return self.pipeline.far_field_off


def prepare_bag(
    path: str | Path,
    settings: RoadbevConfig | None = None,
    *,
    grid_overrides: Mapping[str, float] | None = None,
    map_enabled: bool | None = None,
) -> PreparedBag:
    """Open a bag and build its pipeline as ``roadbev eval`` does.

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        settings: what the user gave (params file, backend, checkpoint), validated; the defaults
            when None. Its topics read the bag; the bag's grid and the map switch complete it
            into the pipeline's config.
        grid_overrides: the grid fields among what the user gave
            (:func:`roadbev_lab.evaluation.evalbag.grid_fields`): they win over the bag's own.
        map_enabled: True (``--map``: needs odometry), False (``--no-map``), None (the
            settings' own: on when the bag has odometry).

    Raises:
        OfflineEvalError: the bag cannot be read, has no frames, or ``--map`` without odometry.
        ParamError: the settings do not work on the bag's grid.
    """
    path = Path(path)
    settings = settings or RoadbevConfig()
    try:
        bag = read_eval_bag(path, settings.topics, grid_overrides=grid_overrides)
    except (RoadbevError, OSError):
        raise
    except Exception as exc:  # a damaged bag: rosbags/mcap raise many types; one line, no traceback
        raise OfflineEvalError(f"cannot read bag {path}: {type(exc).__name__}: {exc}") from exc
    if map_enabled and not bag.odometry:
        raise OfflineEvalError(f"--map needs odometry: {path} has none on {bag.topics.odom}")
    map_params = {} if map_enabled is None else {"map.enabled": bool(map_enabled)}
    # the horizontal grid comes from the ground truth's GridMap info (docs/interface/bags.md)
    config = check_config(settings.with_params({**map_params, **bag.grid.to_dict(), **far_field_params(bag)}))
    pipeline = Pipeline(config)  # the grid is evaluated; the far-field key says why the far one is not
    if bag.camera_mount is not None:  # /tf_static base_link -> camera wins over vehicle.camera_position_m
        pipeline.set_camera_mount(*bag.camera_mount)
    if len(bag) == 0:
        raise OfflineEvalError(f"bag {path} has no complete frames to evaluate")
    # a drive bag: the previews are scored at the wheels' arrival too
    return PreparedBag(path, bag, pipeline.config, pipeline, is_drive_bag(path))


def far_field_params(bag: EvalBag) -> dict[str, Any]:
    """The far-field parameters of a bag with far-field truth (its grid), else none.

    Raises:
        OfflineEvalError: that truth is not on a far-field grid beyond the bag's grid.
    """
    far = bag.far_grid
    if far is None:
        return {}
    try:
        expected = FarFieldConfig(enabled=True, x_max=far.x_max, resolution=far.resolution, z_min=far.z_min,
                                  z_max=far.z_max).grid(bag.grid)
    except ConfigError as exc:
        raise OfflineEvalError(f"{bag.path}: the far-field ground truth is not on a far-field grid: {exc}") from None
    if expected != far:
        raise OfflineEvalError(f"{bag.path}: the far-field ground truth's grid (x {far.x_min:g}..{far.x_max:g} m, y "
                               f"{far.y_min:g}..{far.y_max:g} m) does not start at the grid's far edge "
                               f"({bag.grid.x_max:g} m) across its width")
    return {"far_field.enabled": True, "far_field.x_max": far.x_max, "far_field.resolution": far.resolution,
            "far_field.z_min": far.z_min, "far_field.z_max": far.z_max}


def run_prepared(
    prepared: PreparedBag,
    *,
    lead_time_s: float = 0.1,
    max_frames: int | None = None,
    progress: Callable[[int], object] | None = None,
    on_output: Callable[[PipelineOutput], object] | None = None,
) -> BagEvaluation:
    """Evaluate every frame of a prepared bag (see the module docstring).

    Args:
        lead_time_s: the preview-at-arrival lead time (drive bags).
        max_frames: evaluate only the first N frames.
        progress: called with 1 per frame.
        on_output: called with every :class:`roadbev_core.pipeline.PipelineOutput` (``--out``).

    Raises:
        OfflineEvalError: a frame cannot be read, or the drive's truth cannot score the previews.
    """
    bag, pipeline, path = prepared.bag, prepared.pipeline, prepared.path
    result = evaluate(pipeline, _read_failures(bag, path), imu=bag.imu, odometry=bag.odometry, progress=progress,
                      max_frames=max_frames, keep_estimates=prepared.drive, on_output=on_output)
    metrics = result.to_dict()
    sums = BagSums(result.sums)
    if pipeline.map_active or pipeline.fused is not None:
        metrics["map_enabled"] = sums.map_enabled = True
        if pipeline.map_skipped:
            metrics["map_skipped"] = dict(pipeline.map_skipped)
            sums.map_skipped = dict(pipeline.map_skipped)
    if prepared.far_refused and bag.far_grid is not None:
        metrics["far_field"] = {"estimated": False, "reason": prepared.far_refused, "grid": bag.far_grid.to_dict()}
    metrics["lost_frames"] = sums.lost_frames = bag.lost_frames()
    metrics["losses"] = bag.losses()
    if prepared.drive and metrics.get("frames_with_truth", 0) > 0:  # docs/interface/bags.md, "Drive bags"
        keys, drive = _drive_scores(path, prepared.config, result, lead_time_s)
        metrics.update(keys)
        sums.lead_time_s, sums.wheels = drive.lead_time_s, drive.wheels
        sums.map_rows, sums.map_windows = drive.map_rows, drive.map_windows
    return BagEvaluation(metrics, result, pipeline, bag, prepared.drive, sums)


def coverage_hint(first: PipelineOutput | None, grid: GridSpec, coverage_pct: float | None) -> str | None:
    """The self-check's one-line hint (:func:`roadbev_core.selfcheck.self_check` on the
    evaluation's first frame and its estimate) when the evaluation's coverage fell below the
    threshold; None otherwise."""
    if coverage_pct is None or coverage_pct >= MIN_COVERAGE_PCT or first is None:
        return None
    return self_check(first.estimate, first.frame, grid).message


def eval_record(evaluation: BagEvaluation, path: str | Path, params_file: str | Path | None = None) -> dict[str, Any]:
    """The JSON ``roadbev eval BAG --json OUT`` writes: the metrics, the self-check's hint where
    the bag has ground truth and the coverage fell below the threshold (``self_check``), then
    ``bag``, ``grid``, ``backend_options`` and, when one was given, ``params_file``."""
    metrics = dict(evaluation.metrics)
    if metrics.get("frames_with_truth", 0) > 0:
        config = evaluation.pipeline.config
        hint = coverage_hint(evaluation.result.first, config.grid, metrics.get("coverage_pct"))
        if hint:
            metrics["self_check"] = hint
    record = {**metrics, "bag": str(path), "grid": evaluation.bag.grid.to_dict(),
              "backend_options": evaluation.pipeline.config.backend.options_of()}
    if params_file:
        record["params_file"] = str(params_file)
    return record


def evaluate_bag(
    path: str | Path,
    settings: RoadbevConfig | None = None,
    *,
    grid_overrides: Mapping[str, float] | None = None,
    map_enabled: bool | None = None,
    lead_time_s: float = 0.1,
    max_frames: int | None = None,
    progress: Callable[[int], object] | None = None,
) -> BagEvaluation:
    """:func:`prepare_bag` then :func:`run_prepared` (``roadbev eval BAG [--map|--no-map]``)."""
    prepared = prepare_bag(path, settings, grid_overrides=grid_overrides, map_enabled=map_enabled)
    return run_prepared(prepared, lead_time_s=lead_time_s, max_frames=max_frames, progress=progress)
