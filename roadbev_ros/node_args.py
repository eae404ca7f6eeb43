"""The node's command line: ``roadbev_node`` and ``roadbev node`` parse the same arguments.

ROS arguments follow ``--ros-args`` as usual (``-p name:=value``, ``--params-file FILE``,
``-r from:=to``); ``--backend`` and ``--params`` are shortcuts for the two most common ones.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from roadbev_core.backends import available
from roadbev_core.config import DEFAULT_BACKEND

HELP = "run the RoadBEV node"
EPILOG = ("Every parameter, with its default and description: config/roadbev.params.yaml, or `ros2 param "
          "describe` on the running node.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("--backend", help=f"backend ({', '.join(available())}; default {DEFAULT_BACKEND}); "
                                          "the parameter 'backend'")
    parser.add_argument("--params", type=Path, metavar="YAML", help="a ROS 2 params file (--params-file)")
    parser.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                        metavar="...", help="ROS arguments (-p name:=value, --params-file F, -r a:=b)")


def parser(prog: str) -> argparse.ArgumentParser:
    """The command line of ``prog`` (``roadbev node`` or the ``roadbev_node`` console script)."""
    out = argparse.ArgumentParser(prog=prog, description=HELP)
    add_arguments(out)
    return out


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
