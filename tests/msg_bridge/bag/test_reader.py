"""The reader: raw bytes, a bag written by mcap-ros2-support, one by rosbags' writer (chunks
without CRC), and a split bag with a file missing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap_ros2.writer import Writer as McapRos2Writer
from rosbags.rosbag2 import StoragePlugin, Writer

from msg_bridge import (
    DamagedBagError,
    ReadStats,
    bag_factory,
    bag_info,
    bag_topics,
    read_messages,
    serialize,
    typestore,
)
from msg_bridge.grid_map import grid_map_to_arrays
from msg_bridge.image import image_to_rgb
from msg_bridge.imu import imu_message
from tests.msg_bridge.bag._bags import (
    ELEVATION,
    GRID,
    PIXELS,
    split_bag,
    write_bag,
)


def test_raw_reading_gives_the_serialised_bytes(tmp_path: Path) -> None:
    write_bag(tmp_path / "raw.mcap", frames=1)
    raw = {m.topic: m.msg for m in read_messages(tmp_path / "raw.mcap", ["/imu", "/preview"], raw=True)}
    assert set(raw) == {"/imu", "/preview"}
    store = typestore()
    imu = store.deserialize_cdr(raw["/imu"], "sensor_msgs/msg/Imu")
    assert imu.header.stamp.sec == 1


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


def test_a_chunk_without_crc_is_checked_against_its_index_and_reported(tmp_path: Path) -> None:
    """rosbags' writer stores CRC 0: such chunks are counted as unverifiable."""
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


def test_a_split_bag_with_a_file_missing_is_read_from_the_files_that_are_there(tmp_path: Path) -> None:
    path = tmp_path / "split"
    first, second = split_bag(path)
    whole = [(m.topic, m.log_time_ns, bytes(m.msg)) for m in read_messages(path, raw=True)]
    alone = [(m.topic, m.log_time_ns, bytes(m.msg)) for m in read_messages(first, raw=True)]
    assert len(whole) == 40 and whole[:20] == alone
    second.unlink()
    line = "split_1.mcap: listed in metadata.yaml but missing; its 20 message(s) are lost"
    with pytest.raises(DamagedBagError, match=r"split_1\.mcap: listed in metadata\.yaml but missing") as refused:
        list(read_messages(path))
    assert refused.value.damage == [line]
    stats = ReadStats()
    got = [(m.topic, m.log_time_ns, bytes(m.msg)) for m in read_messages(path, raw=True, on_damage="skip",
                                                                           stats=stats)]
    assert got == alone and stats.damage == [line] and not stats.complete
    assert sum(i.count for i in bag_topics(path).values()) == 20
