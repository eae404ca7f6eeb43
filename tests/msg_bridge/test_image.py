"""Image and CompressedImage conversions: encodings, padding, endianness, zero-copy, errors."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, RclpyFactory, bag_factory
from msg_bridge.image import (
    ENCODINGS,
    array_to_compressed,
    array_to_image,
    check_image_message,
    compressed_to_array,
    compressed_to_rgb,
    image_to_array,
    image_to_rgb,
)

RNG = np.random.default_rng(7)


def _pixels(encoding: str, h: int = 5, w: int = 7) -> np.ndarray:
    spec = ENCODINGS[encoding]
    shape = (h, w) if spec.channels == 1 else (h, w, spec.channels)
    if spec.dtype == np.float32:
        return RNG.normal(size=shape).astype(np.float32)
    return RNG.integers(0, np.iinfo(spec.dtype).max, shape, dtype=spec.dtype)


def _raw_image(
    factory: MessageFactory, pixels: np.ndarray, encoding: str, *, pad: int = 0, bigendian: bool = False
) -> Any:
    """An Image built by hand: rows padded with ``pad`` junk bytes, optionally big-endian."""
    h, w = pixels.shape[:2]
    data = pixels.astype(pixels.dtype.newbyteorder(">" if bigendian else "<")).reshape(h, -1).view(np.uint8)
    padded = np.concatenate([data, np.full((h, pad), 0xAB, np.uint8)], axis=1)
    return factory.new(
        "sensor_msgs/msg/Image",
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=padded.shape[1],
        data=factory.sequence(padded.reshape(-1)),
    )


@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_round_trip_every_encoding(factory: MessageFactory, encoding: str) -> None:
    pixels = _pixels(encoding)
    msg = array_to_image(pixels, factory, stamp_ns=1_500_000_001, frame_id="cam", encoding=encoding)
    assert msg.step == pixels.shape[1] * ENCODINGS[encoding].bytes_per_pixel
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_001)
    np.testing.assert_array_equal(image_to_array(msg), pixels)


@pytest.mark.parametrize("encoding", ["rgb8", "mono16", "32FC1", "bgra8"])
@pytest.mark.parametrize("pad", [1, 3, 16])
def test_row_padding_is_skipped(factory: MessageFactory, encoding: str, pad: int) -> None:
    pixels = _pixels(encoding)
    np.testing.assert_array_equal(image_to_array(_raw_image(factory, pixels, encoding, pad=pad)), pixels)


@pytest.mark.parametrize("encoding", ["mono16", "32FC1"])
def test_big_endian_images_are_swapped(factory: MessageFactory, encoding: str) -> None:
    pixels = _pixels(encoding)
    out = image_to_array(_raw_image(factory, pixels, encoding, bigendian=True))
    assert out.dtype.isnative
    np.testing.assert_array_equal(out, pixels)


def test_reading_is_zero_copy_for_native_images() -> None:
    factory = bag_factory()  # rosbags holds data in a numpy array we can compare against
    pixels = _pixels("rgb8", 4, 6)
    msg = _raw_image(factory, pixels, "rgb8", pad=2)
    out = image_to_array(msg)
    assert np.shares_memory(out, msg.data)
    rclpy_msg = array_to_image(pixels, RclpyFactory())
    assert image_to_rgb(rclpy_msg).base is not None  # a view of the array.array buffer


def test_colour_orders_become_rgb(factory: MessageFactory) -> None:
    rgb = _pixels("rgb8")
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    bgra = np.concatenate([bgr, np.full((*rgb.shape[:2], 1), 9, np.uint8)], axis=2)
    rgba = np.concatenate([rgb, np.full((*rgb.shape[:2], 1), 9, np.uint8)], axis=2)
    for pixels, encoding in ((bgr, "bgr8"), (bgra, "bgra8"), (rgba, "rgba8"), (rgb, "rgb8")):
        np.testing.assert_array_equal(image_to_rgb(array_to_image(pixels, factory, encoding=encoding)), rgb)
    mono16 = np.array([[0x1234, 0xFFFF]], np.uint16)
    np.testing.assert_array_equal(image_to_rgb(array_to_image(mono16, factory)), [[0x12, 0xFF]])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"encoding": "yuv422"}, "unsupported image encoding"),
        ({"height": 0}, "empty"),
        ({"width": 0}, "empty"),
        ({"step": 20}, "smaller than"),
        ({"is_bigendian": 2}, "is_bigendian"),
        ({"data": np.zeros(10, np.uint8)}, "less than height\\*step"),
    ],
)
def test_malformed_images_raise_message_error(change: dict[str, Any], message: str) -> None:
    factory = bag_factory()
    msg = array_to_image(_pixels("rgb8"), factory)  # 5x7 rgb8, step 21
    for name, value in change.items():
        setattr(msg, name, value)
    with pytest.raises(MessageError, match=message):
        image_to_array(msg)


def test_depth_image_is_not_a_camera_image(factory: MessageFactory) -> None:
    with pytest.raises(MessageError, match="not a camera image"):
        image_to_rgb(array_to_image(_pixels("32FC1"), factory))


def test_png_round_trip_is_exact_and_jpeg_is_close(factory: MessageFactory) -> None:
    yy, xx = np.mgrid[0:32, 0:40]
    smooth = np.stack([xx * 6, yy * 7, (xx + yy) * 3], axis=-1).astype(np.uint8)
    png = array_to_compressed(smooth, factory, fmt="png", stamp_ns=3)
    assert png.format == "png"
    np.testing.assert_array_equal(compressed_to_rgb(png), smooth)
    jpeg = array_to_compressed(smooth, factory, fmt="jpeg", jpeg_quality=95)
    assert jpeg.format == "jpeg"
    assert np.abs(compressed_to_rgb(jpeg).astype(int) - smooth).mean() < 3.0
    grey = smooth[:, :, 0].copy()
    np.testing.assert_array_equal(compressed_to_rgb(array_to_compressed(grey, factory, fmt="png")), grey)


def test_image_transport_format_strings_are_understood() -> None:
    factory = bag_factory()
    rgb = _pixels("rgb8", 8, 8)
    msg = array_to_compressed(rgb, factory, fmt="png")
    msg.format = "rgb8; png compressed bgr8"
    np.testing.assert_array_equal(compressed_to_rgb(msg), rgb)
    assert compressed_to_array(msg).shape == (8, 8, 3)


@pytest.mark.parametrize(
    ("fmt", "data", "message"),
    [
        ("webp", b"RIFF", "unsupported CompressedImage format"),
        ("jpeg", b"", "empty"),
        ("jpeg", b"\xff\xd8\xff\xe0 this is not a jpeg", "not a valid jpeg"),
        ("png", b"\x89PNG\r\n\x1a\n", "not a valid png"),
    ],
)
def test_bad_compressed_images_raise_message_error(fmt: str, data: bytes, message: str) -> None:
    factory = bag_factory()
    msg = factory.new("sensor_msgs/msg/CompressedImage", format=fmt, data=np.frombuffer(data, np.uint8))
    with pytest.raises(MessageError, match=message):
        compressed_to_rgb(msg)


def test_truncated_jpeg_raises_or_decodes() -> None:
    factory = bag_factory()
    msg = array_to_compressed(_pixels("rgb8", 32, 32), factory)
    msg.data = msg.data[: len(msg.data) // 3]
    try:
        out = compressed_to_rgb(msg)
    except MessageError:
        return
    assert out.shape == (32, 32, 3)  # libjpeg pads a truncated scan: still a whole image


def test_building_rejects_arrays_that_are_not_images(factory: MessageFactory) -> None:
    with pytest.raises(MessageError, match="no image encoding"):
        array_to_image(np.zeros((2, 2, 2), np.uint8), factory)
    with pytest.raises(MessageError, match="is not mono16"):
        array_to_image(np.zeros((2, 2), np.uint8), factory, encoding="mono16")
    with pytest.raises(MessageError, match="need uint8 RGB"):
        array_to_compressed(np.zeros((2, 2), np.float32), factory)


def test_an_oversized_image_is_refused_from_its_fields_alone(factory: MessageFactory) -> None:
    small = array_to_image(_pixels("rgb8", 48, 64), factory, stamp_ns=1, frame_id="cam")
    assert check_image_message(small, 48 * 64 * 3) == 48 * 64 * 3
    with pytest.raises(MessageError, match=r"left image of 0.0 MiB is larger than the limit .*max_image_mb"):
        check_image_message(small, 48 * 64 * 3 - 1, "left image")
    # 8000 x 8000 in the header: refused by its size before the (here missing) pixels are looked at
    huge = array_to_image(_pixels("mono8", 2, 2), factory, stamp_ns=1, frame_id="cam")
    huge.width = huge.height = 8000
    with pytest.raises(MessageError, match="8000 x 8000 pixels is larger than the limit"):
        check_image_message(huge, 2**30, "right image")
    jpeg = array_to_compressed(_pixels("rgb8", 48, 64), factory, stamp_ns=1, frame_id="cam", fmt="jpeg")
    assert check_image_message(jpeg, 2**20) == len(jpeg.data)
    with pytest.raises(MessageError, match="larger than the limit"):
        check_image_message(jpeg, 10)
