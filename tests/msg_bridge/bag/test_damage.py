"""Damaged and truncated bags: a typed error naming the file and the chunk, or the damage skipped
and counted per topic; no damaged byte ever reaches a message. The accounting: one line per
damaged part, losses per topic, the summary of a read."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from msg_bridge import BagError, DamagedBagError, bag_info, read_messages
from msg_bridge.bag.damage import ReadStats, count_damage, count_undefined_channel, describe_damage, lost_file_lines
from msg_bridge.bag.files import Bag
from msg_bridge.bag.mcap_file import Channel, Damage
from tests.msg_bridge.bag._bags import (
    SMALL_CHUNKS,
    chunk_indexes,
    data_range,
    index_entries,
    raw_by_key,
    write_bag,
)


def test_truncated_bag_names_the_file_and_what_was_readable(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    write_bag(path, frames=3, compression="none", chunk_size=64 * 1024)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(BagError, match=r"cut\.mcap: chunk \d+ at byte \d+: the file ends inside this chunk.*"
                       r"readable before the damage \(/camera_info: \d"):
        list(read_messages(path))


def test_damaged_chunk_is_reported_with_the_messages_read_before(tmp_path: Path) -> None:
    path = tmp_path / "flipped.mcap"
    write_bag(path, frames=3, compression="zstd")
    data = bytearray(path.read_bytes())
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    last = summary.chunk_indexes[-1]
    middle = last.chunk_start_offset + last.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"flipped\.mcap") as info:
        list(read_messages(path))
    assert "message" in str(info.value)


def test_a_damaged_chunk_is_a_typed_error_naming_it_or_is_skipped_and_counted(tmp_path: Path) -> None:
    path = tmp_path / "bag.mcap"
    write_bag(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = raw_by_key(path)
    chunks = chunk_indexes(path)
    victim = chunks[2]
    start, end = data_range(path, victim)
    data = bytearray(path.read_bytes())
    data[(start + end) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    with pytest.raises(DamagedBagError, match=r"bag\.mcap: chunk 2 at byte \d+: .*(CRC|decompress)"):
        list(read_messages(path))
    stats = ReadStats()
    got = list(read_messages(path, raw=True, on_damage="skip", stats=stats))
    assert stats.lost and len(got) == len(original) - sum(stats.lost.values())
    for m in got:  # every message delivered is the original, byte for byte
        assert bytes(m.msg) == original[(m.topic, m.log_time_ns)]
    assert len(stats.damage) == 1 and "chunk 2" in stats.damage[0] and "lost" in stats.summary()
    assert not stats.complete


def test_fuzz_100_single_byte_flips_in_chunk_data_are_each_detected_or_harmless(tmp_path: Path) -> None:
    """A flipped byte inside a chunk is caught (typed error, counted skip) or changes nothing:
    no flip ever reaches a decoded message."""
    path = tmp_path / "bag.mcap"
    write_bag(path, frames=2, chunk_size=SMALL_CHUNKS)
    original_bytes = path.read_bytes()
    original = raw_by_key(path)
    ranges = [data_range(path, c) for c in chunk_indexes(path)]
    rng = np.random.default_rng(2026)
    victim = tmp_path / "flipped.mcap"
    outcomes: Counter[str] = Counter()
    for _ in range(100):
        start, end = ranges[int(rng.integers(len(ranges)))]
        at = int(rng.integers(start, end))
        data = bytearray(original_bytes)
        data[at] ^= 1 << int(rng.integers(8))
        victim.write_bytes(bytes(data))
        stats = ReadStats()
        got = list(read_messages(victim, raw=True, on_damage="skip", stats=stats))
        for m in got:
            assert bytes(m.msg) == original[(m.topic, m.log_time_ns)], f"flip at {at} reached a message"
        if stats.damage:
            assert sum(stats.lost.values()) > 0 and len(got) < len(original)
            with pytest.raises(DamagedBagError, match=r"chunk \d+ at byte \d+"):
                list(read_messages(victim, raw=True))
            outcomes["detected"] += 1
        else:
            assert len(got) == len(original)  # provably harmless: the messages equal the original
            outcomes["harmless"] += 1
    assert sum(outcomes.values()) == 100 and outcomes["detected"] > 90


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.55, 0.8, 0.97])
def test_a_truncated_bag_gives_its_complete_chunks(tmp_path: Path, fraction: float) -> None:
    path = tmp_path / "bag.mcap"
    write_bag(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = raw_by_key(path)
    chunks = chunk_indexes(path)
    data = path.read_bytes()
    cut = int(len(data) * fraction)
    path.write_bytes(data[:cut])
    whole = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]  # type: ignore[attr-defined]
    with pytest.raises(DamagedBagError, match=r"bag\.mcap.*truncated"):
        list(read_messages(path))
    stats = ReadStats()
    got = list(read_messages(path, raw=True, on_damage="skip", stats=stats))
    expected = sum(sum(1 for _ in index_entries(data, c)) for c in whole)
    assert len(got) == expected
    for m in got:
        assert bytes(m.msg) == original[(m.topic, m.log_time_ns)]
    assert stats.lost_unknown and stats.unfinished and "breaks off" in stats.summary()
    info = bag_info(path)
    assert not info.closed and sum(i.count for i in info.topics.values()) == expected


def _bag_with_imu(file: Path) -> Bag:
    return Bag(file.parent, [], {}, {(file, 1): Channel(1, 1, "/imu", "cdr", {})}, False)


def test_a_damaged_part_is_one_line_with_its_loss_per_topic(tmp_path: Path) -> None:
    file = tmp_path / "a.mcap"
    bag = _bag_with_imu(file)
    line, lost = describe_damage(bag, Damage(file, 100, 2, "CRC mismatch", {1: 4, 7: 1}))
    assert line == "a.mcap: chunk 2 at byte 100: CRC mismatch; 5 message(s) lost (/imu: 4, channel 7: 1)"
    assert lost == {"/imu": 4, "channel 7": 1}
    kept, _ = describe_damage(bag, Damage(file, 100, 2, "index disagrees", {1: 4}, kept=True))
    assert kept.endswith("; nothing lost")
    cut, _ = describe_damage(bag, Damage(file, 900, None, "the file ends inside a record", lost_unknown=True))
    assert cut == "a.mcap: byte 900: the file ends inside a record; what it held is lost"


def test_counted_damage_adds_the_wanted_topics_once(tmp_path: Path) -> None:
    file = tmp_path / "a.mcap"
    bag = _bag_with_imu(file)
    stats = ReadStats()
    damage = Damage(file, 100, 2, "CRC mismatch", {1: 4}, lost_unknown=True)
    line = count_damage(bag, damage, stats, {"/other"})
    assert stats.lost == {} and stats.lost_unknown and stats.damage == [line]
    count_damage(bag, damage, stats, None)
    assert stats.lost == {"/imu": 4} and stats.damage == [line]
    count_undefined_channel(stats, file, 9)
    count_undefined_channel(stats, file, 9)
    assert stats.lost["channel 9"] == 2
    assert stats.damage[1:] == ["a.mcap: messages on channel 9, whose definition is lost"]


def test_a_lost_file_of_a_split_bag_is_one_line(tmp_path: Path) -> None:
    bag = _bag_with_imu(tmp_path / "a.mcap")
    assert lost_file_lines(bag) == []
    bag.lost_files[tmp_path / "b.mcap"] = "listed in metadata.yaml but missing; its 7 message(s) are lost"
    assert lost_file_lines(bag) == ["b.mcap: listed in metadata.yaml but missing; its 7 message(s) are lost"]


def test_read_stats_summary() -> None:
    stats = ReadStats()
    stats.read.update({"/imu": 3})
    assert stats.complete and stats.summary() == "3 message(s) read, nothing lost"
    stats.unfinished = True
    assert stats.complete and stats.summary() == "3 message(s) read, the bag was not closed cleanly"
    stats.lost.update({"/imu": 2})
    stats.damage += [f"part {k}" for k in range(5)]
    assert not stats.complete
    assert stats.summary() == ("3 message(s) read, 2 lost (/imu: 2), the bag was not closed cleanly "
                               "[part 0; part 1; part 2; and 2 more]")
