"""``roadbev node`` argument handling (the node itself runs in test_e2e / test_node)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from roadbev_ros import node_args


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    node_args.add_arguments(parser)
    return parser.parse_args(argv)


def test_shortcuts_and_ros_arguments_are_passed_to_rclpy(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("roadbev:\n  ros__parameters: {}\n")
    args = parse(["--backend", "bm", "--params", str(params), "--ros-args", "-p", "sync_slop_s:=0.05",
                  "-r", "/stereo/left/image_rect:=/cam/left"])
    assert node_args.ros_arguments(args) == [
        "roadbev_node", "--ros-args", "--params-file", str(params), "-p", "backend:=bm",
        "-p", "sync_slop_s:=0.05", "-r", "/stereo/left/image_rect:=/cam/left",
    ]
    assert node_args.ros_arguments(parse([])) == ["roadbev_node"]


def test_a_missing_params_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(OSError, match="params file not found"):
        node_args.ros_arguments(parse(["--params", str(tmp_path / "nope.yaml")]))


@pytest.mark.parametrize(
    "ros_args, reason",
    [
        (["-p", "base_hieght:=1.2"], "unknown parameter 'base_hieght' (did you mean 'base_height'?)"),
        (["-p", "sync_slop_s:=fast"], "sync_slop_s"),
        (["-p", "resolution:=0.001"], "voxels, more than the limit"),
        (["--params-file", "{typo}"], "unknown parameter 'preview.tyre_width' (did you mean 'preview.tyre_width_m'?)"),
        (["--params-file", "{other}"], "no section for node 'roadbev'"),
        (["-p", "map.enabled:=maybe"], "parameter map.enabled: 'maybe' is a string, expected a bool (true or false)"),
        (["-p", "preview.rear_axle:=3"], "parameter preview.rear_axle: 3 is an integer, expected a bool"),
        (["--params-file", "{int_bool}"], "parameter require_imu: 1 is an integer, expected a bool"),
    ],
)
def test_the_node_refuses_a_typo_or_a_wrong_type_at_start(tmp_path: Path, ros_args: list[str], reason: str) -> None:
    """What `roadbev node`, `ros2 run` and the launch file's params file all end in: exit 2, the name."""
    import subprocess
    import sys

    from roadbev_ros.dds import child_env

    typo = tmp_path / "typo.yaml"
    typo.write_text("roadbev:\n  ros__parameters:\n    preview:\n      tyre_width: 0.2\n")
    other = tmp_path / "other.yaml"
    other.write_text("camera_driver:\n  ros__parameters:\n    exposure: 3\n")
    int_bool = tmp_path / "int_bool.yaml"
    int_bool.write_text("roadbev:\n  ros__parameters:\n    require_imu: 1\n")
    args = [a.format(typo=typo, other=other, int_bool=int_bool) for a in ros_args]
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "node", "--ros-args", *args],
                          capture_output=True, text=True, timeout=120, env=child_env())
    assert proc.returncode == 2, proc.stderr
    assert reason in proc.stderr
    assert proc.stderr.strip().splitlines() == [f"roadbev node: error: {proc.stderr.split(': error: ', 1)[1].strip()}"]


@pytest.mark.parametrize("program, module", [
    ("roadbev_node", "roadbev_ros.node"),
    ("roadbev_preview_controller", "roadbev_ros.preview_controller"),
    ("roadbev_hazard_monitor", "roadbev_ros.hazard_monitor"),
])
def test_help_of_each_node_executable_prints_its_usage_and_starts_nothing(
        program: str, module: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib

    from roadbev_ros import dds

    def no_ros(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("--help started ROS")

    monkeypatch.setattr(dds, "init_ros", no_ros)
    for flag in ("--help", "-h"):
        assert importlib.import_module(module).main([program, flag]) == 0
        out = capsys.readouterr().out
        assert out.startswith(f"usage: {program}")
    # after --ros-args, -h is rclpy's, not the executable's
    assert not dds.asks_for_help([program, "--ros-args", "-p", "a:=1", "-h"])


@pytest.mark.parametrize("argv, reason", [
    (["roadbev_preview_controller", "--ros-args", "-p", "control_rate_hz:=300"],
     "roadbev_preview_controller: error: parameter control_rate_hz: 300 is an integer, expected a double "
     "(write 300.0)"),
    (["roadbev_hazard_monitor", "--ros-args", "-p", "confirm_hits:=2.5"],
     "roadbev_hazard_monitor: error: parameter confirm_hits: 2.5 is a double, expected an integer"),
])
def test_the_small_nodes_refuse_a_wrong_type_in_one_line(argv: list[str], reason: str) -> None:
    import subprocess
    import sys

    from roadbev_ros.dds import child_env

    module = "roadbev_ros.preview_controller" if "controller" in argv[0] else "roadbev_ros.hazard_monitor"
    proc = subprocess.run([sys.executable, "-m", module, *argv[1:]], capture_output=True, text=True, timeout=120,
                          env=child_env())
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [reason]
