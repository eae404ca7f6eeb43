"""rosbag2 MCAP bags: our writer read by the independent mcap + mcap-ros2-support reader and back,
a bag written by mcap-ros2-support read by us, determinism, and damaged bags."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer

from msg_bridge import BagError, BagWriter, bag_factory, bag_topics, read_messages, typestore
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


def _write(path: Path, *, frames: int = 3, compression: str = "zstd") -> None:
    with BagWriter(path, compression=compression) as bag:
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
    _write(path, frames=3, compression="none")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(BagError, match=r"cut\.mcap.*readable before the damage \(/camera_info: \d"):
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
