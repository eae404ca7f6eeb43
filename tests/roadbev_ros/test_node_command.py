"""``roadbev node`` argument handling (the node itself runs in test_e2e / test_node)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from roadbev_ros.commands import node as node_command


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    node_command.add_arguments(parser)
    return parser.parse_args(argv)


def test_shortcuts_and_ros_arguments_are_passed_to_rclpy(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("roadbev:\n  ros__parameters: {}\n")
    args = parse(["--backend", "bm", "--params", str(params), "--ros-args", "-p", "sync_slop_s:=0.05",
                  "-r", "/stereo/left/image_rect:=/cam/left"])
    assert node_command.ros_arguments(args) == [
        "roadbev_node", "--ros-args", "--params-file", str(params), "-p", "backend:=bm",
        "-p", "sync_slop_s:=0.05", "-r", "/stereo/left/image_rect:=/cam/left",
    ]
    assert node_command.ros_arguments(parse([])) == ["roadbev_node"]


def test_a_missing_params_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(OSError, match="params file not found"):
        node_command.ros_arguments(parse(["--params", str(tmp_path / "nope.yaml")]))
