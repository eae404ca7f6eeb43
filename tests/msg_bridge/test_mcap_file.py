"""The MCAP record reader: resynchronising after a damaged chunk header, the summary's index of
what was lost, and files that are not MCAP."""

from __future__ import annotations

from pathlib import Path

import pytest

from msg_bridge import BagWriter, ReadStats, bag_factory, read_messages
from msg_bridge.mcap_file import McapFormatError, load_chunk, scan_file

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
