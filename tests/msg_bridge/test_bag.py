"""rosbag2 MCAP bags: our writer read by the independent mcap + mcap-ros2-support reader and back,
a bag written by mcap-ros2-support read by us, determinism, and damaged bags."""

from __future__ import annotations

import hashlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer

from msg_bridge import BagError, BagWriter, bag_factory, bag_topics, read_messages, serialize, typestore
from msg_bridge.camera_info import camera_info_from_stereo, stereo_camera_from_camera_info
from msg_bridge.grid_map import elevation_grid_map, grid_map_to_arrays
from msg_bridge.image import array_to_compressed, array_to_image, compressed_to_rgb, image_to_rgb
from msg_bridge.imu import attitude_from_imu, imu_message
from msg_bridge.point_cloud import elevation_point_cloud, point_cloud_to_array
from msg_bridge.preview import preview_from_message, road_preview_message
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.preview import wheel_track_profiles

GRID = GridSpec()
CAMERA = StereoCamera(60.0, 60.0, 15.5, 11.5, 0.12, 32, 24)
RNG = np.random.default_rng(11)
ELEVATION = RNG.normal(0, 0.02, GRID.shape).astype(np.float32)
ELEVATION[:5] = np.nan
PIXELS = RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)

TOPICS = {
    "/image": "sensor_msgs/msg/Image",
    "/image/compressed": "sensor_msgs/msg/CompressedImage",
    "/camera_info": "sensor_msgs/msg/CameraInfo",
    "/imu": "sensor_msgs/msg/Imu",
    "/elevation": "grid_map_msgs/msg/GridMap",
    "/preview": "roadbev_msgs/msg/RoadPreview",
    "/points": "sensor_msgs/msg/PointCloud2",
}


def _messages(stamp: int) -> dict[str, object]:
    f = bag_factory()
    profiles = wheel_track_profiles(ELEVATION, None, GRID, vehicle_speed=5.0)
    return {
        "/image": array_to_image(PIXELS, f, stamp_ns=stamp, frame_id="cam"),
        "/image/compressed": array_to_compressed(PIXELS, f, stamp_ns=stamp, fmt="png"),
        "/camera_info": camera_info_from_stereo(CAMERA, f, right=True, stamp_ns=stamp),
        "/imu": imu_message(f, stamp_ns=stamp, orientation_xyzw=(0.0, 0.0998334, 0.0, 0.9950042)),
        "/elevation": elevation_grid_map(ELEVATION, np.abs(ELEVATION), GRID, f, stamp_ns=stamp),
        "/preview": road_preview_message(profiles, f, stamp_ns=stamp),
        "/points": elevation_point_cloud(ELEVATION, None, GRID, f, stamp_ns=stamp),
    }


def _write(path: Path, *, frames: int = 3, compression: str = "zstd", chunk_size: int = 1 << 20) -> None:
    with BagWriter(path, compression=compression, chunk_size=chunk_size) as bag:
        for topic, msgtype in TOPICS.items():
            bag.add_topic(topic, msgtype, latched=topic == "/camera_info")
        for i in range(frames):
            stamp = 1_000_000_000 * (i + 1) + 7
            for topic, msg in _messages(stamp).items():
                bag.write(topic, msg, stamp)


def _check_content(topic: str, msg: object) -> None:
    """Decode one message with the converters and compare with what was written."""
    if topic == "/image":
        np.testing.assert_array_equal(image_to_rgb(msg), PIXELS)
    elif topic == "/image/compressed":
        np.testing.assert_array_equal(compressed_to_rgb(msg), PIXELS)
    elif topic == "/camera_info":
        right = msg
        left = camera_info_from_stereo(CAMERA, bag_factory())
        assert stereo_camera_from_camera_info(left, right) == CAMERA
    elif topic == "/imu":
        assert attitude_from_imu(msg).pitch == pytest.approx(0.2, abs=1e-6)
    elif topic == "/elevation":
        decoded = grid_map_to_arrays(msg)
        assert decoded.grid == GRID
        np.testing.assert_array_equal(decoded.layers["elevation"], ELEVATION)
    elif topic == "/preview":
        assert preview_from_message(msg).profiles.n_samples == GRID.n_rows
    elif topic == "/points":
        assert point_cloud_to_array(msg)[1].shape == (int(np.isfinite(ELEVATION).sum()), 4)


def _independent_read(mcap_file: Path) -> list[tuple[str, str, int, object]]:
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        out: list[tuple[str, str, int, object]] = []
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema is not None
            out.append((channel.topic, schema.name, message.log_time, decoded))
        return out


