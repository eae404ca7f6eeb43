"""Label bags: a recorded drive with a LiDAR -> the same drive with ``/ground_truth/elevation``.

:func:`label_bag` reads a bag with stereo images, CameraInfos, the IMU, a LiDAR
(``sensor_msgs/PointCloud2``), optionally ``/tf_static`` and odometry (``nav_msgs/Odometry``), and
writes an evaluation/training bag (docs/interface/bags.md, "Evaluation bags"): every message of the input except
the LiDAR, plus ``/ground_truth/elevation`` per left image (stamped exactly like it) and
``/roadbev/grid_config`` (the grid with its ``base_height``, the rig, the labeller's settings).
The geometry and the road-surface test are :mod:`roadbev_lab.data.lidar_labels`; the per-cell mean is
:func:`roadbev_core.labels.elevation_map`.

The LiDAR's extrinsic (LiDAR -> left optical frame) comes from ``/tf_static`` (any chain of
static transforms joining the cloud's ``header.frame_id`` with the left CameraInfo's) or, where
the bag has none, from the caller (parameter ``label.lidar_extrinsic_xyz_rpy_deg``). The planar
motion between a scan and a frame comes from the odometry of ``base_link`` and the left camera's
place in ``base_link`` (``/tf_static`` ``base_link`` -> left optical frame, else
``vehicle.camera_position_m`` with the camera looking along ``base_link``'s x).
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import MessageError, TypestoreFactory, as_str, field, stamp_from_header
from msg_bridge.bag import BagError, BagWriter, TopicInfo, bag_topics, read_messages, typestore
from msg_bridge.camera_info import camera_info_from_stereo
from msg_bridge.grid_map import ROAD_FRAME, grid_map_message
from msg_bridge.image import array_to_image
from msg_bridge.imu import imu_message, imu_orientation
from msg_bridge.point_cloud import array_point_cloud, point_cloud_xyz
from msg_bridge.tf import (
    StaticTransform,
    TransformError,
    TransformTree,
    odometry_message,
    odometry_pose,
    tf_message,
    transforms_from_tf,
)
from roadbev_core.attitude import ImuError, ImuStale, imu_buffer
from roadbev_core.config import BASE_FRAME, GridSpec, ImuConfig, StereoCamera, TopicsConfig, VehicleConfig
from roadbev_core.geometry import R_BODY_FROM_OPTICAL
from roadbev_lab.data.lidar_labels import LabelConfig, LabelError, accumulate_label, planar_transform, scan_to_road
from roadbev_lab.evaluation.evalbag import IMU_FRAME, LEFT_FRAME, RIGHT_FRAME, TF_STATIC_TOPIC, BagTopics, read_eval_bag

__all__ = [
    "DEFAULT_LIDAR_TOPIC",
    "Extrinsic",
    "LabelReport",
    "RecordedFrame",
    "label_bag",
    "write_recording",
]

DEFAULT_LIDAR_TOPIC = "/lidar/points"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
DEFAULT_CAMERA_POSITION_M = VehicleConfig().camera_position_m  # the interface's vehicle.camera_position_m


class Extrinsic(NamedTuple):
    """LiDAR -> left optical frame: ``p_cam = rotation @ p_lidar + translation``."""

    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]


class LabelReport(NamedTuple):
    """What :func:`label_bag` did.

    Attributes:
        frames: left images (frames) in the bag.
        labelled_frames: frames that got a non-empty label.
        scans: LiDAR messages read.
        mean_labelled_pct: mean share of the grid's cells labelled, over the labelled frames.
        mean_scans_per_frame: scans accumulated per labelled frame.
        plane_offset_cm: median height of the fitted road plane above the reference plane at the
            grid centre (a large value says ``base_height`` or the attitude is off).
        skipped: reason -> count (frames without a label, scans left out).
        rejected_points: road-surface test: reason -> points rejected (all frames).
        notes: remarks on how the bag was interpreted.
        counts: messages written per topic.
    """

    frames: int
    labelled_frames: int
    scans: int
    mean_labelled_pct: float
    mean_scans_per_frame: float
    plane_offset_cm: float
    skipped: dict[str, int]
    rejected_points: dict[str, int]
    notes: list[str]
    counts: dict[str, int]


class _Series(NamedTuple):
    stamps: np.ndarray  # [K] int64
    values: np.ndarray  # [K, D]


class _Scan(NamedTuple):
    stamp_ns: int
    points: np.ndarray  # [N, 3] road frame at the scan's stamp
    pose: tuple[float, float, float] | None  # planar pose of that road frame in odom


def _interp_pose(odom: _Series, stamp: int, max_age_ns: int) -> tuple[float, float, float] | None:
    """Planar pose (x, y, unwrapped yaw) of base_link at ``stamp`` (None outside the span)."""
    s = odom.stamps
    if s.size == 0 or stamp < s[0] - max_age_ns or stamp > s[-1] + max_age_ns:
        return None
    if s.size == 1 or stamp <= s[0]:
        v = odom.values[0]
    elif stamp >= s[-1]:
        v = odom.values[-1]
    else:
        i = int(np.searchsorted(s, stamp))
        w = (stamp - s[i - 1]) / max(int(s[i] - s[i - 1]), 1)
        v = odom.values[i - 1] * (1 - w) + odom.values[i] * w
    return (float(v[0]), float(v[1]), float(v[2]))


def _road_pose(
    base: tuple[float, float, float], camera_xy_yaw: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Planar pose of the road frame (under the camera, along its yaw) from base_link's."""
    x, y, yaw = base
    cx, cy, cyaw = camera_xy_yaw
    c, s = math.cos(yaw), math.sin(yaw)
    return (x + c * cx - s * cy, y + s * cx + c * cy, yaw + cyaw)


