"""The shipped viewer configs (config/roadbev.rviz, config/roadbev.foxglove.json) show what the
node and the hazard monitor really publish and subscribe: every topic with its type, every layer,
message field and diagnostic status they name is read from the running nodes (no screenshot, no
list kept by hand).

The fused map (/roadbev/map, issue 16) is checked as soon as the node publishes it; until then its
entries are the only ones allowed to name a topic the node does not have.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import pytest
import yaml

from ._ros_harness import MS, START_NS, Harness, wait_for

ROOT = Path(__file__).resolve().parents[2]
RVIZ = ROOT / "config" / "roadbev.rviz"
FOXGLOVE = ROOT / "config" / "roadbev.foxglove.json"
# RViz display classes and the message type each one shows (RViz's, not ours)
RVIZ_TYPES = {
    "rviz_default_plugins/Image": "sensor_msgs/msg/Image",
    "grid_map_rviz_plugin/GridMap": "grid_map_msgs/msg/GridMap",
    "rviz_default_plugins/PointCloud2": "sensor_msgs/msg/PointCloud2",
    "rviz_default_plugins/MarkerArray": "visualization_msgs/msg/MarkerArray",
}
NOT_YET = "/roadbev/map"  # the fused map of issue 16, in the configs before the node has it


def type_name(cls: Any) -> str:
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


@pytest.fixture(scope="module")
def node_graph(ros: Any) -> Iterator[dict[str, Any]]:
    """What the node (and the hazard monitor, at their defaults) publish and subscribe, and one of
    each of the node's outputs."""
    from roadbev_ros.hazard_monitor import DEFAULTS, HazardMonitorNode

    h = Harness(ros, params={"diagnostics_period_s": 0.2})
    monitor = HazardMonitorNode(node_name=f"{h.node.get_name()}_hazards")
    try:
        stamp = START_NS
        h.imu_around(stamp + 3 * MS, lambda _t: 0.05)
        h.publish_frame(stamp)
        elevation = h.wait_output(stamp)
        assert wait_for(lambda: len(h.diagnostics) > 0 and len(h.previews) > 0)
        yield {
            "published": {p.topic_name: type_name(p.msg_type) for p in h.node.publishers},
            "subscribed": {s.topic_name: type_name(s.msg_type) for s in h.node.subscriptions},
            "monitor_published": {p.topic_name: type_name(p.msg_type) for p in monitor.publishers},
            "hazard_markers": str(DEFAULTS["markers_topic"]),
            "layers": {h.node.config.topics.elevation: list(elevation.layers)},
            "preview": h.previews[-1],
            "statuses": [s.name for s in h.diagnostics[-1].status],
            "hardware_ids": {s.hardware_id for s in h.diagnostics[-1].status},
            "config": h.node.config,
        }
    finally:
        monitor.destroy_node()
        h.close()


def known(graph: dict[str, Any], topic: str) -> str | None:
    """The type of ``topic`` as the node or the hazard monitor has it (None: neither publishes nor
    subscribes it)."""
    return cast("str | None", graph["published"].get(topic) or graph["subscribed"].get(topic)
                or graph["monitor_published"].get(topic))


def check_topic(graph: dict[str, Any], topic: str, msgtype: str | None = None) -> bool:
    """Whether ``topic`` is checked (False: the fused map, not in this node yet)."""
    have = known(graph, topic)
    if have is None and topic == NOT_YET:
        return False
    assert have is not None, f"{topic} is neither published nor subscribed by the node"
    if msgtype is not None:
        assert have == msgtype, f"{topic}: the config shows {msgtype}, the node has {have}"
    return True


def rviz_displays() -> list[dict[str, Any]]:
    config = yaml.safe_load(RVIZ.read_text())
    out: list[dict[str, Any]] = []

    def walk(displays: list[dict[str, Any]]) -> None:
        for d in displays:
            out.append(d)
            walk(d.get("Displays", []))

    walk(config["Visualization Manager"]["Displays"])
    return out


