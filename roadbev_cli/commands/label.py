"""``roadbev label BAG OUT``: an evaluation/training bag from a recorded drive with a LiDAR.

The input holds stereo images, CameraInfos, the IMU, a LiDAR (``sensor_msgs/PointCloud2``) and
optionally ``/tf_static`` and odometry (``/odom``, ``nav_msgs/Odometry``). The output is the same
drive without the LiDAR, plus ``/ground_truth/elevation`` per left image: the paper's labels (mean
height of the road points per cell, :mod:`roadbev_core.labels`) from the scans within
``label.window_s`` of the frame, moved with the odometry; only road-surface points count (the
test is documented in :mod:`roadbev_lab.data.lidar_labels`). ``roadbev eval OUT`` and
``roadbev train`` read the result.

``--params`` is a ROS 2 params YAML with the node's grid parameters (``base_height``, ``x_min``...
``resolution``, ``z_min``, ``z_max``), topics, ``imu_to_camera_rpy_deg``, ``odom_topic``,
``vehicle.camera_position_m`` and the labeller's ``label.*`` parameters (``label.window_s``,
``label.tile_m``... see ``roadbev_lab.data.lidar_labels.LabelConfig``), among them
``label.lidar_extrinsic_xyz_rpy_deg``: the LiDAR's pose in the left optical frame
(x, y, z in m, roll, pitch, yaw in degrees: ``p_cam = R p_lidar + t``) for bags whose
``/tf_static`` does not carry it.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from msg_bridge.bag import BagError, bag_topics
from roadbev_cli.cli import CommandError, add_output_flags, output_path, progress_bar, shows_progress
from roadbev_cli.commands.eval import check_bag_path
from roadbev_core.config import RoadbevConfig, load_params_file
from roadbev_core.geometry import rotation_from_rpy
from roadbev_core.pipeline import check_config
from roadbev_lab.data.labelbag import Extrinsic, label_bag
from roadbev_lab.data.lidar_labels import LabelConfig, LabelError

HELP = "label a recorded drive from its LiDAR: an evaluation/training bag with /ground_truth/elevation"
EXTRINSIC = "label.lidar_extrinsic_xyz_rpy_deg"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev label``."""
    parser.add_argument("bag", metavar="BAG", type=Path, help="recorded drive: rosbag2 directory or .mcap file")
    parser.add_argument("out", metavar="OUT", type=output_path, help="output bag: NAME.mcap or a directory")
    parser.add_argument(
        "--lidar-topic",
        default=None,
        metavar="T",
        help="PointCloud2 topic (default /lidar/points, else the bag's only PointCloud2 topic)",
    )
    parser.add_argument("--params", default=None, metavar="P", help="ROS 2 params YAML (grid, topics, label.*)")
    add_output_flags(parser)


def _numbers(name: str, value: Any, n: int) -> list[float]:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != n
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    ):
        raise CommandError(f"{name} must be a list of {n} finite numbers, got {value!r}")
    return [float(v) for v in value]


def run(args: argparse.Namespace) -> int:
    """Label the bag, write OUT, print a summary; non-zero exit (CommandError) on bad input."""
    check_bag_path(args.bag)
    if args.out.exists():
        raise CommandError(f"{args.out} exists already; remove it first")
    raw = load_params_file(args.params).values if args.params else {}
    label_params = {k: v for k, v in raw.items() if k.startswith("label.") and k != EXTRINSIC}
    node = check_config(RoadbevConfig.from_params({k: v for k, v in raw.items() if not k.startswith("label.")}))
    config = LabelConfig.from_params(label_params)
    grid = node.grid
    extrinsic = None
    if EXTRINSIC in raw:
        x, y, z, r, p, w = _numbers(EXTRINSIC, raw[EXTRINSIC], 6)
        extrinsic = Extrinsic(rotation_from_rpy(*np.radians([r, p, w])), np.array([x, y, z]))
    camera_position = list(node.vehicle.camera_position_m)
    try:
        lidar = args.lidar_topic
        topics = bag_topics(args.bag)
        total = (
            topics[lidar].count
            if lidar in topics
            else sum(t.count for t in topics.values() if t.msgtype == "sensor_msgs/msg/PointCloud2")
        )
        with progress_bar(total=total or None, unit="scan", desc="label", disable=not shows_progress(args)) as bar:
            report = label_bag(
                args.bag,
                args.out,
                grid=grid,
                config=config,
                topics=node.topics,
                imu=node.imu,
                lidar_topic=lidar,
                extrinsic=extrinsic,
                camera_position_m=camera_position,
                progress=bar.update,
            )
    except (BagError, LabelError) as exc:
        raise CommandError(str(exc)) from None
    if not args.quiet:
        print(
            f"wrote {args.out}: {report.labelled_frames}/{report.frames} frames labelled from {report.scans} scans, "
            f"{report.mean_labelled_pct:.1f} % of the cells per frame, "
            f"{report.mean_scans_per_frame:.1f} scans per frame"
        )
        print(
            f"  road plane at the grid centre: {report.plane_offset_cm:+.1f} cm from the reference plane"
            " (base_height below the camera)"
        )
        for reason, n in sorted(report.skipped.items()):
            print(f"  skipped: {reason}: {n}")
        for reason, n in sorted(report.rejected_points.items()):
            print(f"  points rejected by the road-surface test ({reason}): {n}")
        for note in report.notes:
            print(f"  note: {note}")
    return 0