def _pick_lidar_topic(path: Path, topics: Mapping[str, TopicInfo], requested: str | None) -> tuple[str, list[str]]:
    clouds = sorted(t for t, info in topics.items() if info.msgtype == POINT_CLOUD)
    if requested:
        if requested not in topics:
            raise BagError(f"{path}: no LiDAR topic {requested}; PointCloud2 topics: {clouds or 'none'}")
        if topics[requested].msgtype != POINT_CLOUD:
            raise BagError(f"{path}: {requested} is a {topics[requested].msgtype}, not a PointCloud2")
        return requested, []
    if DEFAULT_LIDAR_TOPIC in clouds:
        return DEFAULT_LIDAR_TOPIC, []
    if len(clouds) == 1:
        return clouds[0], [f"LiDAR topic {clouds[0]} (the bag's only PointCloud2 topic)"]
    if not clouds:
        raise BagError(f"{path}: no sensor_msgs/PointCloud2 topic: nothing to make labels from")
    raise BagError(f"{path}: several PointCloud2 topics ({', '.join(clouds)}); choose one with --lidar-topic")


def label_bag(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    grid: GridSpec,
    config: LabelConfig,
    topics: TopicsConfig | None = None,
    imu: ImuConfig | None = None,
    lidar_topic: str | None = None,
    extrinsic: Extrinsic | None = None,
    camera_position_m: Sequence[float] = DEFAULT_CAMERA_POSITION_M,
    progress: Callable[[int], object] | None = None,
) -> LabelReport:
    """Label every left image of a recorded drive from its LiDAR scans; write the result.

    Args:
        src: the recorded bag (rosbag2 directory or ``.mcap``).
        dst: the evaluation bag to write (must not exist).
        grid: the label grid (window, cells, ``base_height``, vertical range).
        config: the labeller's settings.
        topics: the node's topics (``left_image_topic``..., ``imu_topic``, ``odom_topic``,
            ``image_transport``; the defaults when None).
        imu: the IMU settings (``imu_to_camera_rpy_deg``, ``imu_max_age_s``: also how far the
            odometry may lie from a stamp; the defaults when None).
        lidar_topic: the PointCloud2 topic (default ``/lidar/points``, else the only one).
        extrinsic: LiDAR -> left optical frame, used when ``/tf_static`` does not join them.
        camera_position_m: the left camera in ``base_link`` when ``/tf_static`` does not say.
        progress: called with 1 after each scan (e.g. ``tqdm.update``).

    Raises:
        BagError: unreadable bag, no LiDAR topic, or an output that exists.
        LabelError: no extrinsic, accumulation without odometry, or no frame that got a label.
    """
    src, dst = Path(src), Path(dst)
    node_topics, imu = topics or TopicsConfig(), imu or ImuConfig()
    if dst.exists():
        raise BagError(f"{dst} exists already; not overwriting it")
    present = bag_topics(src)
    lidar, notes = _pick_lidar_topic(src, present, lidar_topic)
    topic_names = BagTopics.of(node_topics)
    odom_topic = topic_names.odom
    max_age_ns = int(imu.max_age_s * 1e9)  # odometry may lie this far from a stamp too
    # the one attitude rule set (roadbev_core.attitude), over the whole recording
    attitudes = imu_buffer(imu, whole_history=True)
    frames = read_eval_bag(src, node_topics, grid_overrides=grid.to_dict())
    frame_stamps = frames.stamps
    skipped: Counter[str] = Counter(frames.skipped)

    # Pass 1: everything but the scans.
    tree = TransformTree()
    odom: list[tuple[int, float, float, float]] = []
    left_frame = ""
    wanted = [TF_STATIC_TOPIC, topic_names.imu, odom_topic, topic_names.left_info]
    for item in read_messages(src, [t for t in wanted if t in present]):
        try:
            if item.topic == TF_STATIC_TOPIC:
                for tf in transforms_from_tf(item.msg):
                    tree.add(tf)
            elif item.topic == topic_names.imu:
                attitudes.add(stamp_from_header(item.msg), imu_orientation(item.msg))
            elif item.topic == odom_topic:
                pose = odometry_pose(item.msg)
                odom.append((pose.stamp_ns, pose.x, pose.y, pose.yaw))
            elif not left_frame:
                left_frame = as_str(field(field(item.msg, "header"), "frame_id"), "CameraInfo frame_id").lstrip("/")
        except (MessageError, ImuError) as exc:
            skipped[f"malformed {item.topic} message ({exc})"] += 1
    odom.sort()
    odom_series = _Series(np.array([o[0] for o in odom], np.int64), np.array([o[1:] for o in odom]).reshape(-1, 3))
    if odom_series.values.size:
        odom_series.values[:, 2] = np.unwrap(odom_series.values[:, 2])
    has_odom = odom_series.stamps.size > 0
    if config.window_s > 0 and not has_odom:
        raise LabelError(
            f"label.window_s = {config.window_s} s accumulates scans, which needs odometry on {odom_topic} "
            "(nav_msgs/Odometry); the bag has none: set label.window_s: 0 for single scans"
        )
    if not has_odom:
        notes.append(f"no odometry on {odom_topic}: each frame is labelled from its nearest scan, uncompensated")

    camera_xy_yaw = (float(camera_position_m[0]), float(camera_position_m[1]), 0.0)
    if left_frame and BASE_FRAME in tree.frames:
        try:
            R, t = tree.lookup(BASE_FRAME, left_frame)
            forward = R @ R_BODY_FROM_OPTICAL.T[:, 0]  # camera body x in base_link
            camera_xy_yaw = (float(t[0]), float(t[1]), math.atan2(float(forward[1]), float(forward[0])))
            notes.append(f"camera in {BASE_FRAME} from {TF_STATIC_TOPIC}: x {t[0]:.2f} m, y {t[1]:.2f} m")
        except TransformError:
            pass

    extrinsics: dict[str, Extrinsic] = {}

    def extrinsic_for(frame_id: str) -> Extrinsic:
        if frame_id not in extrinsics:
            try:
                R, t = tree.lookup(left_frame, frame_id)
                extrinsics[frame_id] = Extrinsic(R, t)
                notes.append(f"LiDAR extrinsic {frame_id} -> {left_frame} from {TF_STATIC_TOPIC}")
            except TransformError as exc:
                if extrinsic is None:
                    raise LabelError(
                        f"no extrinsic for the LiDAR frame {frame_id!r}: {exc}; publish it on {TF_STATIC_TOPIC} "
                        "or set label.lidar_extrinsic_xyz_rpy_deg"
                    ) from None
                extrinsics[frame_id] = extrinsic
                notes.append(f"LiDAR extrinsic {frame_id} -> left camera from the parameters")
        return extrinsics[frame_id]

    # Pass 2: the scans, streamed; each frame is labelled once all its scans have arrived.
    reach_ns = int(max(config.window_s, config.max_scan_gap_s) * 1e9)
    window_ns, gap_ns = int(config.window_s * 1e9), int(config.max_scan_gap_s * 1e9)
    buffer: deque[_Scan] = deque()
    labels: dict[int, np.ndarray] = {}
    rejected: Counter[str] = Counter()
    used_per_frame: list[int] = []
    plane_offsets: list[float] = []
    next_frame = 0
    n_scans = 0
    keep_top = config.obstacle_top_m + 0.5

    def label_frame(i: int) -> None:
        stamp = frame_stamps[i]
        near = [s for s in buffer if abs(s.stamp_ns - stamp) <= reach_ns]
        if not near:
            skipped["frames without a scan within label.max_scan_gap_s"] += 1
            return
        own = min(near, key=lambda s: abs(s.stamp_ns - stamp))
        if abs(own.stamp_ns - stamp) > gap_ns:
            skipped["frames without a scan within label.max_scan_gap_s"] += 1
            return
        frame_pose = None
        if has_odom:
            base = _interp_pose(odom_series, stamp, max_age_ns)
            frame_pose = None if base is None else _road_pose(base, camera_xy_yaw)
            if frame_pose is None or own.pose is None:
                skipped["frames outside the odometry's time span"] += 1
                return
        own_points = own.points if frame_pose is None else planar_transform(own.pose, frame_pose, own.points)  # type: ignore[arg-type]
        moved = []
        if frame_pose is not None and window_ns > 0:
            for s in near:
                if s is own or s.pose is None or abs(s.stamp_ns - stamp) > window_ns:
                    continue
                moved.append(planar_transform(s.pose, frame_pose, s.points))
        try:
            result = accumulate_label(own_points, moved, grid, config)
        except LabelError as exc:
            skipped[f"frames without a label: {exc}"] += 1
            return
        if not result.label.mask.any():
            skipped["frames whose scans hold no road cell"] += 1
            return
        labels[stamp] = result.label.elevation
        rejected.update(result.selection.rejected)
        used_per_frame.append(result.scans_used)
        cx, cy = grid.centre
        plane_offsets.append(float(result.selection.plane.height(cx, cy)))

    def flush(until_ns: int | None) -> None:
        nonlocal next_frame
        while next_frame < len(frame_stamps) and (until_ns is None or frame_stamps[next_frame] + reach_ns < until_ns):
            label_frame(next_frame)
            next_frame += 1
        oldest = frame_stamps[next_frame] - reach_ns if next_frame < len(frame_stamps) else None
        while buffer and (oldest is None or buffer[0].stamp_ns < oldest):
            buffer.popleft()

    for item in read_messages(src, [lidar]):
        n_scans += 1
        if progress is not None:
            progress(1)
        try:
            stamp = stamp_from_header(item.msg)
            cloud_frame = as_str(field(field(item.msg, "header"), "frame_id"), "PointCloud2 frame_id").lstrip("/")
            xyz = point_cloud_xyz(item.msg)
        except MessageError as exc:
            skipped[f"malformed scans ({exc})"] += 1
            continue
        if xyz.shape[0] == 0:
            skipped["empty scans (no finite point)"] += 1
            continue
        ext = extrinsic_for(cloud_frame)
        flush(stamp)
        try:
            attitude = attitudes.attitude_at(stamp)
        except ImuStale:
            skipped["scans without an IMU attitude (outside the IMU's time span)"] += 1
            continue
        points = scan_to_road(
            xyz, ext.rotation, ext.translation, attitude, grid.base_height, max_range_m=config.max_range_m
        )
        points = points[points[:, 2] <= keep_top]
        base = _interp_pose(odom_series, stamp, max_age_ns) if has_odom else None
        buffer.append(_Scan(stamp, points, None if base is None else _road_pose(base, camera_xy_yaw)))
    if n_scans == 0:
        raise LabelError(f"{src}: the LiDAR topic {lidar} holds no message")
    flush(None)
    if not labels:
        reasons = "; ".join(f"{k}: {v}" for k, v in sorted(skipped.items())) or "none"
        raise LabelError(f"no frame got a label from {n_scans} scan(s) on {lidar} ({reasons})")

    # Pass 3: copy the drive (without the LiDAR) and add the labels.
    counts = _write(src, dst, present, lidar, topic_names, grid, config, frames.camera.to_dict(), labels, notes)
    labelled_pct = [100.0 * float(np.isfinite(v).mean()) for v in labels.values()]
    return LabelReport(
        frames=len(frame_stamps),
        labelled_frames=len(labels),
        scans=n_scans,
        mean_labelled_pct=float(np.mean(labelled_pct)),
        mean_scans_per_frame=float(np.mean(used_per_frame)),
        plane_offset_cm=100.0 * float(np.median(plane_offsets)),
        skipped=dict(skipped),
        rejected_points=dict(rejected),
        notes=notes,
        counts=counts,
    )


