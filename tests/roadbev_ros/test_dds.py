"""The shipped Fast DDS profile and the environment that selects it."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from roadbev_ros.dds import PROFILE_ENV_VARS, DdsError, child_env, message_class, profile_path, use_profile

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


def test_profile_has_large_shared_memory_udp_and_no_builtin_transports() -> None:
    root = ET.parse(profile_path()).getroot()
    transports = {t.findtext(f"{NS}transport_id"): t for t in root.iter(f"{NS}transport_descriptor")}
    shm = [t for t in transports.values() if t.findtext(f"{NS}type") == "SHM"]
    udp = [t for t in transports.values() if t.findtext(f"{NS}type") == "UDPv4"]
    assert len(shm) == 1 and len(udp) == 1
    segment_size = shm[0].findtext(f"{NS}segment_size")
    assert segment_size is not None and int(segment_size) >= 64 * 2**20
    participant = next(root.iter(f"{NS}participant"))
    assert participant.get("is_default_profile") == "true"
    assert participant.findtext(f"{NS}rtps/{NS}useBuiltinTransports") == "false"
    used = {e.text for e in participant.iter(f"{NS}transport_id")}
    assert used == set(transports)


def test_use_profile_sets_both_variables_and_respects_the_users_choice() -> None:
    env: dict[str, str] = {}
    assert use_profile(env) == profile_path()
    assert all(env[v] == str(profile_path()) for v in PROFILE_ENV_VARS)
    mine = {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"}
    assert str(use_profile(mine)) == "/etc/my_profile.xml"
    assert mine["FASTDDS_DEFAULT_PROFILES_FILE"] == "/etc/my_profile.xml"
    cyclone = {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    assert use_profile(cyclone) is None and set(cyclone) == {"RMW_IMPLEMENTATION"}
    assert child_env({"X": "1"})["X"] == "1"


def test_message_class() -> None:
    from sensor_msgs.msg import Image

    assert message_class("sensor_msgs/msg/Image") is Image
    assert message_class("sensor_msgs/Image") is Image
    with pytest.raises(DdsError, match="not available"):
        message_class("no_such_msgs/msg/Thing")
    with pytest.raises(DdsError, match="not a ROS message type"):
        message_class("Image")
