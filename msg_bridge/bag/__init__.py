"""rosbag2 MCAP bags: writing, CRC-checked reading, partial reads of damaged bags, recovery.

A BAG path is either a rosbag2 directory (with ``metadata.yaml``) or a single ``.mcap`` file
(contract, "Command line"); both read the same way. Every public name is importable from here
(``from msg_bridge.bag import BagWriter, read_messages``); one module per concern:

* :mod:`~msg_bridge.bag.errors`: :class:`BagError` and :class:`DamagedBagError`.
* :mod:`~msg_bridge.bag.typestore`: the message types (ROS 2 Jazzy + ``grid_map_msgs`` +
  ``roadbev_msgs``), :func:`serialize` and :func:`deserialize`.
* :mod:`~msg_bridge.bag.writer`: :class:`BagWriter` (rosbag2 MCAP with chunk CRCs, readable up to
  its last complete chunk if its writer is killed).
* :mod:`~msg_bridge.bag.metadata`: rosbag2's ``metadata.yaml``, the channels' QoS profiles and
  the ``.recording`` marker (:func:`marker_path`).
* :mod:`~msg_bridge.bag.reader`: :func:`read_messages` and :func:`bag_topics`.
* :mod:`~msg_bridge.bag.damage`: damage accounting, :class:`ReadStats`.
* :mod:`~msg_bridge.bag.info`: :func:`bag_info` (what a bag holds, whether it was closed cleanly).
* :mod:`~msg_bridge.bag.recovery`: :func:`recover_bag` (a complete copy of what is readable).
* underneath: :mod:`~msg_bridge.bag.files` (a BAG path opened: its MCAP files scanned, their
  channels) and :mod:`~msg_bridge.bag.mcap_file` (MCAP records, every chunk checked before use).
"""

from __future__ import annotations

from msg_bridge.bag.damage import ReadStats
from msg_bridge.bag.errors import BagError, DamagedBagError
from msg_bridge.bag.info import BagInfo, bag_info
from msg_bridge.bag.metadata import MARKER_SUFFIX, marker_path
from msg_bridge.bag.reader import BagMessage, OnDamage, TopicInfo, bag_topics, read_messages
from msg_bridge.bag.recovery import recover_bag
from msg_bridge.bag.typestore import CUSTOM_PACKAGES, deserialize, serialize, typestore
from msg_bridge.bag.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE, BagWriter

__all__ = [
    "COMPRESSIONS",
    "CUSTOM_PACKAGES",
    "DEFAULT_CHUNK_SIZE",
    "MARKER_SUFFIX",
    "BagError",
    "BagInfo",
    "BagMessage",
    "BagWriter",
    "DamagedBagError",
    "OnDamage",
    "ReadStats",
    "TopicInfo",
    "bag_info",
    "bag_topics",
    "deserialize",
    "marker_path",
    "read_messages",
    "recover_bag",
    "serialize",
    "typestore",
]