def _write(
    src: Path,
    dst: Path,
    present: Mapping[str, TopicInfo],
    lidar: str,
    topics: BagTopics,
    grid: GridSpec,
    config: LabelConfig,
    camera: dict[str, Any],
    labels: dict[int, np.ndarray],
    notes: list[str],
) -> dict[str, int]:
    factory = TypestoreFactory(typestore())
    gt_topic, config_topic = topics.ground_truth, topics.grid_config
    copied = [t for t in present if t not in (lidar, gt_topic, config_topic)]
    pending = sorted(labels)
    with BagWriter(dst) as bag:
        bag.add_topic(config_topic, "std_msgs/msg/String", latched=True)
        bag.add_topic(gt_topic, "grid_map_msgs/msg/GridMap")
        for topic in copied:
            bag.add_topic(topic, present[topic].msgtype, latched=topic == TF_STATIC_TOPIC)
        text = json.dumps(
            {"grid": grid.to_dict(), "camera": camera, "label": config.to_dict(), "label_notes": notes},
            sort_keys=True,
        )
        first = True
        k = 0

        def write_labels(until_ns: int) -> None:
            nonlocal k
            while k < len(pending) and pending[k] <= until_ns:
                stamp = pending[k]
                msg = grid_map_message({"elevation": labels[stamp]}, grid, factory, stamp_ns=stamp, frame_id=ROAD_FRAME)
                bag.write(gt_topic, msg, stamp)
                k += 1

        for item in read_messages(src, copied, raw=True):
            if first:
                bag.write(config_topic, factory.new("std_msgs/msg/String", data=text), item.log_time_ns)
                first = False
            write_labels(item.log_time_ns)
            bag.write_raw(item.topic, item.msg, item.log_time_ns)
        if first:
            bag.write(config_topic, factory.new("std_msgs/msg/String", data=text), pending[0])
        write_labels(2**63 - 1)
        return dict(bag.counts)


