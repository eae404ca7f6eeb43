"""The MCAP record reader: resynchronising after a damaged chunk header, the summary's index of
what was lost, files that are not MCAP, and messages outside chunks; a summary used only when its
CRC and records are sound, the data section's CRC, damaged message indexes never trusted."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer

from msg_bridge import BagWriter, ReadStats, bag_factory, bag_topics, read_messages, serialize, typestore
from msg_bridge.bag import OnDamage
from msg_bridge.bag.mcap_file import McapFormatError, load_chunk, loose_message_channel, scan_file
from tests.msg_bridge.bag._bags import (
    OP_CHANNEL,
    OP_FOOTER,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    TEXT_TOPICS,
    flip,
    records,
    summary_start,
    text_bag,
)

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


def _loose_bag(path: Path, topics: tuple[str, ...], *, statistics: bool = True, data_crcs: bool = False) -> list[int]:
    """A bag without chunks: five strings ``m0``..``m4`` at log times 0..4, on ``topics`` in turn;
    the channel ids of ``topics``."""
    factory = bag_factory()
    text, _digest = typestore().generate_msgdef("std_msgs/msg/String", ros_version=2)
    with path.open("wb") as stream:
        writer = Writer(stream, use_chunking=False, use_statistics=statistics, enable_data_crcs=data_crcs)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", text.encode())
        channels = [writer.register_channel(topic, "cdr", schema) for topic in topics]
        for k in range(5):
            message = serialize(factory.new("std_msgs/msg/String", data=f"m{k}"))
            writer.add_message(channels[k % len(topics)], k, message, k)
        writer.finish()
    return channels


def test_messages_outside_chunks_are_found_and_read(tmp_path: Path) -> None:
    path = tmp_path / "loose.mcap"
    channels = _loose_bag(path, ("/a", "/b"), statistics=False)
    scan = scan_file(path)
    assert not scan.chunks and scan.statistics is None
    assert [loose_message_channel(scan, offset) for _t, offset, _n in scan.loose] == [channels[k % 2] for k in range(5)]
    assert {t: i.count for t, i in bag_topics(path).items()} == {"/a": 3, "/b": 2}
    assert [(m.topic, m.msg.data) for m in read_messages(path)] == [("/a" if k % 2 == 0 else "/b", f"m{k}")
                                                                     for k in range(5)]


def _read(path: Path, on_damage: OnDamage = "skip") -> tuple[list[tuple[str, int, bytes]], ReadStats]:
    """(topic, log time, raw bytes) of every message read, and what the read reported."""
    stats = ReadStats()
    messages = read_messages(path, raw=True, on_damage=on_damage, stats=stats)
    return [(m.topic, m.log_time_ns, bytes(m.msg)) for m in messages], stats


def test_a_summary_whose_crc_fails_is_ignored_and_channels_come_from_the_data_section(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    text_bag(path)
    original, _ = _read(path)
    data = path.read_bytes()
    channel = next(start for op, start, _end in records(data) if op == OP_CHANNEL and start >= summary_start(data))
    at = data.index(b"/stereo/left/image_rect", channel)
    flip(path, at + len("/stereo/lef"), ord("t") ^ ord("\r"))  # the summary's copy reads /stereo/lef\r/image_rect
    scan = scan_file(path)
    assert scan.summary_crc_ok is False and not scan.summary_used and scan.closed
    assert scan.channels == {} and scan.statistics is None  # our writer defines channels in chunks only
    assert [d.reason for d in scan.damage] == [
        "the summary's CRC does not match: the summary is ignored, channels and counts come from the data section"]
    assert scan.damage[0].kept
    got, stats = _read(path, "raise")  # the chunks' own channel records serve: nothing lost, nothing refused
    assert got == original and {t for t, _n, _d in got} == set(TEXT_TOPICS)
    assert len(stats.damage) == 1 and "summary is ignored" in stats.damage[0] and not stats.lost
    assert set(bag_topics(path)) == set(TEXT_TOPICS)


def test_a_malformed_summary_record_is_ignored_without_a_summary_crc(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    text_bag(path)
    data = bytearray(path.read_bytes())
    statistics = next(start for op, start, _end in records(bytes(data)) if op == 0x0B)
    counts_length = statistics + 9 + 8 + 2 + 4 * 4 + 8 + 8  # the channel message count map's byte length
    data[counts_length] += 1  # no longer a whole number of (uint16, uint64) entries
    footer = next(start for op, start, _end in records(bytes(data)) if op == OP_FOOTER)
    data[footer + 25 : footer + 29] = bytes(4)  # no summary CRC: only the records' structure can be checked
    path.write_bytes(bytes(data))
    scan = scan_file(path)
    assert scan.summary_crc_ok is None and not scan.summary_used and scan.statistics is None
    assert len(scan.damage) == 1 and "malformed" in scan.damage[0].reason
    assert "the summary is ignored" in scan.damage[0].reason
    assert {t: i.count for t, i in bag_topics(path).items()} == {"/imu": 20, "/stereo/left/image_rect": 40}


def test_the_data_section_crc_reports_damage_outside_the_chunks(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    text_bag(path)
    original, _ = _read(path)
    assert scan_file(path).data_crc_ok is True
    metadata = next(start for op, start, _end in records(path.read_bytes()) if op == OP_METADATA)
    flip(path, metadata + 100, 0x01)  # inside the rosbag2 metadata record, which no reader uses
    scan = scan_file(path)
    assert scan.data_crc_ok is False and not scan.damage
    assert scan_file(path, check_data_crc=False).data_crc_ok is None
    got, stats = _read(path, "raise")
    assert got == original
    assert stats.damage == [f"a.mcap: byte {scan.data_end_offset}: the data section's CRC does not match: a record "
                            "outside the chunks (a message index, the metadata) is damaged; every chunk passed its "
                            "own CRC, so every message read is sound; nothing lost"]


@pytest.mark.parametrize(("at", "mask"), [(23, 0x01), (9, 0x01), (3, 0x80), (0, 0x08)],
                         ids=["entry offset", "channel", "record length", "opcode becomes data end"])
def test_a_damaged_message_index_is_reported_and_never_trusted(tmp_path: Path, at: int, mask: int) -> None:
    path = tmp_path / "a.mcap"
    text_bag(path)
    original, _ = _read(path)
    chunks = len(scan_file(path).chunks)
    index = next(start for op, start, _end in records(path.read_bytes()) if op == OP_MESSAGE_INDEX)
    flip(path, index + at, mask)
    assert len(scan_file(path).chunks) == chunks  # the walk goes on to every chunk after it
    got, stats = _read(path, "raise")
    assert got == original and stats.damage and not stats.lost and not stats.lost_unknown
    assert all(line.endswith("nothing lost") for line in stats.damage)
    assert any("message index" in line for line in stats.damage)


def test_messages_outside_chunks_are_dropped_when_the_data_crc_fails(tmp_path: Path) -> None:
    path = tmp_path / "loose.mcap"
    _loose_bag(path, ("/a",), data_crcs=True)
    assert [m.msg.data for m in read_messages(path)] == [f"m{k}" for k in range(5)]
    data = path.read_bytes()
    flip(path, data.index(b"m2"), ord("m") ^ ord("M"))  # nothing but the data section's CRC covers it
    got, stats = _read(path)
    assert got == [] and stats.lost == {"/a": 5}
    assert "5 message(s) outside chunks, which only the data section's CRC covers" in stats.damage[0]
