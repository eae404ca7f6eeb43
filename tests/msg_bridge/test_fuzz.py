"""Property-based tests: random and truncated messages give a MessageError or a correct result;
byte flips in a bag's indexes, summary and metadata are each reported.

Every converter is fed messages whose fields are drawn at random (sizes, encodings, NaN and
infinite floats, wrong types) and valid messages cut short; any exception other than
:class:`msg_bridge.MessageError` fails the test. Examples are bounded to keep the suite fast.
A small bag gets single-byte flips (seeded) where no chunk CRC looks: its message indexes, chunk
indexes, summary, footer and rosbag2 metadata record; any exception other than
:class:`msg_bridge.BagError` fails the test.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msg_bridge import MessageError, bag_factory
from msg_bridge.bag import BagError, OnDamage, ReadStats, bag_info, deserialize, read_messages, recover_bag, serialize
from msg_bridge.camera_info import camera_info_from_stereo, stereo_camera_from_camera_info
from msg_bridge.grid_map import elevation_grid_map, grid_map_to_arrays
from msg_bridge.image import ENCODINGS, array_to_compressed, compressed_to_rgb, image_to_array, image_to_rgb
from msg_bridge.imu import attitude_from_imu
from msg_bridge.point_cloud import elevation_point_cloud, point_cloud_to_array
from msg_bridge.preview import preview_from_message, road_preview_message
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.preview import wheel_track_profiles
from tests.msg_bridge.bag._bags import OP_DATA_END, OP_MESSAGE_INDEX, OP_METADATA, records, text_bag

FACTORY = bag_factory()
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
CAMERA = StereoCamera(50.0, 50.0, 9.5, 7.5, 0.0, 20, 16)
SMALL_GRID = GridSpec(x_min=2.0, x_max=2.3, y_min=-0.12, y_max=0.12, resolution=0.03)

# no subnormals: the suite's conftest makes torch flush denormals, which hypothesis refuses
floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=False),
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300]),
)
junk = st.one_of(st.none(), st.text(max_size=3), floats, st.lists(st.integers(0, 255), max_size=4))
byte_arrays = st.binary(max_size=400).map(lambda b: np.frombuffer(b, np.uint8).copy())


def _converts_or_message_error(convert: Callable[[Any], Any], msg: Any) -> Any:
    try:
        return convert(msg)
    except MessageError:
        return None


@FUZZ
@given(
    height=st.integers(0, 9),
    width=st.integers(0, 9),
    encoding=st.sampled_from([*ENCODINGS, "yuv422", "", "RGB8"]),
    step=st.integers(0, 80),
    bigendian=st.integers(0, 3),
    data=byte_arrays,
)
def test_random_images(height: int, width: int, encoding: str, step: int, bigendian: int, data: np.ndarray) -> None:
    msg = FACTORY.new(
        "sensor_msgs/msg/Image",
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=bigendian,
        step=step,
        data=data,
    )
    out = _converts_or_message_error(image_to_array, msg)
    if out is not None:
        spec = ENCODINGS[encoding]
        assert out.shape[:2] == (height, width) and out.dtype == spec.dtype
        # the first pixel row is the first bytes of the buffer, read with the message's byte order
        order: Literal[">", "<"] = ">" if bigendian else "<"
        first = data[: width * spec.bytes_per_pixel].view(spec.dtype.newbyteorder(order))
        np.testing.assert_array_equal(out[0].reshape(-1), first)
    _converts_or_message_error(image_to_rgb, msg)


@FUZZ
@given(field=st.sampled_from(["height", "width", "encoding", "step", "is_bigendian", "data"]), value=junk)
def test_images_with_wrongly_typed_fields(field: str, value: object) -> None:
    msg = FACTORY.new("sensor_msgs/msg/Image", height=2, width=2, encoding="mono8", step=2, data=np.zeros(4, np.uint8))
    setattr(msg, field, value)
    _converts_or_message_error(image_to_rgb, msg)


@FUZZ
@given(
    fmt=st.sampled_from(["jpeg", "png"]),
    keep=st.floats(0.0, 1.0, allow_subnormal=False),
    flip=st.integers(0, 10_000),
)
def test_truncated_and_damaged_compressed_images(fmt: str, keep: float, flip: int) -> None:
    pixels = np.random.default_rng(0).integers(0, 256, (12, 10, 3), dtype=np.uint8)
    msg = array_to_compressed(pixels, FACTORY, fmt=fmt)
    data = np.array(msg.data[: int(len(msg.data) * keep)])
    if data.size:
        data[flip % data.size] ^= 0x5A
    msg.data = data
    out = _converts_or_message_error(compressed_to_rgb, msg)
    if out is not None:
        assert out.dtype == np.uint8 and out.shape in ((12, 10, 3), (12, 10))


@FUZZ
@given(
    p_left=st.lists(floats, min_size=12, max_size=12),
    p_right=st.lists(floats, min_size=0, max_size=13),
    size=st.tuples(st.integers(0, 3000), st.integers(0, 3000)),
)
def test_random_camera_infos(p_left: list[float], p_right: list[float], size: tuple[int, int]) -> None:
    left = FACTORY.new("sensor_msgs/msg/CameraInfo", width=size[0], height=size[1], p=np.array(p_left))
    right = FACTORY.new("sensor_msgs/msg/CameraInfo", width=size[0], height=size[1], p=np.array(p_right))
    camera = _converts_or_message_error(lambda m: stereo_camera_from_camera_info(m, right), left)
    if camera is not None:
        assert camera.fx == p_left[0] and camera.baseline == pytest.approx(-p_right[3] / p_right[0])
        assert camera.baseline > 0


@FUZZ
@given(q=st.tuples(floats, floats, floats, floats))
def test_random_imu_orientations(q: tuple[float, float, float, float]) -> None:
    msg = FACTORY.new("sensor_msgs/msg/Imu")
    msg.orientation = FACTORY.new("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3])
    attitude = _converts_or_message_error(attitude_from_imu, msg)
    if attitude is not None:
        assert all(math.isfinite(v) for v in q)
        assert abs(math.sqrt(sum(v * v for v in q)) - 1.0) <= 1e-3
        assert abs(attitude.pitch) < math.pi / 2


@FUZZ
@given(
    resolution=st.one_of(floats, st.just(0.03)),
    lengths=st.tuples(st.sampled_from([0.3, 0.24, 0.0, -0.3, 0.31]), st.sampled_from([0.24, 0.3, 0.25])),
    sizes=st.lists(st.integers(0, 120), min_size=0, max_size=3),
    labels=st.sampled_from([("column_index", "row_index"), ("row_index", "column_index"), ("a", "b")]),
    n_names=st.integers(0, 3),
    start=st.tuples(st.integers(0, 20), st.integers(0, 20)),
)
def test_random_grid_maps(
    resolution: float,
    lengths: tuple[float, float],
    sizes: list[int],
    labels: tuple[str, str],
    n_names: int,
    start: tuple[int, int],
) -> None:
    msg = elevation_grid_map(np.zeros(SMALL_GRID.shape), None, SMALL_GRID, FACTORY, stamp_ns=0)
    msg.info.resolution = resolution
    msg.info.length_x, msg.info.length_y = lengths
    layer = msg.data[0]
    msg.data = [
        FACTORY.new("std_msgs/msg/Float32MultiArray", layout=layer.layout, data=np.zeros(n, np.float32))
        for n in sizes
    ]
    for d in msg.data:
        d.layout.dim[0].label, d.layout.dim[1].label = labels
    msg.layers = [f"layer{i}" for i in range(n_names)]
    msg.outer_start_index, msg.inner_start_index = start
    decoded = _converts_or_message_error(grid_map_to_arrays, msg)
    if decoded is not None:
        assert all(a.shape == decoded.grid.shape for a in decoded.layers.values())


@FUZZ
@given(keep=st.integers(0, 2000))
def test_truncated_cdr_of_every_message_family(keep: int) -> None:
    """Cut-short serialised messages fail to decode with a MessageError, or decode completely."""
    grid_map = elevation_grid_map(np.ones(SMALL_GRID.shape), None, SMALL_GRID, FACTORY, stamp_ns=5)
    profiles = wheel_track_profiles(np.zeros(SMALL_GRID.shape), None, SMALL_GRID, track_offsets_m=[0.0])
    messages: list[tuple[Any, Callable[[Any], Any]]] = [
        (grid_map, grid_map_to_arrays),
        (road_preview_message(profiles, FACTORY, stamp_ns=1), preview_from_message),
        (camera_info_from_stereo(CAMERA, FACTORY), stereo_camera_from_camera_info),
        (elevation_point_cloud(np.ones(SMALL_GRID.shape), None, SMALL_GRID, FACTORY, stamp_ns=0), point_cloud_to_array),
    ]
    for msg, convert in messages:
        data = serialize(msg)
        cut = data[: min(keep, len(data))]
        decoded = _converts_or_message_error(functools.partial(deserialize, msgtype=msg.__msgtype__), cut)
        if decoded is not None:
            _converts_or_message_error(convert, decoded)


@FUZZ
@given(
    n=st.integers(0, 6),
    m=st.integers(0, 6),
    spacing=floats,
    speed=floats,
    arrival=st.integers(0, 7),
)
def test_random_previews(n: int, m: int, spacing: float, speed: float, arrival: int) -> None:
    track = FACTORY.new(
        "roadbev_msgs/msg/WheelTrackProfile",
        name="left",
        elevation=np.zeros(n, np.float32),
        uncertainty=np.zeros(m, np.float32),
    )
    msg = FACTORY.new(
        "roadbev_msgs/msg/RoadPreview",
        spacing=spacing,
        vehicle_speed=speed,
        time_of_arrival=np.zeros(arrival, np.float32),
        tracks=[track],
    )
    decoded = _converts_or_message_error(preview_from_message, msg)
    if decoded is not None:
        assert n == m and decoded.profiles.spacing == spacing > 0
        assert arrival in (0, n)


@FUZZ
@given(
    width=st.integers(0, 5),
    height=st.integers(0, 3),
    point_step=st.integers(0, 24),
    row_step=st.integers(0, 100),
    offsets=st.lists(st.integers(0, 24), max_size=4),
    datatype=st.sampled_from([7, 8, 2]),
    data=byte_arrays,
)
def test_random_point_clouds(
    width: int, height: int, point_step: int, row_step: int, offsets: list[int], datatype: int, data: np.ndarray
) -> None:
    fields = [
        FACTORY.new("sensor_msgs/msg/PointField", name=f"f{i}", offset=o, datatype=datatype, count=1)
        for i, o in enumerate(offsets)
    ]
    msg = FACTORY.new(
        "sensor_msgs/msg/PointCloud2",
        height=height,
        width=width,
        fields=fields,
        point_step=point_step,
        row_step=row_step,
        data=data,
    )
    out = _converts_or_message_error(point_cloud_to_array, msg)
    if out is not None:
        assert out[1].shape == (height * width, len(offsets))


OP_CHUNK_INDEX = 0x08
BAG_FLIPS = 200


def _flip_targets(data: bytes) -> dict[str, list[tuple[int, int]]]:
    """[start, end) of the records no chunk CRC covers, by kind; "summary" runs from the data end
    (with the data section's CRC) through the footer and the closing magic."""
    found = records(data)
    data_end = next(start for op, start, _end in found if op == OP_DATA_END)
    return {
        "message index": [(s, e) for op, s, e in found if op == OP_MESSAGE_INDEX],
        "chunk index": [(s, e) for op, s, e in found if op == OP_CHUNK_INDEX],
        "metadata": [(s, e) for op, s, e in found if op == OP_METADATA],
        "summary": [(data_end, len(data))],
    }


def _read(path: Path, on_damage: OnDamage) -> tuple[list[tuple[str, str, int, bytes]], ReadStats]:
    stats = ReadStats()
    messages = read_messages(path, raw=True, on_damage=on_damage, stats=stats)
    return [(m.topic, m.msgtype, m.log_time_ns, bytes(m.msg)) for m in messages], stats


def test_byte_flips_in_a_bags_indexes_summary_and_metadata_are_each_reported(tmp_path: Path) -> None:
    """Every flip leaves what is read identical and is reported as damage, or is reported with
    what it cost (only original messages delivered, the missing ones counted); the reader, ``bag
    info`` and ``recover`` report the same damage; nothing but a BagError is raised."""
    path = tmp_path / "bag.mcap"
    text_bag(path)
    data = path.read_bytes()
    original, _ = _read(path, "raise")
    targets = _flip_targets(data)
    rng = np.random.default_rng(20260)
    victim = tmp_path / "flipped.mcap"
    outcomes: Counter[str] = Counter()
    problems = []
    for k in range(BAG_FLIPS):
        kind = sorted(targets)[k % len(targets)]
        start, end = targets[kind][int(rng.integers(len(targets[kind])))]
        at, mask = int(rng.integers(start, end)), int(rng.integers(1, 256))
        flipped = bytearray(data)
        flipped[at] ^= mask
        victim.write_bytes(bytes(flipped))
        where = f"{kind}: byte {at} ^ 0x{mask:02x}"
        try:
            got, stats = _read(victim, "skip")
        except BagError:
            outcomes["refused"] += 1
            continue
        if not stats.damage:
            problems.append(f"{where}: not reported" + ("" if got == original else " and the messages differ"))
        elif got == original:
            outcomes["reported, nothing lost"] += 1
        else:
            missing = len(original) - len(got)
            counted = stats.lost_unknown or missing <= sum((stats.lost + stats.undecodable).values())
            if Counter(got) - Counter(original) or not counted:
                problems.append(f"{where}: {missing} message(s) missing, not all counted, or a changed one delivered")
            outcomes["reported, messages lost"] += 1
        try:
            if _read(victim, "raise")[0] != original:
                problems.append(f"{where}: read without an error, but different")
        except BagError:
            pass
        if bag_info(victim).damage != stats.damage:
            problems.append(f"{where}: bag info reports other damage than the reader")
        if k % 4 == 0:
            copy = tmp_path / f"copy{k}.mcap"
            try:
                recovered = recover_bag(victim, copy)
            except BagError:
                problems.append(f"{where}: nothing recovered though messages were read")
                continue
            if recovered.damage != stats.damage or _read(copy, "raise")[0] != got:
                problems.append(f"{where}: recover copies or reports something else than the reader")
    assert problems == []
    assert sum(outcomes.values()) == BAG_FLIPS and outcomes["reported, nothing lost"] > BAG_FLIPS // 2
