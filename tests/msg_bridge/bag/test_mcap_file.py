"""The MCAP record reader: resynchronising after a damaged chunk header, the summary's index of
what was lost, files that are not MCAP, and messages outside chunks."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer

from msg_bridge import BagWriter, ReadStats, bag_factory, bag_topics, read_messages, serialize, typestore
from msg_bridge.bag.mcap_file import McapFormatError, load_chunk, loose_message_channel, scan_file

N = 300


def _write(path: Path) -> None:
    factory = bag_factory()
    with BagWriter(path, chunk_size=2048) as writer:
        writer.add_topic("/s", "std_msgs/msg/String")
        for k in range(N):
            writer.write("/s", factory.new("std_msgs/msg/String", data=f"message {k:04d} " + "x" * 40), k)


def test_a_sound_file_scans_closed_with_indexed_crc_chunks(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    _write(path)
    scan = scan_file(path)
    assert scan.closed and scan.summary_crc_ok and not scan.damage and scan.profile == "ros2"
    assert len(scan.chunks) > 5 and all(c.crc and not c.cut for c in scan.chunks)
    assert scan.statistics is not None
    assert sum(sum(c.indexed_counts.values()) for c in scan.chunks) == N == sum(scan.statistics.values())
    content, damage = load_chunk(scan.chunks[0])
    assert damage is None and content is not None and content.channels[0].topic == "/s"


@pytest.mark.parametrize("field_offset", [1, 5, 12])  # the record length, its high bytes, the start time
def test_a_damaged_chunk_header_costs_that_chunk_only(tmp_path: Path, field_offset: int) -> None:
    path = tmp_path / "a.mcap"
    _write(path)
    victim = scan_file(path).chunks[3]
    lost_here = sum(victim.indexed_counts.values())
    data = bytearray(path.read_bytes())
    data[victim.offset + field_offset] ^= 0xA5
    path.write_bytes(bytes(data))
    stats = ReadStats()
    got = [m.msg.data for m in read_messages(path, on_damage="skip", stats=stats)]
    assert stats.damage
    if len(got) < N:  # the chunk is gone: exactly its messages, counted from the summary's index
        assert len(got) == N - lost_here and stats.lost["/s"] == lost_here
    # what is delivered is the original, in order
    expected = [f"message {k:04d} " + "x" * 40 for k in range(N)]
    assert got == [t for t in expected if t in set(got)]


def test_not_an_mcap_file(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello, this is text")
    with pytest.raises(McapFormatError, match="magic"):
        scan_file(path)
    path.write_bytes(b"")
    with pytest.raises(McapFormatError, match="too short"):
        scan_file(path)


def test_messages_outside_chunks_are_found_and_read(tmp_path: Path) -> None:
    path = tmp_path / "loose.mcap"
    factory = bag_factory()
    text, _digest = typestore().generate_msgdef("std_msgs/msg/String", ros_version=2)
    with path.open("wb") as stream:
        writer = Writer(stream, use_chunking=False, use_statistics=False)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", text.encode())
        channels = [writer.register_channel(topic, "cdr", schema) for topic in ("/a", "/b")]
        for k in range(5):
            writer.add_message(channels[k % 2], k, serialize(factory.new("std_msgs/msg/String", data=f"m{k}")), k)
        writer.finish()
    scan = scan_file(path)
    assert not scan.chunks and scan.statistics is None
    assert [loose_message_channel(scan, offset) for _t, offset, _n in scan.loose] == [channels[k % 2] for k in range(5)]
    assert {t: i.count for t, i in bag_topics(path).items()} == {"/a": 3, "/b": 2}
    assert [(m.topic, m.msg.data) for m in read_messages(path)] == [("/a" if k % 2 == 0 else "/b", f"m{k}")
                                                                     for k in range(5)]
