"""``roadbev synth OUT``: write a synthetic drive as an evaluation bag (rosbag2 MCAP).

With ``--drive`` the car rides on its road (:class:`roadbev_lab.synth.RidingDrive`: suspension,
``base_link``, odometry) and the bag is a drive bag (:mod:`roadbev_lab.evaluation.drivebag`): the
evaluation-bag topics plus ``/odom``, ``/ground_truth/odom``, ``/tf_static`` and
``/ground_truth/road_map`` (docs/interface/bags.md, "Drive bags").

The bag follows docs/interface/bags.md, "Evaluation bags" (see :mod:`roadbev_lab.evaluation.evalbag`):
stereo images (raw rgb8, or JPEG with ``--compressed``), both CameraInfos per frame, the IMU at
``--imu-rate`` Hz, ``/ground_truth/elevation`` per frame and ``/roadbev/grid_config``; with
``--far-field`` also ``/ground_truth/elevation_far`` on the far-field grid of the ``far_field``
defaults (7.08-15 m in 12 cm cells: docs/concepts/grid.md). ``OUT``
ending in ``.mcap`` gives a single MCAP file, anything else a rosbag2 directory. The same
arguments always give the same bytes (no wall-clock time is stored). The pavement and cameras
are the middle of the ``real-road`` appearance range (``roadbev_lab.synth.REAL_ROAD_MIDDLE``,
scene version 2).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from roadbev_cli.cli import CommandError, add_output_flags, list_item, progress_bar, shows_progress
from roadbev_core.config import FarFieldConfig
from roadbev_lab.evaluation.drivebag import write_drive_bag
from roadbev_lab.evaluation.evalbag import write_eval_bag
from roadbev_lab.synth import (
    FEATURE_NAMES,
    REAL_ROAD_MIDDLE,
    DriveConfig,
    OdometryNoise,
    RidingConfig,
    RidingDrive,
    RoadConfig,
    SyntheticDrive,
)

HELP = "write a synthetic evaluation/training bag (MCAP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:

    parser.add_argument("out", type=Path, help="output bag: NAME.mcap (single file) or a directory (its folder is "
                        "created)")
    parser.add_argument("--drive", action="store_true",
                        help="a drive bag: the car rides on its road (suspension, /odom, /ground_truth/odom, "
                        "/tf_static, /ground_truth/road_map)")
    parser.add_argument("--frames", type=int, default=None, help="stereo frames (default 20)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="seconds of camera frames instead of --frames (frames = duration x rate)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of road, look and motion (default 0)")
    parser.add_argument("--speed", type=float, default=5.0, metavar="MPS", help="vehicle speed in m/s (default 5)")
    parser.add_argument("--rate", "--frame-rate", dest="frame_rate", type=float, default=5.0, metavar="HZ",
                        help="camera rate (default 5 Hz)")
    parser.add_argument("--imu-rate", type=float, default=100.0, metavar="HZ", help="IMU rate (default 100 Hz)")
    parser.add_argument("--road-class", default="C", choices=list("ABCDE"),
                        help="ISO 8608 roughness class (default C)")
    parser.add_argument("--features", nargs="*", type=list_item, metavar="FEATURE", choices=FEATURE_NAMES,
                        help=f"road features repeated along the drive, space-separated, from: "
                        f"{', '.join(FEATURE_NAMES)} "
                        "(default: the synthesiser's mix; give the flag alone for none)")
    parser.add_argument("--surface", choices=["asphalt", "concrete"], default="asphalt",
                        help="pavement texture (default asphalt)")
    parser.add_argument("--grade", type=float, default=None, help="road grade dz/dx (default 0; |g| <= 0.012)")
    parser.add_argument("--cross-slope", type=float, default=None, help="cross slope dz/dy (default 0.02)")
    parser.add_argument("--roughness-scale", type=float, default=None, help="ISO 8608 amplitude factor (default 1)")
    parser.add_argument("--feature-spacing", type=float, default=None, metavar="M",
                        help="mean distance between features along the drive (default 6 m)")
    drive = parser.add_argument_group("--drive options")
    drive.add_argument("--curve-amplitude", type=float, default=0.6, metavar="M",
                       help="half the lateral swing of the S-curves (default 0.6; 0 = straight)")
    drive.add_argument("--lateral-accel", type=float, default=0.5, metavar="MPS2",
                       help="lateral acceleration of the curves (default 0.5 m/s^2)")
    drive.add_argument("--odom-rate", type=float, default=50.0, metavar="HZ", help="/odom rate (default 50 Hz)")
    drive.add_argument("--odom-scale-error", type=float, default=0.005,
                       help="wheel-speed scale error of /odom (default 0.005)")
    drive.add_argument("--odom-speed-noise", type=float, default=0.05, metavar="MPS",
                       help="wheel-speed noise of /odom, 1-sigma (default 0.05 m/s)")
    drive.add_argument("--odom-yaw-rate-bias", type=float, default=0.001, metavar="RADPS",
                       help="yaw-rate bias of /odom (default 0.001 rad/s)")
    drive.add_argument("--odom-yaw-rate-noise", type=float, default=0.002, metavar="RADPS",
                       help="yaw-rate noise of /odom, 1-sigma (default 0.002 rad/s)")
    drive.add_argument("--road-map-resolution", type=float, default=0.02, metavar="M",
                       help="cell size of /ground_truth/road_map (default 0.02 m)")
    parser.add_argument("--far-field", action="store_true",
                        help="also the truth on the far-field grid beyond the grid (/ground_truth/elevation_far; "
                        "the far_field parameters' defaults: 7.08 to 15 m in 12 cm cells)")
    parser.add_argument("--image-scale", type=float, default=1.0, metavar="F",
                        help="scale the 960x528 RSRD half-resolution rig by F (e.g. 0.5; default 1)")
    parser.add_argument("--compressed", action="store_true",
                        help="JPEG sensor_msgs/CompressedImage on .../image_rect/compressed instead of rgb8")
    parser.add_argument("--jpeg-quality", type=int, default=90, metavar="Q", help="JPEG quality (default 90)")
    parser.add_argument("--compression", choices=["zstd", "none"], default="zstd",
                        help="MCAP chunk compression (default zstd)")
    add_output_flags(parser)


def run(args: argparse.Namespace) -> int:


    if args.frames is not None and args.duration is not None:
        raise CommandError("give --frames or --duration, not both")
    if args.duration is not None:
        if not args.duration > 0:
            raise CommandError(f"--duration must be > 0, got {args.duration}")
        args.frames = max(1, int(round(args.duration * args.frame_rate)))
    if args.frames is None:
        args.frames = 20
    if args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    if not 0 < args.image_scale <= 2:
        raise CommandError(f"--image-scale must be in (0, 2], got {args.image_scale}")
    if not 1 <= args.jpeg_quality <= 100:
        raise CommandError(f"--jpeg-quality must be in 1..100, got {args.jpeg_quality}")
    if args.out.exists():
        raise OSError(f"{args.out} exists already; remove it first")
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class=args.road_class, surface=args.surface))
    if args.features is not None:
        road = replace(road, features=tuple(args.features))
    for option, name in (("grade", "grade"), ("cross_slope", "cross_slope"), ("roughness_scale", "roughness_scale"),
                         ("feature_spacing", "feature_spacing_m")):
        if getattr(args, option) is not None:
            road = replace(road, **{name: getattr(args, option)})
    config = DriveConfig(
        frames=args.frames,
        speed_mps=args.speed,
        frame_rate_hz=args.frame_rate,
        imu_rate_hz=args.imu_rate,
        seed=args.seed,
        road=road,
    )
    if args.far_field:
        config = replace(config, far_grid=FarFieldConfig().grid(config.grid))
    if args.image_scale != 1.0:
        config = replace(config, camera=config.camera.scaled(args.image_scale))
    if args.drive:

        riding = RidingConfig(
            drive=config,
            odometry=OdometryNoise(rate_hz=args.odom_rate, speed_scale_error=args.odom_scale_error,
                                   speed_noise_mps=args.odom_speed_noise, yaw_rate_bias=args.odom_yaw_rate_bias,
                                   yaw_rate_noise=args.odom_yaw_rate_noise),
            curve_amplitude_m=args.curve_amplitude,
            max_lateral_accel=args.lateral_accel,
            road_map_resolution_m=args.road_map_resolution,
        )
        drive: SyntheticDrive = RidingDrive(riding)
        write = write_drive_bag
    else:
        drive = SyntheticDrive(config)
        write = write_eval_bag
    with progress_bar(total=len(drive), unit="frame", desc="synth", disable=not shows_progress(args)) as bar:
        counts = write(
            args.out,
            drive,
            compressed=args.compressed,
            compression=args.compression,
            jpeg_quality=args.jpeg_quality,
            progress=bar.update,
        )
    if not args.quiet:
        size = sum(p.stat().st_size for p in ([args.out] if args.out.is_file() else args.out.rglob("*")))
        print(f"wrote {args.out} ({size / 1e6:.1f} MB)")
        for topic, count in sorted(counts.items()):
            print(f"  {topic}: {count}")
    return 0
