"""Bags for the msg_bridge.bag tests: every kind of message the project writes, written by our
writer, small text bags (one file, or split over several files), and independent looks into the
files (the mcap reader, the raw index, the top-level records)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from msg_bridge import BagWriter, bag_factory, read_messages
from msg_bridge.bag.mcap_file import scan_file
from msg_bridge.bag.metadata import to_yaml
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
SMALL_CHUNKS = 16 * 1024  # several chunks per bag


def messages(stamp: int) -> dict[str, object]:
    """One message per topic of :data:`TOPICS`, stamped ``stamp``."""
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


def write_bag(path: Path, *, frames: int = 3, compression: str = "zstd", chunk_size: int = 1 << 20) -> None:
    """A bag of ``frames`` times :func:`messages` (``/camera_info`` latched)."""
    with BagWriter(path, compression=compression, chunk_size=chunk_size) as bag:
        for topic, msgtype in TOPICS.items():
            bag.add_topic(topic, msgtype, latched=topic == "/camera_info")
        for i in range(frames):
            stamp = 1_000_000_000 * (i + 1) + 7
            for topic, msg in messages(stamp).items():
                bag.write(topic, msg, stamp)


def check_content(topic: str, msg: object) -> None:
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


def independent_read(mcap_file: Path) -> list[tuple[str, str, int, object]]:
    """(topic, type, log time, decoded message) of every message, by mcap + mcap-ros2-support."""
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        out: list[tuple[str, str, int, object]] = []
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema is not None
            out.append((channel.topic, schema.name, message.log_time, decoded))
        return out


def chunk_indexes(path: Path) -> list[object]:
    """The chunk indexes of a closed bag's summary, as the mcap reader gives them."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return list(summary.chunk_indexes)


def raw_by_key(path: Path) -> dict[tuple[str, int], bytes]:
    """(topic, log time) -> the serialised bytes of every message of a sound bag."""
    return {(m.topic, m.log_time_ns): bytes(m.msg) for m in read_messages(path, raw=True)}


def data_range(path: Path, chunk: object) -> tuple[int, int]:
    """[start, end) of a chunk's (compressed) records inside the file."""
    found = {c.offset: c for c in scan_file(path).chunks}[chunk.chunk_start_offset]  # type: ignore[attr-defined]
    return found.data_start, found.data_start + found.data_length


def index_entries(data: bytes, chunk: object) -> list[tuple[int, int]]:
    """The message index entries of a chunk, read from the file independently."""
    entries = []
    for offset in chunk.message_index_offsets.values():  # type: ignore[attr-defined]
        length = int.from_bytes(data[offset + 1 : offset + 9], "little")
        body = data[offset + 9 : offset + 9 + length]
        size = int.from_bytes(body[2:6], "little")
        entries += [(int.from_bytes(body[6 + k : 14 + k], "little"), 0) for k in range(0, size, 16)]
    return entries


TEXT_TOPICS = ("/stereo/left/image_rect", "/imu")
OP_CHANNEL, OP_MESSAGE_INDEX, OP_METADATA, OP_DATA_END, OP_FOOTER = 0x04, 0x07, 0x0C, 0x0F, 0x02


def text_bag(path: Path, *, messages: int = 60, first_time: int = 1000, chunk_size: int = 1024) -> None:
    """A small bag of ``std_msgs/String`` on :data:`TEXT_TOPICS`, in several chunks."""
    factory = bag_factory()
    with BagWriter(path, chunk_size=chunk_size) as bag:
        for topic in TEXT_TOPICS:
            bag.add_topic(topic, "std_msgs/msg/String")
        for k in range(messages):
            msg = factory.new("std_msgs/msg/String", data=f"message {k:03d} " + "x" * 30)
            bag.write(TEXT_TOPICS[k % 3 == 0], msg, first_time + k)


def split_bag(path: Path, *, parts: int = 2, per_part: int = 20) -> list[Path]:
    """A rosbag2 directory whose metadata.yaml lists ``parts`` files of :func:`text_bag`; the files."""
    path.mkdir()
    files = [path / f"{path.name}_{i}.mcap" for i in range(parts)]
    for i, file in enumerate(files):
        text_bag(file, messages=per_part, first_time=1000 * (i + 1))
    info = {
        "version": 9,
        "storage_identifier": "mcap",
        "relative_file_paths": [f.name for f in files],
        "message_count": parts * per_part,
        "files": [{"path": f.name, "message_count": per_part} for f in files],
    }
    (path / "metadata.yaml").write_text(to_yaml({"rosbag2_bagfile_information": info}))
    return files


def records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of every top-level record of an intact MCAP file, read independently."""
    out = []
    pos = 8
    while pos < len(data) - 8:
        end = pos + 9 + int.from_bytes(data[pos + 1 : pos + 9], "little")
        out.append((data[pos], pos, end))
        pos = end
    return out


def summary_start(data: bytes) -> int:
    """Where the summary of an intact MCAP file starts (just after its data end)."""
    return next(end for op, _start, end in records(data) if op == OP_DATA_END)


def flip(path: Path, at: int, mask: int) -> None:
    """XOR the byte at ``at`` of the file with ``mask``."""
    data = bytearray(path.read_bytes())
    data[at] ^= mask
    path.write_bytes(bytes(data))
