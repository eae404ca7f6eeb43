"""The message types of bags: ROS 2 Jazzy's plus ``grid_map_msgs`` and ``roadbev_msgs``, and CDR
serialisation through them.

The custom types come from their ``.msg`` files: the repository's ``interfaces/`` or an installed
``share/<package>/msg``.
"""

from __future__ import annotations

import os
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any

from msg_bridge._common import MessageError
from msg_bridge.bag.errors import BagError

__all__ = ["CUSTOM_PACKAGES", "deserialize", "serialize", "typestore"]

CUSTOM_PACKAGES = ("grid_map_msgs", "roadbev_msgs")


def _interface_dirs(package: str) -> list[Path]:
    """Places that may hold ``<package>/msg/*.msg``, most specific first."""
    candidates = [Path(__file__).resolve().parents[2] / "interfaces" / package]
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    candidates += [Path(p) / "share" / package for p in prefixes if p]
    return [c for c in candidates if (c / "msg").is_dir()]


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags typestore: ROS 2 Jazzy + ``grid_map_msgs`` + ``roadbev_msgs``."""
    # Imported on first use: rosbags is slow to import and ``import msg_bridge`` needs no typestore.
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for package in CUSTOM_PACKAGES:
        dirs = _interface_dirs(package)
        if not dirs:
            raise BagError(f"cannot find the .msg files of {package} (interfaces/ or share/)")
        for path in sorted((dirs[0] / "msg").glob("*.msg")):
            types.update(get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    store.register(types)
    return store


def serialize(msg: Any, msgtype: str | None = None) -> bytes:
    """CDR bytes of a typestore message (as rclpy and ``ros2 bag`` write them)."""
    store = typestore()
    return bytes(store.serialize_cdr(msg, msgtype or msg.__msgtype__))


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    """A typestore message from CDR bytes.

    Raises:
        MessageError: unknown type or bytes that are not a CDR ``msgtype``.
    """
    store = typestore()
    if msgtype not in store.types:
        raise MessageError(f"unknown message type {msgtype!r}")
    try:
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:  # rosbags raises struct/index/value errors on bad bytes
        raise MessageError(f"{len(data)} bytes are not a valid {msgtype}: {exc!r}") from None
