"""``roadbev synth OUT``: write a synthetic drive as an evaluation bag (rosbag2 MCAP).

The bag follows the contract's "Evaluation bags" section (see :mod:`msg_bridge.evalbag`):
stereo images (raw rgb8, or JPEG with ``--compressed``), both CameraInfos per frame, the IMU at
``--imu-rate`` Hz, ``/ground_truth/elevation`` per frame and ``/roadbev/grid_config``. ``OUT``
ending in ``.mcap`` gives a single MCAP file, anything else a rosbag2 directory. The same
arguments always give the same bytes (no wall-clock time is stored).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from roadbev_ros.cli import CommandError

HELP = "write a synthetic evaluation/training bag (MCAP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from roadbev_core.synth import FEATURE_NAMES

    parser.add_argument("out", type=Path, help="output bag: NAME.mcap (single file) or a directory")
    parser.add_argument("--frames", type=int, default=20, help="stereo frames (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of road, look and motion (default 0)")
    parser.add_argument("--speed", type=float, default=5.0, metavar="MPS", help="vehicle speed in m/s (default 5)")
    parser.add_argument("--frame-rate", type=float, default=5.0, metavar="HZ", help="camera rate (default 5 Hz)")
    parser.add_argument("--imu-rate", type=float, default=100.0, metavar="HZ", help="IMU rate (default 100 Hz)")
    parser.add_argument("--road-class", default="C", choices=list("ABCDE"),
                        help="ISO 8608 roughness class (default C)")
    parser.add_argument("--features", nargs="*", metavar="FEATURE", choices=FEATURE_NAMES,
                        help=f"road features repeated along the drive, from: {', '.join(FEATURE_NAMES)} "
                        "(default: the synthesiser's mix; give the flag alone for none)")
    parser.add_argument("--surface", choices=["asphalt", "concrete"], default="asphalt")
    parser.add_argument("--image-scale", type=float, default=1.0, metavar="F",
                        help="scale the 960x528 RSRD half-resolution rig by F (e.g. 0.5; default 1)")
    parser.add_argument("--compressed", action="store_true",
                        help="JPEG sensor_msgs/CompressedImage on .../image_rect/compressed instead of rgb8")
    parser.add_argument("--jpeg-quality", type=int, default=90, metavar="Q", help="JPEG quality (default 90)")
    parser.add_argument("--compression", choices=["zstd", "none"], default="zstd",
                        help="MCAP chunk compression (default zstd)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from msg_bridge.evalbag import write_eval_bag
    from roadbev_core.synth import DriveConfig, RoadConfig, SyntheticDrive

    if args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    if not 0 < args.image_scale <= 2:
        raise CommandError(f"--image-scale must be in (0, 2], got {args.image_scale}")
    if not 1 <= args.jpeg_quality <= 100:
        raise CommandError(f"--jpeg-quality must be in 1..100, got {args.jpeg_quality}")
    if args.out.exists():
        raise OSError(f"{args.out} exists already; remove it first")
    road = RoadConfig(road_class=args.road_class, surface=args.surface)
    if args.features is not None:
        road = replace(road, features=tuple(args.features))
    config = DriveConfig(
        frames=args.frames,
        speed_mps=args.speed,
        frame_rate_hz=args.frame_rate,
        imu_rate_hz=args.imu_rate,
        seed=args.seed,
        road=road,
    )
    if args.image_scale != 1.0:
        config = replace(config, camera=config.camera.scaled(args.image_scale))
    drive = SyntheticDrive(config)
    with tqdm(total=len(drive), unit="frame", desc="synth", disable=args.quiet or None, file=sys.stderr) as bar:
        counts = write_eval_bag(
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
