"""ROS messages <-> numpy and the project's types, and rosbag2 MCAP bags.

Every converter reads messages by attribute only, so rclpy messages (the node), rosbags typestore
messages (bags) and ``mcap_ros2`` decoded messages all work. Converters that build messages take
a factory: :class:`RclpyFactory` (rclpy objects, imported lazily) or :class:`TypestoreFactory`
(``TypestoreFactory(msg_bridge.bag.typestore())`` for bag writing). Every malformed message
raises :class:`MessageError` (a ``ValueError``) saying what is wrong; damaged bags raise
:class:`BagError` (:class:`DamagedBagError` naming the damaged chunk), or are read as far as they
are sound with ``on_damage="skip"`` and a :class:`ReadStats`. No rclpy import happens at module
level.

Modules: ``image`` (Image, CompressedImage), ``camera_info`` (CameraInfo <-> StereoCamera),
``imu`` (Imu -> Attitude, slerp), ``grid_map`` (GridMap <-> arrays + GridSpec), ``preview``
(RoadPreview), ``point_cloud`` (PointCloud2), ``hazards`` (RoadHazards), ``markers`` (the
preview and the hazards as viewers' MarkerArrays), ``tf`` (TF and the camera's mounting),
``tf_buffer`` (a tf2 buffer: ``/tf_static`` and ``/tf`` looked up at a stamp), ``pipeline_io``
(pipeline outputs -> messages), ``bag`` (MCAP bags: write, read, info, recover, over its own
CRC-checked MCAP record reader; one module per concern), ``outputs`` (the node's output
messages, and a bag of them). Evaluation and drive bags, which carry ground truth, are the lab's
(:mod:`roadbev_lab.evaluation.evalbag`).
"""

from __future__ import annotations

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    RclpyFactory,
    TypestoreFactory,
    make_header,
    stamp_from_header,
    stamp_to_ns,
)
from msg_bridge.bag import (
    BagError,
    BagWriter,
    DamagedBagError,
    ReadStats,
    bag_info,
    bag_topics,
    marker_path,
    read_messages,
    recover_bag,
    serialize,
    typestore,
)

__all__ = [
    "BagError",
    "BagWriter",
    "DamagedBagError",
    "MessageError",
    "MessageFactory",
    "RclpyFactory",
    "ReadStats",
    "TypestoreFactory",
    "bag_factory",
    "bag_info",
    "bag_topics",
    "make_header",
    "marker_path",
    "read_messages",
    "recover_bag",
    "serialize",
    "stamp_from_header",
    "stamp_to_ns",
    "typestore",
]


def bag_factory() -> TypestoreFactory:
    """A factory of typestore messages for :class:`BagWriter` (custom types registered)."""
    return TypestoreFactory(typestore())