@pytest.mark.parametrize(("name", "compression"), [("bag.mcap", "zstd"), ("bag_dir", "none")])
def test_every_message_is_decoded_by_the_independent_reader(tmp_path: Path, name: str, compression: str) -> None:
    path = tmp_path / name
    _write(path, compression=compression)
    mcap_file = path if path.suffix == ".mcap" else path / f"{name}.mcap"
    assert path.is_file() == (name.endswith(".mcap"))
    if path.is_dir():
        assert (path / "metadata.yaml").is_file()
    ours = list(read_messages(path))
    theirs = _independent_read(mcap_file)
    assert len(ours) == len(theirs) == 3 * len(TOPICS)
    for mine, (topic, schema, log_time, decoded) in zip(ours, theirs, strict=True):
        assert (mine.topic, mine.msgtype, mine.log_time_ns) == (topic, TOPICS[topic], log_time)
        assert schema == TOPICS[topic].replace("/msg/", "/msg/")
        _check_content(topic, decoded)
        _check_content(topic, mine.msg)
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = [c.compression for c in summary.chunk_indexes]
    assert set(chunks) == ({"zstd"} if compression == "zstd" else {""})
    assert {t: i.count for t, i in bag_topics(path).items()} == dict.fromkeys(TOPICS, 3)


def test_raw_reading_gives_the_serialised_bytes(tmp_path: Path) -> None:
    _write(tmp_path / "raw.mcap", frames=1)
    raw = {m.topic: m.msg for m in read_messages(tmp_path / "raw.mcap", ["/imu", "/preview"], raw=True)}
    assert set(raw) == {"/imu", "/preview"}
    store = typestore()
    imu = store.deserialize_cdr(raw["/imu"], "sensor_msgs/msg/Imu")
    assert imu.header.stamp.sec == 1


def test_writing_is_deterministic(tmp_path: Path) -> None:
    digests = set()
    for folder in ("first", "second"):  # same file name: the name is part of the bag's metadata
        (tmp_path / folder).mkdir()
        _write(tmp_path / folder / "bag.mcap", frames=2)
        digests.add(hashlib.sha256((tmp_path / folder / "bag.mcap").read_bytes()).hexdigest())
    assert len(digests) == 1


def test_we_read_a_bag_written_by_mcap_ros2(tmp_path: Path) -> None:
    store = typestore()
    path = tmp_path / "foreign.mcap"
    with path.open("wb") as stream:
        writer = McapRos2Writer(stream)
        gm_schema = writer.register_msgdef(
            "grid_map_msgs/msg/GridMap", store.generate_msgdef("grid_map_msgs/msg/GridMap", ros_version=2)[0]
        )
        img_schema = writer.register_msgdef(
            "sensor_msgs/msg/Image", store.generate_msgdef("sensor_msgs/msg/Image", ros_version=2)[0]
        )
        column_major = ELEVATION.flatten(order="F")
        grid_map = {
            "header": {"stamp": {"sec": 3, "nanosec": 5}, "frame_id": "roadbev_road"},
            "info": {
                "resolution": 0.03,
                "length_x": 4.92,
                "length_y": 1.92,
                "pose": {"position": {"x": 4.62, "y": 0.04, "z": 0.0}, "orientation": {"w": 1.0}},
            },
            "layers": ["elevation"],
            "basic_layers": ["elevation"],
            "data": [
                {
                    "layout": {
                        "dim": [
                            {"label": "column_index", "size": 64, "stride": 164 * 64},
                            {"label": "row_index", "size": 164, "stride": 164},
                        ],
                        "data_offset": 0,
                    },
                    "data": column_major.tolist(),
                }
            ],
            "outer_start_index": 0,
            "inner_start_index": 0,
        }
        image = {
            "header": {"stamp": {"sec": 3, "nanosec": 5}, "frame_id": "cam"},
            "height": 24,
            "width": 32,
            "encoding": "rgb8",
            "is_bigendian": 0,
            "step": 96,
            "data": PIXELS.tobytes(),
        }
        for i in range(2):
            writer.write_message("/gt", gm_schema, grid_map, log_time=10 + i)
            writer.write_message("/image", img_schema, image, log_time=10 + i)
        writer.finish()
    assert {t: (i.msgtype, i.count) for t, i in bag_topics(path).items()} == {
        "/gt": ("grid_map_msgs/msg/GridMap", 2),
        "/image": ("sensor_msgs/msg/Image", 2),
    }
    messages = list(read_messages(path))
    assert [m.topic for m in messages] == ["/gt", "/image", "/gt", "/image"]
    decoded = grid_map_to_arrays(messages[0].msg)
    assert decoded.grid == GRID and decoded.stamp_ns == 3_000_000_005
    np.testing.assert_array_equal(decoded.layers["elevation"], ELEVATION)
    np.testing.assert_array_equal(image_to_rgb(messages[1].msg), PIXELS)


