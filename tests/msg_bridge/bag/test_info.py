"""Bag info: the same topics and counts from the index as from reading every chunk, the report's
lines and its JSON form."""

from __future__ import annotations

import json
from pathlib import Path

from msg_bridge.bag.info import bag_info
from tests.msg_bridge.bag._bags import SMALL_CHUNKS, TOPICS, write_bag


def test_a_closed_bag_from_the_index_and_verified(tmp_path: Path) -> None:
    path = tmp_path / "bag"
    write_bag(path, frames=2, chunk_size=SMALL_CHUNKS)
    verified, indexed = bag_info(path), bag_info(path, verify=False)
    assert verified.topics == indexed.topics
    assert {t: i.count for t, i in verified.topics.items()} == dict.fromkeys(TOPICS, 2)
    assert (verified.start_ns, verified.end_ns) == (indexed.start_ns, indexed.end_ns) == (1_000_000_007, 2_000_000_007)
    assert verified.closed and not verified.marker and not verified.damage and verified.files == [path / "bag.mcap"]
    assert verified.verified and not indexed.verified and verified.chunks == indexed.chunks > 1
    lines = verified.lines()
    assert lines[0] == f"bag:      {path}" and lines[2] == "state:    closed cleanly"
    assert lines[5] == f"messages: {2 * len(TOPICS)} readable over 1.000 s"
    assert "(not verified)" in indexed.lines()[4] and "(not verified)" not in lines[4]
    assert json.loads(json.dumps(verified.to_dict()))["topics"]["/imu"] == {"type": "sensor_msgs/msg/Imu", "count": 2}
