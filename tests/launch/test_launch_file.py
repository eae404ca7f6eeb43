"""The launch file (launch_ros has no PyPI wheel): it compiles, keeps to the params file, and its
arguments name real node parameters and topics."""

from __future__ import annotations

import ast
import sys
import types
from pathlib import Path
from typing import Any

import pytest

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


# --- behaviour: the launch file run against stand-ins of launch / launch_ros ----------------------
# launch_ros has no PyPI wheel. The stand-ins keep the semantics the file relies on: a
# LaunchConfiguration performs to the value given for its name (else the declared default), a
# launch_ros Node records what it was given, OpaqueFunction calls its function with the context.


class _Context:
    def __init__(self, values: dict[str, str]) -> None:
        self.launch_configurations = values


class _Configuration:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: _Context) -> str:
        return context.launch_configurations[self.name]


class _Join:
    def __init__(self, parts: list[Any]) -> None:
        self.parts = parts

    def perform(self, context: _Context) -> str:
        return "/".join(p if isinstance(p, str) else p.perform(context) for p in self.parts)


class _Share:
    def __init__(self, package: str) -> None:
        self.package = package

    def perform(self, _context: _Context) -> str:
        return f"/opt/share/{self.package}"


class _Declare:
    def __init__(self, name: str, default_value: Any = None, description: str = "") -> None:
        self.name, self.default_value, self.description = name, default_value, description


class _Opaque:
    def __init__(self, function: Any) -> None:
        self.function = function


class _Node:
    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs


def _launch(monkeypatch: pytest.MonkeyPatch, **given: str) -> list[_Node]:
    """The nodes the launch file starts with ``given`` launch arguments (the others at their defaults)."""
    modules = {
        "launch": types.SimpleNamespace(LaunchContext=_Context, LaunchDescription=lambda items: items),
        "launch.actions": types.SimpleNamespace(DeclareLaunchArgument=_Declare, OpaqueFunction=_Opaque),
        "launch.substitutions": types.SimpleNamespace(LaunchConfiguration=_Configuration,
                                                      PathJoinSubstitution=_Join),
        "launch_ros": types.SimpleNamespace(),
        "launch_ros.actions": types.SimpleNamespace(Node=_Node),
        "launch_ros.substitutions": types.SimpleNamespace(FindPackageShare=_Share),
    }
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    namespace: dict[str, Any] = {"__name__": "roadbev_launch"}
    exec(compile(LAUNCH.read_text(), str(LAUNCH), "exec"), namespace)
    items = namespace["generate_launch_description"]()
    declared = {item.name: item for item in items if isinstance(item, _Declare)}
    unknown = set(given) - set(declared)
    assert not unknown, f"not launch arguments: {unknown}"
    context = _Context({})
    values = {name: d.default_value if isinstance(d.default_value, str) else d.default_value.perform(context)
              for name, d in declared.items()}
    context.launch_configurations = {**values, **given}
    (opaque,) = [item for item in items if isinstance(item, _Opaque)]
    nodes: list[_Node] = opaque.function(context)
    return nodes


def test_defaults_start_the_node_alone_on_wall_time_with_the_shipped_params(monkeypatch: pytest.MonkeyPatch) -> None:
    (node,) = _launch(monkeypatch)
    kw = node.kwargs
    assert (kw["package"], kw["executable"], kw["name"], kw["namespace"]) == ("roadbev_ros", "roadbev_node", "roadbev",
                                                                           "")
    assert kw["parameters"] == ["/opt/share/roadbev_ros/config/roadbev.params.yaml", {"use_sim_time": False}]
    assert kw["additional_env"]["FASTRTPS_DEFAULT_PROFILES_FILE"].endswith("config/fastdds.xml")
    assert ("/stereo/left/image_rect", "/stereo/left/image_rect") in kw["remappings"]


def test_arguments_reach_the_node_and_rviz(monkeypatch: pytest.MonkeyPatch) -> None:
    node, rviz = _launch(monkeypatch, use_sim_time="true", namespace="front", rviz="true", backend="bm",
                         publish_odom_tf="true", params_file="/cars/a.yaml", left_image="/cam/left/image_rect")
    kw = node.kwargs
    assert kw["namespace"] == "front"
    assert kw["parameters"] == ["/cars/a.yaml", {"use_sim_time": True}, {"backend": "bm"},
                                {"publish_odom_tf": True}]
    assert ("/stereo/left/image_rect", "/cam/left/image_rect") in kw["remappings"]
    assert rviz.kwargs["executable"] == "rviz2" and rviz.kwargs["namespace"] == "front"
    assert rviz.kwargs["arguments"] == ["-d", "/opt/share/roadbev_ros/config/roadbev.rviz"]
    assert rviz.kwargs["parameters"] == [{"use_sim_time": True}]


def test_a_flag_that_is_not_true_or_false_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="use_sim_time:='yes': expected true or false"):
        _launch(monkeypatch, use_sim_time="yes")