class RecordedFrame(NamedTuple):
    """One stereo frame of a recording: images [H, W, 3] uint8 (or [H, W]), optional truth."""

    stamp_ns: int
    left: np.ndarray
    right: np.ndarray | None
    truth: np.ndarray | None = None


def _yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``yaw`` about z (planar odometry)."""
    return (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


def write_recording(
    path: str | os.PathLike[str],
    camera: StereoCamera,
    frames: Sequence[RecordedFrame],
    *,
    imu: Sequence[tuple[int, Sequence[float] | np.ndarray]],
    scans: Sequence[tuple[int, str, np.ndarray]] = (),
    odometry: Sequence[tuple[int, float, float, float, float]] = (),
    static_transforms: Sequence[StaticTransform] = (),
    grid: GridSpec | None = None,
    lidar_topic: str = DEFAULT_LIDAR_TOPIC,
) -> dict[str, int]:
    """Write a drive as a recording would hold it (the input of :func:`label_bag`).

    Args:
        path: ``*.mcap`` or a rosbag2 directory to create.
        camera: the rectified rig (CameraInfos per frame).
        frames: the stereo frames (``truth`` needs ``grid``: written as ``/ground_truth/elevation``).
        imu: ``(stamp_ns, (x, y, z, w))`` orientations of the IMU (aligned with the camera body).
        scans: ``(stamp_ns, frame_id, points [N, 3 or 4])`` LiDAR scans (x, y, z[, intensity]).
        odometry: ``(stamp_ns, x, y, z, yaw)`` of ``base_link`` in ``odom``.
        static_transforms: written once on ``/tf_static``.
        grid: the grid of the truths (and ``/roadbev/grid_config``).
        lidar_topic: the scans' topic.

    Returns:
        Messages written per topic.
    """
    factory = TypestoreFactory(typestore())
    t = BagTopics.of(TopicsConfig())  # the node's default topics
    records: list[tuple[int, int, str, object]] = []  # (stamp, order, topic, message)
    for frame in frames:
        s = int(frame.stamp_ns)
        records.append(
            (s, 1, t.left_image, array_to_image(frame.left, factory, stamp_ns=s, frame_id=LEFT_FRAME))
        )
        records.append(
            (s, 2, t.left_info, camera_info_from_stereo(camera, factory, stamp_ns=s, frame_id=LEFT_FRAME))
        )
        if frame.right is not None:
            records.append(
                (s, 1, t.right_image, array_to_image(frame.right, factory, stamp_ns=s, frame_id=RIGHT_FRAME))
            )
            info = camera_info_from_stereo(camera, factory, right=True, stamp_ns=s, frame_id=RIGHT_FRAME)
            records.append((s, 2, t.right_info, info))
        if frame.truth is not None:
            if grid is None:
                raise BagError("frames with truth need the grid")
            gt = grid_map_message({"elevation": frame.truth}, grid, factory, stamp_ns=s, frame_id=ROAD_FRAME)
            records.append((s, 3, t.ground_truth, gt))
    for s, q in imu:
        records.append(
            (int(s), 0, t.imu, imu_message(factory, stamp_ns=int(s), orientation_xyzw=q, frame_id=IMU_FRAME))
        )
    for s, frame_id, points in scans:
        pts = np.asarray(points, dtype=np.float32)
        names = ("x", "y", "z", "intensity")[: pts.shape[1]]
        records.append(
            (int(s), 4, lidar_topic, array_point_cloud(pts, names, factory, stamp_ns=int(s), frame_id=frame_id))
        )
    for s, x, y, z, yaw in odometry:
        records.append(
            (int(s), 0, t.odom, odometry_message(factory, stamp_ns=int(s), position=(x, y, z),
                                                                orientation_xyzw=_yaw_quaternion(yaw)))
        )
    records.sort(key=lambda r: (r[0], r[1]))
    types = {
        t.left_image: "sensor_msgs/msg/Image",
        t.right_image: "sensor_msgs/msg/Image",
        t.left_info: "sensor_msgs/msg/CameraInfo",
        t.right_info: "sensor_msgs/msg/CameraInfo",
        t.ground_truth: "grid_map_msgs/msg/GridMap",
        t.imu: "sensor_msgs/msg/Imu",
        lidar_topic: POINT_CLOUD,
        t.odom: "nav_msgs/msg/Odometry",
    }
    first = records[0][0] if records else 0
    with BagWriter(path) as bag:
        if grid is not None:
            bag.add_topic(t.grid_config, "std_msgs/msg/String", latched=True)
            text = json.dumps({"grid": grid.to_dict(), "camera": camera.to_dict()}, sort_keys=True)
            bag.write(t.grid_config, factory.new("std_msgs/msg/String", data=text), first)
        if static_transforms:
            bag.add_topic(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", latched=True)
            bag.write(TF_STATIC_TOPIC, tf_message(static_transforms, factory, stamp_ns=first), first)
        for topic in sorted({r[2] for r in records}):
            bag.add_topic(topic, types[topic])
        for s, _order, topic, msg in records:
            bag.write(topic, msg, s)
        return dict(bag.counts)