def test_truncated_bag_names_the_file_and_what_was_readable(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    _write(path, frames=3, compression="none", chunk_size=64 * 1024)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(BagError, match=r"cut\.mcap: chunk \d+ at byte \d+: the file ends inside this chunk.*"
                       r"readable before the damage \(/camera_info: \d"):
        list(read_messages(path))


def test_damaged_chunk_is_reported_with_the_messages_read_before(tmp_path: Path) -> None:
    path = tmp_path / "flipped.mcap"
    _write(path, frames=3, compression="zstd")
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


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all", b"\x89MCAP0\r\n" + bytes(100)])
def test_garbage_files_raise_bag_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "garbage.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError, match=r"garbage\.mcap"):
        bag_topics(path)


def test_bad_paths_raise_bag_error(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no such bag"):
        list(read_messages(tmp_path / "missing.mcap"))
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagError, match=r"without metadata\.yaml"):
        bag_topics(tmp_path / "empty_dir")
    (tmp_path / "bag.db3").write_bytes(b"")
    with pytest.raises(BagError, match=r"not an \.mcap file"):
        bag_topics(tmp_path / "bag.db3")


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


# ------------------------------------------------------------------------------------------------
# integrity: CRCs, damaged chunks, truncation, unfinished bags, recovery
# ------------------------------------------------------------------------------------------------
SMALL_CHUNKS = 16 * 1024  # several chunks per bag


def _chunks(path: Path) -> list[object]:
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return list(summary.chunk_indexes)


def _raw_by_key(path: Path) -> dict[tuple[str, int], bytes]:
    return {(m.topic, m.log_time_ns): bytes(m.msg) for m in read_messages(path, raw=True)}


def _data_range(path: Path, chunk: object) -> tuple[int, int]:
    """[start, end) of a chunk's (compressed) records inside the file."""
    from msg_bridge.mcap_file import scan_file

    found = {c.offset: c for c in scan_file(path).chunks}[chunk.chunk_start_offset]  # type: ignore[attr-defined]
    return found.data_start, found.data_start + found.data_length


def test_project_bags_carry_chunk_crcs_that_the_independent_reader_checks(tmp_path: Path) -> None:
    import zlib

    from mcap.reader import make_reader as reader_with_crcs

    path = tmp_path / "crc.mcap"
    _write(path, frames=3, chunk_size=SMALL_CHUNKS)
    with path.open("rb") as stream:
        reader = reader_with_crcs(stream, validate_crcs=True)
        assert len(list(reader.iter_messages())) == 3 * len(TOPICS)
        summary = reader.get_summary()
        assert summary is not None
        chunks = summary.chunk_indexes
    assert len(chunks) > 3
    import zstandard

    data = path.read_bytes()
    for chunk in chunks:
        body = data[chunk.chunk_start_offset + 9 : chunk.chunk_start_offset + chunk.chunk_length]
        crc = int.from_bytes(body[24:28], "little")
        start, end = _data_range(path, chunk)
        uncompressed = zstandard.ZstdDecompressor().decompress(data[start:end], max_output_size=chunk.uncompressed_size)
        assert crc != 0 and crc == zlib.crc32(uncompressed)


def test_a_damaged_chunk_is_a_typed_error_naming_it_or_is_skipped_and_counted(tmp_path: Path) -> None:
    from msg_bridge import DamagedBagError, ReadStats

    path = tmp_path / "bag.mcap"
    _write(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = _raw_by_key(path)
    chunks = _chunks(path)
    victim = chunks[2]
    start, end = _data_range(path, victim)
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
    from msg_bridge import DamagedBagError, ReadStats

    path = tmp_path / "bag.mcap"
    _write(path, frames=2, chunk_size=SMALL_CHUNKS)
    original_bytes = path.read_bytes()
    original = _raw_by_key(path)
    ranges = [_data_range(path, c) for c in _chunks(path)]
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
    from msg_bridge import DamagedBagError, ReadStats, bag_info

    path = tmp_path / "bag.mcap"
    _write(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = _raw_by_key(path)
    chunks = _chunks(path)
    data = path.read_bytes()
    cut = int(len(data) * fraction)
    path.write_bytes(data[:cut])
    whole = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]  # type: ignore[attr-defined]
    with pytest.raises(DamagedBagError, match=r"bag\.mcap.*truncated"):
        list(read_messages(path))
    stats = ReadStats()
    got = list(read_messages(path, raw=True, on_damage="skip", stats=stats))
    expected = sum(sum(1 for _ in _index_entries(data, c)) for c in whole)
    assert len(got) == expected
    for m in got:
        assert bytes(m.msg) == original[(m.topic, m.log_time_ns)]
    assert stats.lost_unknown and stats.unfinished and "breaks off" in stats.summary()
    info = bag_info(path)
    assert not info.closed and sum(i.count for i in info.topics.values()) == expected


def _index_entries(data: bytes, chunk: object) -> list[tuple[int, int]]:
    """The message index entries of a chunk, read from the file independently."""
    entries = []
    for offset in chunk.message_index_offsets.values():  # type: ignore[attr-defined]
        length = int.from_bytes(data[offset + 1 : offset + 9], "little")
        body = data[offset + 9 : offset + 9 + length]
        size = int.from_bytes(body[2:6], "little")
        entries += [(int.from_bytes(body[6 + k : 14 + k], "little"), 0) for k in range(0, size, 16)]
    return entries


def test_an_unfinished_bag_is_readable_and_recovers_to_a_complete_indexed_copy(tmp_path: Path) -> None:
    """The state a killed writer leaves: finished chunks in the file, no summary, the marker."""
    from msg_bridge import ReadStats, bag_info, marker_path, recover_bag

    path = tmp_path / "live.mcap"
    writer = BagWriter(path, chunk_size=SMALL_CHUNKS)
    writer.open()
    for topic, msgtype in TOPICS.items():
        writer.add_topic(topic, msgtype, latched=topic == "/camera_info")
    for i in range(3):
        for topic, msg in _messages(1_000_000_000 * (i + 1)).items():
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
    theirs = _independent_read(out)
    assert len(theirs) == 3 * len(TOPICS)
    for mine, (topic, _schema, log_time, decoded) in zip(live, theirs, strict=True):
        assert (mine.topic, mine.log_time_ns) == (topic, log_time)
        _check_content(topic, decoded)
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as reader:  # QoS and types survive the copy
        assert {c.topic: c.msgcount for c in reader.connections} == dict.fromkeys(TOPICS, 3)
    writer.close()
    assert not marker_path(path).exists() and bag_info(path).closed


def test_recovering_a_damaged_bag_keeps_every_sound_chunk(tmp_path: Path) -> None:
    from msg_bridge import bag_info, recover_bag

    path = tmp_path / "bag.mcap"
    _write(path, frames=3, chunk_size=SMALL_CHUNKS)
    original = _raw_by_key(path)
    start, _end = _data_range(path, _chunks(path)[1])
    data = bytearray(path.read_bytes())
    data[start + 10] ^= 0xFF
    path.write_bytes(bytes(data))
    info = bag_info(path)
    assert info.closed and len(info.damage) == 1 and sum(info.lost.values()) > 0
    out = tmp_path / "copy"
    stats = recover_bag(path, out, compression="none")
    copy = _raw_by_key(out)
    assert len(copy) == len(original) - sum(info.lost.values()) == sum(stats.read.values())
    assert all(original[k] == v for k, v in copy.items())
    assert (out / "metadata.yaml").is_file() and bag_info(out).closed
    with pytest.raises(BagError, match="exists already"):
        recover_bag(path, out)


def test_a_chunk_without_crc_is_checked_against_its_index_and_reported(tmp_path: Path) -> None:
    """rosbags' writer stores CRC 0: such chunks are counted as unverifiable."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from msg_bridge import ReadStats, bag_info

    path = tmp_path / "old"
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        for i in range(5):
            msg = imu_message(bag_factory(), stamp_ns=i, orientation_xyzw=(0.0, 0.0, 0.0, 1.0))
            writer.write(conn, i, serialize(msg))
    stats = ReadStats()
    assert len(list(read_messages(path, on_damage="skip", stats=stats))) == 5
    assert stats.unverified_chunks == 1 and "without CRC" in stats.summary()
    assert bag_info(path).chunks_without_crc == 1


@pytest.mark.parametrize("content, reason", [
    (b"rosbag2_bagfile_information:\n  version: \xff\xfe\n", "not UTF-8 text"),
    (b"rosbag2_bagfile_information: [unclosed\n", "not a rosbag2 metadata file"),
])
def test_a_bad_metadata_file_is_a_one_line_bag_error(tmp_path: Path, content: bytes, reason: str) -> None:
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "metadata.yaml").write_bytes(content)
    with pytest.raises(BagError, match=reason) as exc:
        bag_topics(folder)
    assert "\n" not in str(exc.value)