def test_every_rviz_display_shows_a_topic_and_type_of_the_node(node_graph: dict[str, Any]) -> None:
    shown = 0
    for display in rviz_displays():
        if "Topic" not in display:
            continue
        topic = display["Topic"]["Value"] if isinstance(display["Topic"], dict) else display["Topic"]
        assert display["Class"] in RVIZ_TYPES, f"display {display['Name']!r}: unknown class {display['Class']}"
        if not check_topic(node_graph, topic, RVIZ_TYPES[display["Class"]]):
            continue
        shown += 1
        if topic in node_graph["layers"]:  # GridMap displays: their layers are the node's
            for key in ("Height Layer", "Color Layer"):
                assert display[key] in node_graph["layers"][topic], (display["Name"], key, display[key])
        if display["Class"] == "rviz_default_plugins/Image":  # the node's QoS is best effort
            assert display["Topic"]["Reliability Policy"] == "Best Effort"
    config = node_graph["config"]
    assert shown >= 4
    shown_topics = {d["Topic"]["Value"] for d in rviz_displays() if "Topic" in d}
    assert {config.topics.left_image, config.topics.elevation} <= shown_topics
    # the far-field grid, which the node publishes at its defaults (far_field.enabled)
    assert config.far_field.topic in shown_topics
    assert node_graph["published"][config.far_field.topic] == RVIZ_TYPES["grid_map_rviz_plugin/GridMap"]
    # the preview and the hazards as markers, each from its own node
    hazard_markers = node_graph["hazard_markers"]
    assert {config.topics.preview_markers, hazard_markers} <= shown_topics
    assert node_graph["published"][config.topics.preview_markers] == RVIZ_TYPES["rviz_default_plugins/MarkerArray"]
    assert node_graph["monitor_published"][hazard_markers] == RVIZ_TYPES["rviz_default_plugins/MarkerArray"]
    manager = yaml.safe_load(RVIZ.read_text())["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "odom"  # docs/interface/topics.md: the fused map's frame
    assert manager["Views"]["Current"]["Target Frame"] == "base_link"


def foxglove_topics(layout: dict[str, Any]) -> list[tuple[str, str, str | None]]:
    """(panel, topic, field path or None) of every topic a panel names."""
    out: list[tuple[str, str, str | None]] = []
    for panel, config in layout["configById"].items():
        for topic in config.get("topics", {}):
            out.append((panel, topic, None))
        for key in ("imageTopic", "calibrationTopic"):
            if key in config.get("imageMode", {}):
                out.append((panel, config["imageMode"][key], None))
        for path in config.get("paths", []):
            topic, _, fields = path["value"].partition(".")
            out.append((panel, topic, fields))
        for key in ("topicPath", "topicToRender"):
            if key in config:
                topic, _, fields = config[key].partition(".")
                out.append((panel, topic, fields or None))
    return out


def resolve(msg: Any, path: str) -> Any:
    """Follow a Foxglove message path (``tracks[0].elevation[:]``) through a message."""
    value = msg
    for part in path.split("."):
        name, *indices = re.split(r"\[", part)
        assert hasattr(value, name), f"{type(value).__name__} has no field {name!r}"
        value = getattr(value, name)
        for index in indices:
            index = index.rstrip("]")
            if index != ":":
                value = value[int(index)]
    return value


def test_every_foxglove_panel_shows_a_topic_field_and_layer_of_the_node(node_graph: dict[str, Any]) -> None:
    layout = json.loads(FOXGLOVE.read_text())
    checked = 0
    for panel, topic, fields in foxglove_topics(layout):
        if not check_topic(node_graph, topic):
            continue
        checked += 1
        if fields and topic == node_graph["config"].topics.preview:
            resolve(node_graph["preview"], fields)
        settings = layout["configById"][panel].get("topics", {}).get(topic, {})
        if "colorField" in settings and topic in node_graph["layers"]:
            assert settings["colorField"] in node_graph["layers"][topic], (panel, topic, settings["colorField"])
    assert checked >= 6
    shown = {topic for _, topic, _ in foxglove_topics(layout)}
    assert {node_graph["config"].topics.preview_markers, node_graph["hazard_markers"]} <= shown
    far = node_graph["config"].far_field.topic
    assert far in shown and far in node_graph["published"]
    status = layout["configById"]["DiagnosticStatusPanel!roadbev"]
    assert status["selectedName"] in node_graph["statuses"]
    assert status["selectedHardwareId"] in node_graph["hardware_ids"]
    elevation = layout["configById"]["3D!elevation"]
    assert f"frame:{node_graph['config'].topics.frame_id}" in elevation["transforms"]
    # the fused map is coloured by elevation in one view and by uncertainty in the other
    colour = {p: layout["configById"][p]["topics"][NOT_YET]["colorField"] for p in ("3D!elevation", "3D!uncertainty")}
    assert colour == {"3D!elevation": "elevation", "3D!uncertainty": "uncertainty"}
    for layer in colour.values():  # layers the per-frame grid has too (docs/interface/topics.md: the map adds more)
        assert layer in node_graph["layers"][node_graph["config"].topics.elevation]


def test_a_field_path_that_the_message_lacks_is_caught(node_graph: dict[str, Any]) -> None:
    with pytest.raises(AssertionError, match="has no field 'profile'"):
        resolve(node_graph["preview"], "tracks[0].profile[:]")
