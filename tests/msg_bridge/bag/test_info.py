"""Bag info: the same topics and counts from the index as from reading every chunk, the report's
lines and its JSON form; a damaged summary and a missing file of a split bag in the report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from msg_bridge.bag.info import bag_info
from tests.msg_bridge.bag._bags import (
    SMALL_CHUNKS,
    TEXT_TOPICS,
    TOPICS,
    flip,
    split_bag,
    summary_start,
    text_bag,
    write_bag,
)


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


@pytest.mark.parametrize("verify", [True, False])
def test_a_damaged_summary_is_reported_and_its_topics_are_not_used(tmp_path: Path, verify: bool) -> None:
    path = tmp_path / "bag.mcap"
    text_bag(path)
    data = path.read_bytes()
    flip(path, data.index(b"/stereo/left/image_rect", summary_start(data)) + 10, ord("t") ^ ord("\r"))
    info = bag_info(path, verify=verify)
    assert {t: i.count for t, i in info.topics.items()} == {TEXT_TOPICS[0]: 40, TEXT_TOPICS[1]: 20}
    assert info.closed and not info.lost and len(info.damage) == 1
    assert "the summary's CRC does not match: the summary is ignored" in info.damage[0]


def test_a_split_bag_with_a_file_missing_names_it(tmp_path: Path) -> None:
    path = tmp_path / "split"
    first, second = split_bag(path)
    second.unlink()
    for verify in (True, False):
        info = bag_info(path, verify=verify)
        assert info.files == [first] and sum(i.count for i in info.topics.values()) == 20
        assert info.damage == ["split_1.mcap: listed in metadata.yaml but missing; its 20 message(s) are lost"]
        assert "  split_1.mcap: listed in metadata.yaml but missing; its 20 message(s) are lost" in info.lines()
