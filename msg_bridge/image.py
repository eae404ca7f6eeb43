"""``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` <-> numpy arrays.

Reading is zero-copy where the layout allows: a native-endian image becomes a (possibly strided,
when ``step`` pads the rows) view of the message buffer. Camera images for the pipeline
(:func:`image_to_rgb`, :func:`compressed_to_rgb`) are uint8 RGB ``[H, W, 3]`` or grey ``[H, W]``.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import cv2
import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_int,
    as_str,
    buffer_view,
    field,
    make_header,
)
from roadbev_core.config import ConfigError, check_image_size

__all__ = [
    "ENCODINGS",
    "Encoding",
    "array_to_compressed",
    "array_to_image",
    "check_image_message",
    "compressed_to_array",
    "compressed_to_rgb",
    "image_to_array",
    "image_to_rgb",
]


class Encoding(NamedTuple):
    """Pixel layout of an image encoding: element type and channels per pixel."""

    dtype: np.dtype
    channels: int

    @property
    def bytes_per_pixel(self) -> int:
        return self.dtype.itemsize * self.channels


ENCODINGS: dict[str, Encoding] = {
    "rgb8": Encoding(np.dtype(np.uint8), 3),
    "bgr8": Encoding(np.dtype(np.uint8), 3),
    "rgba8": Encoding(np.dtype(np.uint8), 4),
    "bgra8": Encoding(np.dtype(np.uint8), 4),
    "mono8": Encoding(np.dtype(np.uint8), 1),
    "mono16": Encoding(np.dtype(np.uint16), 1),
    "32FC1": Encoding(np.dtype(np.float32), 1),
}


def check_image_message(msg: Any, max_bytes: int, what: str = "image") -> int:
    """Refuse an ``Image`` or ``CompressedImage`` from its fields alone (nothing is decoded or
    copied), before it is queued: data over ``max_bytes``, or a raw image over
    :data:`roadbev_core.config.MAX_IMAGE_PIXELS`.

    Returns:
        The size of its data in bytes.

    Raises:
        MessageError: naming the size and the limit.
    """

    nbytes = len(field(msg, "data"))
    if nbytes > max_bytes:
        raise MessageError(f"{what} of {nbytes / 2**20:.1f} MiB is larger than the limit of "
                           f"{max_bytes / 2**20:.1f} MiB (max_image_mb)")
    if hasattr(msg, "width") and hasattr(msg, "height"):
        try:
            check_image_size(as_int(field(msg, "width"), "Image.width"), as_int(field(msg, "height"), "Image.height"),
                             what)
        except ConfigError as exc:
            raise MessageError(str(exc)) from None
    return nbytes


def image_to_array(msg: Any) -> np.ndarray:
    """The pixels of a ``sensor_msgs/Image`` in its own encoding.

    Returns:
        [H, W] (one channel) or [H, W, C] array of the encoding's dtype in native byte order; a
        view of ``msg.data`` unless the image is big-endian with multi-byte elements.

    Raises:
        MessageError: unknown encoding, zero size, ``step`` smaller than a row, data shorter
            than ``height * step``, or an ``is_bigendian`` that is not 0/1.
    """
    height = as_int(field(msg, "height"), "Image.height")
    width = as_int(field(msg, "width"), "Image.width")
    encoding_name = as_str(field(msg, "encoding"), "Image.encoding")
    step = as_int(field(msg, "step"), "Image.step")
    bigendian = as_int(field(msg, "is_bigendian"), "Image.is_bigendian")
    if encoding_name not in ENCODINGS:
        raise MessageError(
            f"unsupported image encoding {encoding_name!r}; supported: {', '.join(ENCODINGS)}"
        )
    if height == 0 or width == 0:
        raise MessageError(f"image is empty ({width}x{height})")
    if bigendian > 1:
        raise MessageError(f"Image.is_bigendian must be 0 or 1, got {bigendian}")
    encoding = ENCODINGS[encoding_name]
    row_bytes = width * encoding.bytes_per_pixel
    if step < row_bytes:
        raise MessageError(
            f"Image.step {step} is smaller than a {encoding_name} row of {width} pixels "
            f"({row_bytes} bytes)"
        )
    raw = buffer_view(field(msg, "data"), np.uint8, "Image.data")
    if raw.size < height * step:
        raise MessageError(
            f"Image.data holds {raw.size} bytes, less than height*step = {height}*{step} = "
            f"{height * step}"
        )
    rows = raw[: height * step].reshape(height, step)[:, :row_bytes]  # [H, row_bytes] view
    dtype = encoding.dtype.newbyteorder(">" if bigendian else "<")
    pixels = rows.view(dtype)  # [H, W*C]
    if dtype.itemsize > 1 and not dtype.isnative:
        pixels = pixels.astype(encoding.dtype)
    if encoding.channels == 1:
        return cast("np.ndarray", pixels.reshape(height, width))
    return cast("np.ndarray", pixels.reshape(height, width, encoding.channels))


def image_to_rgb(msg: Any) -> np.ndarray:
    """A ``sensor_msgs/Image`` as a camera image for the pipeline.

    Returns:
        uint8 RGB [H, W, 3] for colour encodings (a view for rgb8), uint8 [H, W] for mono8 and
        mono16 (mono16 keeps the high byte).

    Raises:
        MessageError: as :func:`image_to_array`, or a 32FC1 (depth) image.
    """
    pixels = image_to_array(msg)
    encoding = msg.encoding
    if encoding == "rgb8":
        return pixels
    if encoding in ("bgr8", "bgra8", "rgba8"):
        code = {"bgr8": cv2.COLOR_BGR2RGB, "bgra8": cv2.COLOR_BGRA2RGB, "rgba8": cv2.COLOR_RGBA2RGB}[encoding]
        # OpenCV's conversion is far cheaper than a numpy channel flip (a strided copy)
        return cv2.cvtColor(np.ascontiguousarray(pixels), code)
    if encoding == "mono8":
        return pixels
    if encoding == "mono16":
        return (pixels >> 8).astype(np.uint8)
    raise MessageError(f"a {encoding} image is not a camera image (need rgb8/bgr8/mono8...)")


def _infer_encoding(pixels: np.ndarray) -> str:
    if pixels.ndim == 2:
        by_dtype = {np.dtype(np.uint8): "mono8", np.dtype(np.uint16): "mono16"}
        by_dtype[np.dtype(np.float32)] = "32FC1"
        if pixels.dtype in by_dtype:
            return by_dtype[pixels.dtype]
    elif pixels.ndim == 3 and pixels.dtype == np.uint8 and pixels.shape[2] in (3, 4):
        return "rgb8" if pixels.shape[2] == 3 else "rgba8"
    raise MessageError(f"no image encoding for a {pixels.dtype} array of shape {pixels.shape}")


def array_to_image(
    pixels: np.ndarray,
    factory: MessageFactory,
    *,
    stamp_ns: int = 0,
    frame_id: str = "",
    encoding: str | None = None,
) -> Any:
    """A ``sensor_msgs/Image`` (little-endian, unpadded rows) holding ``pixels``.

    Args:
        pixels: [H, W] or [H, W, C] array whose dtype and channels match ``encoding``.
        factory: which library's message to build.
        encoding: one of :data:`ENCODINGS`; inferred when None (uint8 [H,W,3] -> rgb8,
            [H,W,4] -> rgba8, [H,W] uint8/uint16/float32 -> mono8/mono16/32FC1).
    """
    pixels = np.asarray(pixels)
    encoding = encoding or _infer_encoding(pixels)
    if encoding not in ENCODINGS:
        raise MessageError(f"unsupported image encoding {encoding!r}")
    spec = ENCODINGS[encoding]
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    if pixels.ndim not in (2, 3) or pixels.dtype != spec.dtype or channels != spec.channels:
        raise MessageError(f"a {pixels.dtype} array of shape {pixels.shape} is not {encoding}")
    if pixels.size == 0:
        raise MessageError(f"image is empty {pixels.shape}")
    height, width = pixels.shape[:2]
    data = np.ascontiguousarray(pixels.astype(spec.dtype.newbyteorder("<"), copy=False))
    return factory.new(
        "sensor_msgs/msg/Image",
        header=make_header(factory, stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * spec.bytes_per_pixel,
        data=factory.sequence(data.reshape(-1).view(np.uint8)),
    )


def _compressed_kind(fmt: str) -> str:
    text = fmt.lower()
    if "jpeg" in text or "jpg" in text:
        return "jpeg"
    if "png" in text:
        return "png"
    raise MessageError(f"unsupported CompressedImage format {fmt!r} (need jpeg or png)")


def compressed_to_array(msg: Any) -> np.ndarray:
    """Decode a ``sensor_msgs/CompressedImage`` (jpeg or png) as OpenCV does.

    Returns:
        [H, W] (grey) or [H, W, 3|4] (BGR/BGRA) uint8 (uint16 for 16-bit PNG).

    Raises:
        MessageError: unknown format, empty data, or data that does not decode.
    """
    kind = _compressed_kind(as_str(field(msg, "format"), "CompressedImage.format"))
    data = buffer_view(field(msg, "data"), np.uint8, "CompressedImage.data")
    if data.size == 0:
        raise MessageError("CompressedImage.data is empty")
    try:
        pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise MessageError(f"CompressedImage ({kind}) does not decode: {exc}") from None
    if pixels is None or pixels.size == 0:
        raise MessageError(f"CompressedImage data ({data.size} bytes) is not a valid {kind}")
    return pixels


def compressed_to_rgb(msg: Any) -> np.ndarray:
    """A ``sensor_msgs/CompressedImage`` as uint8 RGB [H, W, 3] or grey [H, W]."""
    pixels = compressed_to_array(msg)
    if pixels.dtype == np.uint16:
        pixels = (pixels >> 8).astype(np.uint8)
    if pixels.dtype != np.uint8:
        raise MessageError(f"decoded CompressedImage has unsupported type {pixels.dtype}")
    if pixels.ndim == 2:
        return pixels
    if pixels.shape[2] == 3:
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)
    if pixels.shape[2] == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGB)
    raise MessageError(f"decoded CompressedImage has {pixels.shape[2]} channels")


def array_to_compressed(
    pixels: np.ndarray,
    factory: MessageFactory,
    *,
    stamp_ns: int = 0,
    frame_id: str = "",
    fmt: str = "jpeg",
    jpeg_quality: int = 90,
    png_level: int = 3,
) -> Any:
    """A ``sensor_msgs/CompressedImage`` (``format`` "jpeg" or "png") of an RGB or grey image.

    Args:
        pixels: uint8 RGB [H, W, 3] or grey [H, W].
        fmt: "jpeg" or "png".
        jpeg_quality: 0..100 (JPEG only); png_level: 0..9 (PNG only).
    """
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8 or not (
        pixels.ndim == 2 or (pixels.ndim == 3 and pixels.shape[2] == 3)
    ) or pixels.size == 0:
        raise MessageError(f"need uint8 RGB [H,W,3] or grey [H,W], got {pixels.dtype} {pixels.shape}")
    kind = _compressed_kind(fmt)
    bgr = pixels if pixels.ndim == 2 else cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    if kind == "jpeg":
        ok, encoded = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    else:
        ok, encoded = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)])
    if not ok:
        raise MessageError(f"OpenCV could not encode a {pixels.shape} image as {kind}")
    return factory.new(
        "sensor_msgs/msg/CompressedImage",
        header=make_header(factory, stamp_ns, frame_id),
        format=kind,
        data=factory.sequence(encoded.reshape(-1)),
    )
