"""The launch file (launch_ros has no PyPI wheel): it compiles, keeps to the params file, and its
arguments name real node parameters and topics."""

from __future__ import annotations

import ast
from pathlib import Path

from roadbev_core.config import RoadbevConfig

LAUNCH = Path(__file__).resolve().parents[2] / "launch" / "roadbev.launch.py"


def _tree() -> ast.Module:
    return ast.parse(LAUNCH.read_text(), filename=str(LAUNCH))


def test_it_compiles() -> None:
    compile(LAUNCH.read_text(), str(LAUNCH), "exec")


def test_backend_overrides_the_params_file_only_when_given() -> None:
    declared = {
        node.args[0].value: {kw.arg: kw.value for kw in node.keywords}
        for node in ast.walk(_tree())
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument"
        and node.args and isinstance(node.args[0], ast.Constant)
    }
    default = declared["backend"]["default_value"]
    assert isinstance(default, ast.Constant) and default.value == ""
    assert "if backend:" in LAUNCH.read_text()


def test_the_topics_it_remaps_are_the_nodes_defaults() -> None:
    topics = RoadbevConfig().topics
    text = LAUNCH.read_text()
    for topic in (topics.left_image, topics.right_image, topics.left_info, topics.right_info, topics.imu, topics.odom):
        assert f'"{topic}"' in text


def test_the_dds_profile_is_set_only_when_unset() -> None:
    assert 'if "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ' in LAUNCH.read_text()
