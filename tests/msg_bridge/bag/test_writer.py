"""The writer: its bags read by the independent mcap + mcap-ros2-support reader (decoded, and
its chunk and data section CRCs checked), determinism, and misuse refused."""

from __future__ import annotations

import hashlib
import zlib
from pathlib import Path

import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import DataEnd
from mcap.stream_reader import StreamReader

from msg_bridge import BagError, BagWriter, bag_topics, read_messages
from tests.msg_bridge.bag._bags import (
    SMALL_CHUNKS,
    TOPICS,
    check_content,
    data_range,
    independent_read,
    text_bag,
    write_bag,
)


@pytest.mark.parametrize(("name", "compression"), [("bag.mcap", "zstd"), ("bag_dir", "none")])
def test_every_message_is_decoded_by_the_independent_reader(tmp_path: Path, name: str, compression: str) -> None:
    path = tmp_path / name
    write_bag(path, compression=compression)
    mcap_file = path if path.suffix == ".mcap" else path / f"{name}.mcap"
    assert path.is_file() == (name.endswith(".mcap"))
    if path.is_dir():
        assert (path / "metadata.yaml").is_file()
    ours = list(read_messages(path))
    theirs = independent_read(mcap_file)
    assert len(ours) == len(theirs) == 3 * len(TOPICS)
    for mine, (topic, schema, log_time, decoded) in zip(ours, theirs, strict=True):
        assert (mine.topic, mine.msgtype, mine.log_time_ns) == (topic, TOPICS[topic], log_time)
        assert schema == TOPICS[topic].replace("/msg/", "/msg/")
        check_content(topic, decoded)
        check_content(topic, mine.msg)
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = [c.compression for c in summary.chunk_indexes]
    assert set(chunks) == ({"zstd"} if compression == "zstd" else {""})
    assert {t: i.count for t, i in bag_topics(path).items()} == dict.fromkeys(TOPICS, 3)


def test_writing_is_deterministic(tmp_path: Path) -> None:
    digests = set()
    for folder in ("first", "second"):  # same file name: the name is part of the bag's metadata
        (tmp_path / folder).mkdir()
        write_bag(tmp_path / folder / "bag.mcap", frames=2)
        digests.add(hashlib.sha256((tmp_path / folder / "bag.mcap").read_bytes()).hexdigest())
    assert len(digests) == 1


def test_writer_refuses_misuse(tmp_path: Path) -> None:
    existing = tmp_path / "exists.mcap"
    existing.write_bytes(b"")
    with pytest.raises(BagError, match="exists already"):
        BagWriter(existing)
    with pytest.raises(BagError, match="compression"):
        BagWriter(tmp_path / "x.mcap", compression="lz4")
    with pytest.raises(BagError, match="unknown message type"), BagWriter(tmp_path / "y.mcap") as bag:
        bag.add_topic("/x", "nope_msgs/msg/Nope")
    assert not (tmp_path / "y.mcap").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["exists.mcap"]  # nothing half-written left
    with pytest.raises(BagError, match="was not added"), BagWriter(tmp_path / "z") as bag:
        bag.write("/x", None, 0)
    assert not (tmp_path / "z").exists()


def test_project_bags_carry_chunk_crcs_that_the_independent_reader_checks(tmp_path: Path) -> None:
    path = tmp_path / "crc.mcap"
    write_bag(path, frames=3, chunk_size=SMALL_CHUNKS)
    with path.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        assert len(list(reader.iter_messages())) == 3 * len(TOPICS)
        summary = reader.get_summary()
        assert summary is not None
        chunks = summary.chunk_indexes
    assert len(chunks) > 3
    data = path.read_bytes()
    for chunk in chunks:
        body = data[chunk.chunk_start_offset + 9 : chunk.chunk_start_offset + chunk.chunk_length]
        crc = int.from_bytes(body[24:28], "little")
        start, end = data_range(path, chunk)
        uncompressed = zstandard.ZstdDecompressor().decompress(data[start:end], max_output_size=chunk.uncompressed_size)
        assert crc != 0 and crc == zlib.crc32(uncompressed)


def test_project_bags_carry_a_data_section_crc_that_the_independent_reader_checks(tmp_path: Path) -> None:
    """The data section's CRC covers the message indexes and the metadata record, which no chunk CRC does."""
    path = tmp_path / "crc.mcap"
    text_bag(path)
    with path.open("rb") as stream:  # validate_crcs: raises on a data section CRC that does not match
        ends = [r for r in StreamReader(stream, validate_crcs=True).records if isinstance(r, DataEnd)]
    assert len(ends) == 1 and ends[0].data_section_crc != 0
    data = path.read_bytes()
    end = data.rindex(bytes([0x0F]) + (4).to_bytes(8, "little") + ends[0].data_section_crc.to_bytes(4, "little"))
    assert ends[0].data_section_crc == zlib.crc32(data[:end])
