"""One bag's task, as a worker runs it: evaluate it (``roadbev eval``) or label it (``roadbev label``).

A :class:`BagJob` names the bag, the key its result is stored under and the settings (an
:class:`EvalSettings` or :class:`LabelSettings`: plain picklable values, so that a worker on
another machine gets them whole). :func:`run_job` runs it and returns a :class:`BagResult`: the
record the one-bag command writes for it and the arrays its pooled metrics are computed from.
An error is raised as it is (the executor reports it for this bag only).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from roadbev_core.config import GridSpec, ImuConfig, RoadbevConfig, TopicsConfig
from roadbev_lab.data.labelbag import Extrinsic, label_bag
from roadbev_lab.data.lidar_labels import LabelConfig
from roadbev_lab.evaluation.offline import eval_record, evaluate_bag
from roadbev_lab.fleet.store import content_digest

__all__ = ["BagJob", "BagResult", "EvalSettings", "LabelSettings", "bag_digest", "run_job"]


@dataclass(frozen=True)
class EvalSettings:
    """What ``roadbev eval`` runs every bag with.

    Attributes:
        config: the user's settings (params file, backend, checkpoint), validated.
        grid_overrides: the grid fields among them (they win over each bag's own).
        map_enabled: ``--map`` (True), ``--no-map`` (False) or the settings' own (None).
        lead_time_s: the preview-at-arrival lead time.
        max_frames: evaluate only the first N frames (None: all).
        params_file: the params file's path as given (recorded in each bag's JSON).
    """

    config: RoadbevConfig
    grid_overrides: Mapping[str, float] = field(default_factory=dict)
    map_enabled: bool | None = None
    lead_time_s: float = 0.1
    max_frames: int | None = None
    params_file: str | None = None


@dataclass(frozen=True)
class LabelSettings:
    """What ``roadbev label`` labels every bag with (:func:`roadbev_lab.data.labelbag.label_bag`'s settings).

    Attributes:
        grid: the label grid.
        config: the labeller's settings.
        topics, imu: the node's topics and IMU settings.
        lidar_topic: the PointCloud2 topic (None: the default or the only one).
        extrinsic: LiDAR -> left optical frame where ``/tf_static`` does not say.
        camera_position_m: the left camera in ``base_link`` where ``/tf_static`` does not say.
    """

    grid: GridSpec
    config: LabelConfig
    topics: TopicsConfig
    imu: ImuConfig
    lidar_topic: str | None
    extrinsic: Extrinsic | None
    camera_position_m: Sequence[float]


@dataclass(frozen=True)
class BagJob:
    """One bag to evaluate or label.

    Attributes:
        bag: the bag (rosbag2 directory or ``.mcap`` file).
        key: the result store's key (bag content and configuration).
        settings: what to run it with.
        out: where a labelled bag goes (``roadbev label``; None for an evaluation).
    """

    bag: Path
    key: str
    settings: EvalSettings | LabelSettings
    out: Path | None = None


class BagResult(NamedTuple):
    """A finished bag: the record its one-bag command writes and the arrays to pool it (may be empty)."""

    record: dict[str, Any]
    arrays: dict[str, np.ndarray]


def bag_digest(bag: Path) -> str:
    """The bag's content digest (:func:`roadbev_lab.fleet.store.content_digest`), as a task."""
    return content_digest(bag)


def run_job(job: BagJob) -> BagResult:
    """Evaluate or label the job's bag (by the kind of its settings).

    Raises:
        whatever the one-bag command refuses the bag with (a damaged bag, a grid the backend cannot run...).
    """
    if isinstance(job.settings, EvalSettings):
        return _evaluate(job.bag, job.settings)
    if job.out is None:
        raise ValueError(f"label job for {job.bag} without an output path")
    return _label(job.bag, job.out, job.settings)


def _evaluate(bag: Path, settings: EvalSettings) -> BagResult:
    evaluation = evaluate_bag(bag, settings.config, grid_overrides=settings.grid_overrides,
                              map_enabled=settings.map_enabled, lead_time_s=settings.lead_time_s,
                              max_frames=settings.max_frames)
    record = eval_record(evaluation, bag, settings.params_file)
    return BagResult(record, evaluation.sums.to_arrays())


def _label(bag: Path, out: Path, settings: LabelSettings) -> BagResult:
    out.parent.mkdir(parents=True, exist_ok=True)
    # written beside its final name and renamed when complete: an interrupted task leaves no
    # half-written bag under the name a later run takes as done
    partial = out.with_name(f".{out.stem}.{os.getpid()}.partial{out.suffix}")
    try:
        report = label_bag(bag, partial, grid=settings.grid, config=settings.config, topics=settings.topics,
                           imu=settings.imu, lidar_topic=settings.lidar_topic, extrinsic=settings.extrinsic,
                           camera_position_m=list(settings.camera_position_m))
        partial.replace(out)
    finally:
        partial.unlink(missing_ok=True)
    record = {"bag": str(bag), "out": str(out), **report._asdict()}
    return BagResult(record, {})
