"""``roadbev node``: run the RoadBEV node (the same as the ``roadbev_node`` console script).

ROS arguments follow ``--ros-args`` as usual (``-p name:=value``, ``--params-file FILE``,
``-r from:=to``); ``--backend`` and ``--params`` are shortcuts for the two most common ones
(:mod:`roadbev_ros.node_args`).
"""

from __future__ import annotations

import argparse

from roadbev_ros.node_args import HELP, add_arguments, ros_arguments

__all__ = ["HELP", "add_arguments", "run"]


def run(args: argparse.Namespace) -> int:
    from roadbev_ros.node import main  # lazy: rclpy and the pipeline load only for this command

    return main(ros_arguments(args))
