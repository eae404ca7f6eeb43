"""Drive bags (docs/interface/bags.md, "Drive bags"): writing and reading the truth.

A drive bag is an evaluation bag (:mod:`roadbev_lab.evaluation.evalbag`) plus:

=========================  =============================  ===========================================
topic                      type                           content
=========================  =============================  ===========================================
/odom                      nav_msgs/Odometry              the vehicle's odometry (planar, drifting),
                                                          ``odom`` -> ``base_link``
/ground_truth/odom         nav_msgs/Odometry              the exact 6-DoF pose of ``base_link``
/tf_static                 tf2_msgs/TFMessage (latched)   ``base_link`` -> left camera optical frame
/ground_truth/road_map     grid_map_msgs/GridMap          the whole road in ``odom``, layer
                           (latched, once at the start)   ``elevation``
=========================  =============================  ===========================================

:func:`write_drive_bag` writes a :class:`roadbev_lab.synth.RidingDrive`; :func:`read_drive_truth`
reads what the preview-at-arrival metric needs from any bag with these topics (another renderer,
a real car with a LiDAR-made road map).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import MessageError, TypestoreFactory, field, stamp_from_header
from msg_bridge.bag import BagError, BagWriter, ReadStats, bag_topics, read_messages
from msg_bridge.grid_map import decode_grid_map, grid_map_message_at
from msg_bridge.tf import StaticTransform, camera_mount, odometry_message, tf_message, transforms_from_tf
from roadbev_core.config import BASE_FRAME, RoadbevConfig, TopicsConfig
from roadbev_core.geometry import GeometryError, quaternion_to_rotation
from roadbev_lab.evaluation.arrival import (
    ArrivalSettings,
    RoadMap,
    TimedPreview,
    Trajectory,
    WheelErrors,
    arrival_points,
    summarise_errors,
    wheel_errors,
)
from roadbev_lab.evaluation.evalbag import LEFT_FRAME, TF_STATIC_TOPIC, write_eval_bag

__all__ = [
    "GROUND_TRUTH_ODOM_TOPIC",
    "ODOM_FRAME",
    "ROAD_MAP_TOPIC",
    "DriveTruth",
    "arrival_settings",
    "evaluate_drive_previews",
    "is_drive_bag",
    "read_drive_truth",
    "score_preview_errors",
    "score_previews",
    "write_drive_bag",
]

ODOM_FRAME = "odom"
# The drive bag's truth (docs/interface/bags.md); its odometry is on the node's odom_topic and its mount on
# /tf_static (roadbev_lab.evaluation.evalbag.TF_STATIC_TOPIC).
GROUND_TRUTH_ODOM_TOPIC = "/ground_truth/odom"
ROAD_MAP_TOPIC = "/ground_truth/road_map"
# 1-sigma of the vehicle odometry's pose and twist as the covariance advertises them.
_POSE_SIGMA = (0.05, 0.05, 1e3, 1e3, 1e3, 0.01)  # z, roll, pitch unknown: planar odometry
_TWIST_SIGMA = (0.05, 0.05, 1e3, 1e3, 1e3, 0.003)


def _diag(sigmas: tuple[float, ...]) -> np.ndarray:
    cov = np.zeros(36)
    cov[::7] = np.square(sigmas)
    return cov


class _DriveTopics:
    """The drive's extra topics, handed to :func:`write_eval_bag` to interleave in time order."""

    def __init__(self, drive: Any) -> None:
        self.drive = drive
        self.odom_topic = TopicsConfig().odom  # the node's default
        self.odom = drive.odometry()
        self.truth = drive.ground_truth_poses()
        self.next_odom = 0
        self.next_truth = 0
        self.static_written = False

    def add_topics(self, bag: BagWriter) -> None:
        bag.add_topic(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", latched=True)
        bag.add_topic(ROAD_MAP_TOPIC, "grid_map_msgs/msg/GridMap", latched=True)
        bag.add_topic(self.odom_topic, "nav_msgs/msg/Odometry")
        bag.add_topic(GROUND_TRUTH_ODOM_TOPIC, "nav_msgs/msg/Odometry")

    def _write_static(self, bag: BagWriter, factory: TypestoreFactory) -> None:
        stamp = int(self.truth.stamp_ns[0])
        pos, R = self.drive.base_to_camera
        transform = StaticTransform(BASE_FRAME, LEFT_FRAME, np.asarray(R, np.float64), np.asarray(pos, np.float64))
        bag.write(TF_STATIC_TOPIC, tf_message([transform], factory, stamp_ns=stamp), stamp)
        road = self.drive.road_map()
        n_rows, n_cols = road.elevation.shape
        msg = grid_map_message_at(
            {"elevation": road.elevation}, factory, resolution=road.resolution,
            length=(n_rows * road.resolution, n_cols * road.resolution), centre=road.centre, stamp_ns=stamp,
            frame_id=ODOM_FRAME,
        )
        bag.write(ROAD_MAP_TOPIC, msg, stamp)

    def write_until(self, bag: BagWriter, factory: TypestoreFactory, stamp_ns: int) -> None:
        if not self.static_written:
            self._write_static(bag, factory)
            self.static_written = True
        for series, attr, topic, covs in (
            (self.truth, "next_truth", GROUND_TRUTH_ODOM_TOPIC, (None, None)),
            (self.odom, "next_odom", self.odom_topic, (_diag(_POSE_SIGMA), _diag(_TWIST_SIGMA))),
        ):
            k = getattr(self, attr)
            while k < series.stamp_ns.size and series.stamp_ns[k] <= stamp_ns:
                stamp = int(series.stamp_ns[k])
                msg = odometry_message(
                    factory, stamp_ns=stamp, position=series.position[k],
                    orientation_xyzw=series.orientation_xyzw[k], linear_velocity=series.linear_velocity[k],
                    angular_velocity=series.angular_velocity[k], pose_covariance=covs[0], twist_covariance=covs[1],
                )
                bag.write(topic, msg, stamp)
                k += 1
            setattr(self, attr, k)


def write_drive_bag(
    path: str | os.PathLike[str],
    drive: Any,
    *,
    compressed: bool = False,
    compression: str = "zstd",
    jpeg_quality: int = 90,
    progress: Callable[[int], object] | None = None,
) -> dict[str, int]:
    """Write a :class:`roadbev_lab.synth.RidingDrive` as a drive bag (deterministic bytes).

    Returns:
        Messages written per topic.
    """
    return write_eval_bag(path, drive, compressed=compressed, compression=compression, jpeg_quality=jpeg_quality,
                          progress=progress, extra=_DriveTopics(drive))


class DriveTruth(NamedTuple):
    """What a drive bag says about the truth.

    Attributes:
        trajectory: ``/ground_truth/odom`` (``base_link`` in ``odom``).
        road_map: ``/ground_truth/road_map`` (the last one when there are several).
        camera_in_base: ``base_link`` -> camera (position [3], R [3, 3] optical -> base_link)
            from ``/tf_static``, or None when the bag has none for ``camera_frame``.
        notes: how the bag was read.
        odometry: the vehicle's own odometry (the node's ``odom_topic``: planar, drifting), the
            frame the node's map is kept in; None when the bag has fewer than two of its poses.
    """

    trajectory: Trajectory
    road_map: RoadMap
    camera_in_base: tuple[np.ndarray, np.ndarray] | None
    notes: list[str]
    odometry: Trajectory | None = None


def is_drive_bag(path: str | os.PathLike[str]) -> bool:
    """Whether a bag has the ground-truth odometry and road map a preview-at-arrival needs."""
    present = bag_topics(Path(path))
    return GROUND_TRUTH_ODOM_TOPIC in present and ROAD_MAP_TOPIC in present


def read_drive_truth(
    path: str | os.PathLike[str], *, base_frame: str = BASE_FRAME, camera_frame: str = LEFT_FRAME,
    odom_topic: str | None = None,
) -> DriveTruth:
    """Read the true poses, the road map, the camera's mounting and the vehicle's own odometry
    from a drive bag.

    Args:
        base_frame: the vehicle body frame (``TopicsConfig.base_frame``): the TF parent looked for.
        camera_frame: the left image's ``header.frame_id`` (the TF child looked for).
        odom_topic: the vehicle's odometry (``TopicsConfig.odom``; default the node's).

    Raises:
        BagError: no ground-truth poses (or fewer than two), no road map, or malformed ones.
    """
    path = Path(path)
    notes: list[str] = []
    odom_topic = odom_topic or TopicsConfig().odom
    poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    odometry: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    road: RoadMap | None = None
    static: list[StaticTransform] = []
    wanted = [GROUND_TRUTH_ODOM_TOPIC, ROAD_MAP_TOPIC, TF_STATIC_TOPIC, odom_topic]
    bad = 0
    read = ReadStats()
    # a damaged or cut bag: the truth as far as it is readable scores the frames it covers
    for item in read_messages(path, wanted, on_damage="skip", stats=read):
        msg = item.msg
        try:
            if item.topic in (GROUND_TRUTH_ODOM_TOPIC, odom_topic):
                p = field(field(field(msg, "pose"), "pose"), "position")
                o = field(field(field(msg, "pose"), "pose"), "orientation")
                q = np.array([float(field(o, k)) for k in "xyzw"])
                quaternion_to_rotation(*q)  # checks it is a rotation
                pose = (np.array([float(field(p, k)) for k in "xyz"]), q / np.linalg.norm(q))
                (poses if item.topic == GROUND_TRUTH_ODOM_TOPIC else odometry)[stamp_from_header(msg)] = pose
            elif item.topic == ROAD_MAP_TOPIC:
                raw = decode_grid_map(msg)
                if "elevation" not in raw.layers:
                    raise BagError(f"{path}: {item.topic} has no 'elevation' layer")
                if raw.frame_id != ODOM_FRAME:
                    notes.append(f"road map in frame {raw.frame_id!r}, taken as the ground truth's frame")
                road = RoadMap(np.asarray(raw.layers["elevation"], np.float32), raw.resolution, raw.centre)
            else:
                static += transforms_from_tf(msg)
        except (MessageError, GeometryError, TypeError, ValueError, AttributeError) as exc:
            if isinstance(exc, BagError):
                raise
            bad += 1
            continue
    if bad:
        notes.append(f"{bad} malformed ground-truth message(s) ignored")
    if not read.complete:
        notes.append(f"ground truth read as far as the bag is readable: {read.summary()}")
    if len(poses) < 2:
        raise BagError(f"{path}: {GROUND_TRUTH_ODOM_TOPIC} has {len(poses)} usable pose(s); need >= 2")
    if road is None:
        raise BagError(f"{path}: no road map on {ROAD_MAP_TOPIC}")
    camera = camera_mount(static, base_frame, camera_frame)
    if camera is None:
        notes.append(f"no {base_frame} -> {camera_frame} on {TF_STATIC_TOPIC}: "
                     "the camera position comes from vehicle.camera_position_m")
    trajectory = _trajectory(poses)
    if not math.isfinite(float(np.abs(trajectory.position).sum())):
        raise BagError(f"{path}: ground-truth poses are not finite")
    vehicle = _trajectory(odometry) if len(odometry) >= 2 else None
    if vehicle is not None and not math.isfinite(float(np.abs(vehicle.position).sum())):
        notes.append(f"{odom_topic}: poses not finite, the map scored where its cells lie")
        vehicle = None
    return DriveTruth(trajectory, road, camera, notes, vehicle)


def _trajectory(poses: Mapping[int, tuple[np.ndarray, np.ndarray]]) -> Trajectory:
    """Poses by stamp (position [3], unit quaternion xyzw [4]) as a trajectory in stamp order."""
    stamps = np.array(sorted(poses), np.int64)
    position = np.array([poses[s][0] for s in stamps])
    quats = np.array([poses[s][1] for s in stamps])
    for k in range(1, quats.shape[0]):  # sign continuity for slerp
        if quats[k] @ quats[k - 1] < 0:
            quats[k] = -quats[k]
    return Trajectory(stamps, position, quats)


def arrival_settings(
    config: RoadbevConfig,
    *,
    lead_time_s: float = 0.1,
    camera_in_base: tuple[np.ndarray, np.ndarray] | None = None,
) -> ArrivalSettings:
    """Metric settings from the config (``preview.tyre_width_m``, ``preview.spacing_m``, the
    vehicle, the grid's ``base_height``)."""
    return ArrivalSettings(
        lead_time_s=float(lead_time_s),
        spacing_m=config.preview.spacing_m,
        tyre_width_m=config.preview.tyre_width_m,
        base_height=float(config.grid.base_height),
        vehicle=config.vehicle,
        camera_in_base=camera_in_base,
    )


def score_previews(
    truth: DriveTruth,
    previews: Sequence[TimedPreview],
    frame_stamps_ns: Sequence[int],
    config: RoadbevConfig,
    *,
    lead_time_s: float = 0.1,
) -> dict[str, Any]:
    """``preview_at_arrival`` of previews made from a drive's frames, against its truth.

    Returns:
        The ``preview_at_arrival`` keys (see :func:`roadbev_lab.evaluation.arrival.preview_at_arrival`) plus
        ``notes`` on how the truth was read.
    """
    return score_preview_errors(truth, previews, frame_stamps_ns, config, lead_time_s=lead_time_s)[0]


def score_preview_errors(
    truth: DriveTruth,
    previews: Sequence[TimedPreview],
    frame_stamps_ns: Sequence[int],
    config: RoadbevConfig,
    *,
    lead_time_s: float = 0.1,
) -> tuple[dict[str, Any], dict[str, WheelErrors]]:
    """:func:`score_previews` and the points it summarised, per front wheel (to pool the keys
    of several drives: :func:`roadbev_lab.evaluation.arrival.summarise_errors`)."""
    settings = arrival_settings(config, lead_time_s=lead_time_s, camera_in_base=truth.camera_in_base)
    wheels = wheel_errors(arrival_points(previews, truth.trajectory, truth.road_map, settings,
                                         frame_stamps_ns=frame_stamps_ns))
    out = summarise_errors(wheels, settings.lead_time_s)
    if truth.notes:
        out["notes"] = list(truth.notes)
    return out, wheels


def evaluate_drive_previews(
    path: str | os.PathLike[str],
    previews: Sequence[TimedPreview],
    frame_stamps_ns: Sequence[int],
    config: RoadbevConfig,
    *,
    lead_time_s: float = 0.1,
) -> dict[str, Any]:
    """:func:`score_previews` against the truth of the drive bag at ``path``.

    Raises:
        BagError: the bag has no usable ground-truth poses or road map.
    """
    truth = read_drive_truth(path, base_frame=config.topics.base_frame, odom_topic=config.topics.odom)
    return score_previews(truth, previews, frame_stamps_ns, config, lead_time_s=lead_time_s)
