"""``roadbev node``: run the RoadBEV node (the same as the ``roadbev_node`` console script).

ROS arguments follow ``--ros-args`` as usual (``-p name:=value``, ``--params-file FILE``,
``-r from:=to``); ``--backend`` and ``--params`` are shortcuts for the two most common ones.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "run the RoadBEV node"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--backend", help="backend (bev_sweep, stereo, mono, sgbm, bm); a parameter")
    parser.add_argument("--params", type=Path, metavar="YAML", help="a ROS 2 params file (--params-file)")
    parser.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                        metavar="...", help="ROS arguments (-p name:=value, --params-file F, -r a:=b)")


def ros_arguments(args: argparse.Namespace) -> list[str]:
    """The argv handed to rclpy: ``roadbev_node --ros-args ...``."""
    ros_args: list[str] = []
    if args.params is not None:
        if not args.params.is_file():
            raise OSError(f"params file not found: {args.params}")
        ros_args += ["--params-file", str(args.params)]
    if args.backend:
        ros_args += ["-p", f"backend:={args.backend}"]
    ros_args += list(args.ros_args or [])
    return ["roadbev_node", "--ros-args", *ros_args] if ros_args else ["roadbev_node"]


def run(args: argparse.Namespace) -> int:
    from roadbev_ros.node import main

    return main(ros_arguments(args))
