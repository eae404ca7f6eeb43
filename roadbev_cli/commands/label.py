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

Many bags at once (several BAGs, a folder of bags, a glob pattern, or ``--workers`` / ``--ray``:
:mod:`roadbev_cli.fleet`): OUT is a folder; each bag's labelled bag is ``OUT/<its name>.mcap``,
every bag's report and the totals are ``OUT/summary.json``, the report ``OUT/report.md``. Each
finished bag is kept (``OUT/.fleet``, keyed by the bag's content and the parameters): a run again
labels only the bags not done. A bag that fails is listed with its reason; the exit is then
non-zero, after everything else is written.
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
from roadbev_cli.fleet import add_fleet_arguments, fail_on_failed_bags, run_fleet, wants_fleet
from roadbev_core.config import RoadbevConfig, load_params_file
from roadbev_core.geometry import rotation_from_rpy
from roadbev_core.pipeline import check_config
from roadbev_lab.data.labelbag import Extrinsic, label_bag
from roadbev_lab.data.lidar_labels import LabelConfig, LabelError
from roadbev_lab.evaluation.frames import to_json
from roadbev_lab.fleet.runner import output_names
from roadbev_lab.fleet.store import ResultStore
from roadbev_lab.fleet.summary import label_report, label_summary
from roadbev_lab.fleet.tasks import LabelSettings

HELP = "label a recorded drive from its LiDAR: an evaluation/training bag with /ground_truth/elevation"
EXTRINSIC = "label.lidar_extrinsic_xyz_rpy_deg"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev label``."""
    parser.add_argument("bag", metavar="BAG", nargs="+",
                        help="recorded drive: rosbag2 directory or .mcap file; several, a folder of bags or a glob "
                             "pattern label many bags")
    parser.add_argument("out", metavar="OUT", type=output_path,
                        help="output bag: NAME.mcap or a directory (many bags: the folder for their outputs)")
    parser.add_argument(
        "--lidar-topic",
        default=None,
        metavar="T",
        help="PointCloud2 topic (default /lidar/points, else the bag's only PointCloud2 topic)",
    )
    parser.add_argument("--params", default=None, metavar="P", help="ROS 2 params YAML (grid, topics, label.*)")
    add_output_flags(parser)
    add_fleet_arguments(parser, store=False)


def _numbers(name: str, value: Any, n: int) -> list[float]:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != n
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    ):
        raise CommandError(f"{name} must be a list of {n} finite numbers, got {value!r}")
    return [float(v) for v in value]


def _settings(args: argparse.Namespace) -> tuple[LabelSettings, dict[str, Any]]:
    """The labeller's settings from ``--params`` and ``--lidar-topic``, and the parameters as read."""
    raw = load_params_file(args.params).values if args.params else {}
    label_params = {k: v for k, v in raw.items() if k.startswith("label.") and k != EXTRINSIC}
    node = check_config(RoadbevConfig.from_params({k: v for k, v in raw.items() if not k.startswith("label.")}))
    config = LabelConfig.from_params(label_params)
    extrinsic = None
    if EXTRINSIC in raw:
        x, y, z, r, p, w = _numbers(EXTRINSIC, raw[EXTRINSIC], 6)
        extrinsic = Extrinsic(rotation_from_rpy(*np.radians([r, p, w])), np.array([x, y, z]))
    return LabelSettings(node.grid, config, node.topics, node.imu, args.lidar_topic, extrinsic,
                         tuple(node.vehicle.camera_position_m)), raw


def run(args: argparse.Namespace) -> int:
    """Label the bag, write OUT, print a summary; non-zero exit (CommandError) on bad input."""
    if wants_fleet(args.bag, args):
        return _run_many(args)
    args.bag = Path(args.bag[0])
    check_bag_path(args.bag)
    if args.out.exists():
        raise CommandError(f"{args.out} exists already; remove it first")
    settings, _raw = _settings(args)
    grid, config, extrinsic = settings.grid, settings.config, settings.extrinsic
    camera_position = list(settings.camera_position_m)
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
                topics=settings.topics,
                imu=settings.imu,
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


def _run_many(args: argparse.Namespace) -> int:
    """Many bags (:mod:`roadbev_cli.fleet`): label each into OUT/, write the summary and the report."""
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise CommandError(f"{out} is a file: many bags are labelled into a folder")
    settings, raw = _settings(args)
    out.mkdir(exist_ok=True)
    store = ResultStore(out / ".fleet")

    def outputs(bags: list[Path]) -> dict[Path, Path]:
        return {bag: out / name for bag, name in output_names(bags).items()}

    fleet = run_fleet("label", args, args.bag, settings,
                      {"params": raw, "lidar_topic": args.lidar_topic, "outputs": str(out.resolve())}, store, outputs)
    run_record = {"command": "roadbev label", "params_file": str(args.params) if args.params else None,
                  "lidar_topic": args.lidar_topic, "out": str(out), "executor": fleet.executor, "wall_s": fleet.wall_s}
    summary = label_summary(fleet.outcomes, store, run_record)
    report = label_report(summary)
    (out / "summary.json").write_text(to_json(summary))
    (out / "report.md").write_text(report)
    if not args.quiet:
        print(report, end="")
        print(f"summary written to {out / 'summary.json'}, report to {out / 'report.md'}")
    fail_on_failed_bags(fleet)
    return 0
