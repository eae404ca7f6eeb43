"""The interface packages: built from upstream definitions (type hashes), and usable over DDS.

The publisher runs in a second process; the test process subscribes in its own rclpy context
on a random ROS domain, so parallel test runs do not hear each other.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from msg_bridge import RclpyFactory, typestore
from msg_bridge.grid_map import grid_map_to_arrays
from msg_bridge.preview import preview_from_message

REPO = Path(__file__).resolve().parents[2]
MESSAGES = [
    "grid_map_msgs/msg/GridMap",
    "grid_map_msgs/msg/GridMapInfo",
    "roadbev_msgs/msg/RoadPreview",
    "roadbev_msgs/msg/WheelTrackProfile",
]
# RIHS01 of grid_map_msgs/GridMap computed from the upstream definitions (ANYbotics/grid_map,
# branch jazzy, 2.2.1, commit 7ba25bd): pinned so an edit of the .msg files cannot go unnoticed.
UPSTREAM_GRID_MAP_HASH = "RIHS01_343b0e72887541beda6b035cc053f2d6fffaad9d6dcb2773c15a808dfca31fde"


def _share(msgtype: str) -> Path:
    package, kind, name = msgtype.split("/")
    return Path(sys.prefix) / "share" / package / kind / name


@pytest.mark.parametrize("msgtype", MESSAGES)
def test_generated_type_hash_equals_the_one_rosbags_computes(msgtype: str) -> None:
    description = json.loads(_share(msgtype).with_suffix(".json").read_text())
    generated = {h["type_name"]: h["hash_string"] for h in description["type_hashes"]}
    assert generated[msgtype] == typestore().hash_rihs01(msgtype)
    package, kind, name = msgtype.split("/")
    installed = _share(msgtype).with_suffix(".msg").read_bytes()
    assert installed == (REPO / "interfaces" / package / kind / f"{name}.msg").read_bytes()


# Added with the hazard monitor: checked once the venv's interfaces are rebuilt (scripts/setup_venv.sh).
HAZARD_MESSAGES = ["roadbev_msgs/msg/RoadHazard", "roadbev_msgs/msg/RoadHazardArray",
                   "roadbev_msgs/msg/WheelTrackRoughness"]


@pytest.mark.parametrize("msgtype", HAZARD_MESSAGES)
def test_hazard_messages_are_generated_from_the_repository(msgtype: str) -> None:
    if not _share(msgtype).with_suffix(".json").exists():
        pytest.skip("roadbev_msgs in this venv predates the hazard messages: run scripts/setup_venv.sh")
    test_generated_type_hash_equals_the_one_rosbags_computes(msgtype)


def test_grid_map_hash_is_upstreams() -> None:
    assert typestore().hash_rihs01("grid_map_msgs/msg/GridMap") == UPSTREAM_GRID_MAP_HASH


def test_services_are_generated() -> None:
    from grid_map_msgs.srv import GetGridMap, GetGridMapInfo, ProcessFile, SetGridMap

    assert GetGridMap.Request().layers == [] and GetGridMapInfo.Response().info.resolution == 0.0
    assert ProcessFile.Response().success is False and SetGridMap.Request().map.layers == []


PUBLISHER = textwrap.dedent(
    """
    import time
    import numpy as np
    import rclpy
    from grid_map_msgs.msg import GridMap
    from roadbev_msgs.msg import RoadPreview
    from msg_bridge import RclpyFactory
    from msg_bridge.grid_map import elevation_grid_map
    from msg_bridge.preview import road_preview_message
    from roadbev_core.config import GridSpec
    from roadbev_core.preview import wheel_track_profiles

    grid = GridSpec(x_max=3.36)
    elevation = np.linspace(-0.1, 0.1, grid.n_rows * grid.n_cols, dtype=np.float32).reshape(grid.shape)
    f = RclpyFactory()
    rclpy.init()
    node = rclpy.create_node("interfaces_test_publisher")
    pub_map = node.create_publisher(GridMap, "/test/elevation", 10)
    pub_preview = node.create_publisher(RoadPreview, "/test/preview", 10)
    profiles = wheel_track_profiles(elevation, elevation * 0 + 0.01, grid, vehicle_speed=4.0)
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        pub_map.publish(elevation_grid_map(elevation, None, grid, f, stamp_ns=5_000_000_001))
        pub_preview.publish(road_preview_message(profiles, f, stamp_ns=5_000_000_001))
        time.sleep(0.05)
    """
)


def test_publish_and_receive_both_packages_across_processes() -> None:
    import rclpy
    from grid_map_msgs.msg import GridMap
    from rclpy.executors import SingleThreadedExecutor
    from roadbev_msgs.msg import RoadPreview

    domain = random.Random().randint(100, 200)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONPATH=str(REPO))
    profile = REPO / "config" / "fastdds.xml"
    if profile.is_file():
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER], env=env, cwd=REPO)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    received: dict[str, Any] = {}

    def keep(key: str) -> Callable[[Any], None]:
        def callback(msg: Any) -> None:
            received.setdefault(key, msg)

        return callback

    try:
        node = rclpy.create_node("interfaces_test_subscriber", context=context)
        node.create_subscription(GridMap, "/test/elevation", keep("map"), 10)
        node.create_subscription(RoadPreview, "/test/preview", keep("preview"), 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 20.0
        while len(received) < 2 and time.monotonic() < deadline and publisher.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        assert set(received) == {"map", "preview"}, "nothing received over DDS"
        # the running type support's hash, as DDS announces it, is the rosbags/upstream one
        infos = node.get_publishers_info_by_topic("/test/elevation")
        assert infos and str(infos[0].topic_type_hash) == UPSTREAM_GRID_MAP_HASH
        decoded = grid_map_to_arrays(received["map"])
        assert decoded.grid.shape == (40, 64) and decoded.stamp_ns == 5_000_000_001
        assert decoded.layers["elevation"][0, 0] == pytest.approx(-0.1)
        preview = preview_from_message(received["preview"])
        assert [t.name for t in preview.profiles.tracks] == ["left", "right"]
        assert preview.time_of_arrival is not None
        np.testing.assert_allclose(preview.time_of_arrival[0], (2.16 + 0.015) / 4.0, rtol=1e-6)
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
        publisher.kill()
        publisher.wait()


def test_rclpy_messages_accept_what_the_factory_builds() -> None:
    f = RclpyFactory()
    msg = f.new("roadbev_msgs/msg/WheelTrackProfile", elevation=f.sequence(np.array([1.5], np.float32)))
    assert list(msg.elevation) == [1.5]
