"""Recovery: an unfinished bag (a killed writer), a damaged one, one with a damaged summary and a
split bag with a file missing, copied to complete, indexed bags."""

from __future__ import annotations

from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from msg_bridge import BagError, BagWriter, ReadStats, bag_info, marker_path, read_messages, recover_bag
from tests.msg_bridge.bag._bags import (
    SMALL_CHUNKS,
    TEXT_TOPICS,
    TOPICS,
    check_content,
    chunk_indexes,
    data_range,
    flip,
    independent_read,
    messages,
    raw_by_key,
    split_bag,
    summary_start,
    text_bag,
    write_bag,
)


def test_an_unfinished_bag_is_readable_and_recovers_to_a_complete_indexed_copy(tmp_path: Path) -> None:
    """The state a killed writer leaves: finished chunks in the file, no summary, the marker."""
    path = tmp_path / "live.mcap"
    writer = BagWriter(path, chunk_size=SMALL_CHUNKS)
    writer.open()
    for topic, msgtype in TOPICS.items():
        writer.add_topic(topic, msgtype, latched=topic == "/camera_info")
    for i in range(3):
        for topic, msg in messages(1_000_000_000 * (i + 1)).items():
            writer.write(topic, msg, 1_000_000_000 * (i + 1))
    writer.flush(fsync=True)
    assert marker_path(path).is_file()
    stats = ReadStats()
    live = list(read_messages(path, raw=True, on_damage="skip", stats=stats))
    assert len(live) == 3 * len(TOPICS) and stats.unfinished and not stats.lost_unknown
    with pytest.raises(BagError, match="recover"):
        list(read_messages(path))
    info = bag_info(path)
    assert not info.closed and info.marker and "NOT closed cleanly" in "\n".join(info.lines())
    assert {t: i.count for t, i in info.topics.items()} == dict.fromkeys(TOPICS, 3)

    out = tmp_path / "recovered.mcap"
    result = recover_bag(path, out)
    assert sum(result.read.values()) == 3 * len(TOPICS)
    assert bag_info(out).closed and not marker_path(out).exists()
    theirs = independent_read(out)
    assert len(theirs) == 3 * len(TOPICS)
    for mine, (topic, _schema, log_time, decoded) in zip(live, theirs, strict=True):
        assert (mine.topic, mine.log_time_ns) == (topic, log_time)
        check_content(topic, decoded)
    with AnyReader([out]) as reader:  # QoS and types survive the copy
        assert {c.topic: c.msgcount for c in reader.connections} == dict.fromkeys(TOPICS, 3)
    writer.close()
    assert not marker_path(path).exists() and bag_info(path).closed


def test_recovering_a_damaged_bag_keeps_every_sound_chunk(tmp_path: Path) -> None:
    path = tmp_path / "bag.mcap"
    write_bag(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = raw_by_key(path)
    start, _end = data_range(path, chunk_indexes(path)[1])
    data = bytearray(path.read_bytes())
    data[start + 10] ^= 0xFF
    path.write_bytes(bytes(data))
    info = bag_info(path)
    assert info.closed and len(info.damage) == 1 and sum(info.lost.values()) > 0
    out = tmp_path / "copy"
    stats = recover_bag(path, out, compression="none")
    copy = raw_by_key(out)
    assert len(copy) == len(original) - sum(info.lost.values()) == sum(stats.read.values())
    assert all(original[k] == v for k, v in copy.items())
    assert (out / "metadata.yaml").is_file() and bag_info(out).closed
    with pytest.raises(BagError, match="exists already"):
        recover_bag(path, out)


def test_recovering_a_split_bag_with_a_file_missing_copies_the_others(tmp_path: Path) -> None:
    path = tmp_path / "split"
    first, second = split_bag(path)
    second.unlink()
    out = tmp_path / "copy.mcap"
    stats = recover_bag(path, out)
    assert raw_by_key(out) == raw_by_key(first) and sum(stats.read.values()) == 20
    assert stats.damage == ["split_1.mcap: listed in metadata.yaml but missing; its 20 message(s) are lost"]
    assert bag_info(out).closed and not bag_info(out).damage


def test_recovering_a_bag_with_a_damaged_summary_keeps_its_topics(tmp_path: Path) -> None:
    path = tmp_path / "bag.mcap"
    text_bag(path)
    data = path.read_bytes()
    flip(path, data.index(b"/stereo/left/image_rect", summary_start(data)) + 5, 0x20)
    out = tmp_path / "copy.mcap"
    stats = recover_bag(path, out)
    assert set(raw_by_key(out)) == set(raw_by_key(path)) and {t for t, _ in raw_by_key(out)} == set(TEXT_TOPICS)
    assert len(stats.damage) == 1 and "the summary is ignored" in stats.damage[0]
    assert stats.damage == bag_info(path).damage  # the copy and the report name the same damage
