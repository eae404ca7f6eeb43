"""The typestore: the repository's interface packages registered, CDR both ways, bad input named."""

from __future__ import annotations

from pathlib import Path

import pytest

from msg_bridge import MessageError, bag_factory
from msg_bridge.bag.typestore import CUSTOM_PACKAGES, _interface_dirs, deserialize, serialize, typestore

REPO = Path(__file__).resolve().parents[3]


def test_every_custom_message_of_the_repository_is_registered() -> None:
    expected = {f"{package}/msg/{p.stem}" for package in CUSTOM_PACKAGES
                for p in (REPO / "interfaces" / package / "msg").glob("*.msg")}
    assert len(expected) >= 4
    assert expected <= set(typestore().types)


@pytest.mark.parametrize("package", CUSTOM_PACKAGES)
def test_the_checkouts_interfaces_come_before_an_installed_copy(package: str) -> None:
    """Edits of a .msg file in the repository take effect without reinstalling the package."""
    assert _interface_dirs(package)[0] == REPO / "interfaces" / package


def test_serialize_and_deserialize_are_inverse() -> None:
    msg = bag_factory().new("std_msgs/msg/String", data="road")
    data = serialize(msg)
    assert data == serialize(msg, "std_msgs/msg/String")
    assert deserialize(data, "std_msgs/msg/String").data == "road"


def test_deserialize_names_an_unknown_type_and_bad_bytes() -> None:
    with pytest.raises(MessageError, match="unknown message type 'nope_msgs/msg/Nope'"):
        deserialize(b"", "nope_msgs/msg/Nope")
    with pytest.raises(MessageError, match=r"1 bytes are not a valid sensor_msgs/msg/Imu"):
        deserialize(b"\x00", "sensor_msgs/msg/Imu")
