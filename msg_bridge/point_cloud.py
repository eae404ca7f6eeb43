"""``sensor_msgs/PointCloud2`` <-> numpy: elevation maps for viewers, LiDAR scans for labels.

:func:`elevation_point_cloud`: one point per cell with an estimate, at the cell centre in the road
frame: (x, y) of the cell, z = elevation; four little-endian float32 fields (16-byte points),
``height`` 1, dense. :func:`point_cloud_to_array` reads such clouds back (any float32 fields).
:func:`point_cloud_xyz` reads x, y, z of any LiDAR driver's cloud (float32 or float64 fields,
other fields such as ``ring`` or ``time`` skipped); :func:`array_point_cloud` writes float32 clouds.
"""

from __future__ import annotations

from typing import Any

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
from msg_bridge.grid_map import ROAD_FRAME
from roadbev_core.config import GridSpec

__all__ = [
    "FLOAT32",
    "FLOAT64",
    "array_point_cloud",
    "elevation_point_cloud",
    "point_cloud_to_array",
    "point_cloud_xyz",
]

FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
FLOAT64 = 8  # sensor_msgs/PointField.FLOAT64
_FIELDS = ("x", "y", "z", "uncertainty")


def elevation_point_cloud(
    elevation: np.ndarray,
    uncertainty: np.ndarray | None,
    grid: GridSpec,
    factory: MessageFactory,
    *,
    stamp_ns: int,
    frame_id: str = ROAD_FRAME,
) -> Any:
    """A PointCloud2 of the estimated cells (uncertainty NaN when not given)."""
    elevation = np.asarray(elevation, dtype=np.float32)
    if elevation.shape != grid.shape:
        raise MessageError(f"elevation is {elevation.shape}, the grid is {grid.shape}")
    sigma = (
        np.full(grid.shape, np.nan, np.float32)
        if uncertainty is None
        else np.asarray(uncertainty, dtype=np.float32)
    )
    if sigma.shape != grid.shape:
        raise MessageError(f"uncertainty is {sigma.shape}, the grid is {grid.shape}")
    rows, cols = np.nonzero(np.isfinite(elevation))  # row-major order: far to near
    points = np.empty((rows.size, 4), dtype="<f4")  # [N, 4]
    points[:, 0] = grid.x_centres()[rows]
    points[:, 1] = grid.y_centres()[cols]
    points[:, 2] = elevation[rows, cols]
    points[:, 3] = sigma[rows, cols]
    return array_point_cloud(points, _FIELDS, factory, stamp_ns=stamp_ns, frame_id=frame_id)


def point_cloud_to_array(msg: Any) -> tuple[tuple[str, ...], np.ndarray]:
    """The float32 fields of a PointCloud2 as ``(names, [N, n_fields] float32)``.

    Raises:
        MessageError: non-float32 or overlapping fields, a point_step too small for them,
            a row_step smaller than a row, or data shorter than ``height * row_step``.
    """
    height = as_int(field(msg, "height"), "PointCloud2.height")
    width = as_int(field(msg, "width"), "PointCloud2.width")
    point_step = as_int(field(msg, "point_step"), "PointCloud2.point_step")
    row_step = as_int(field(msg, "row_step"), "PointCloud2.row_step")
    bigendian = bool(field(msg, "is_bigendian"))
    names, offsets = [], []
    for f in field(msg, "fields"):
        name = as_str(field(f, "name"), "PointField.name")
        datatype = as_int(field(f, "datatype"), f"PointField {name!r} datatype")
        count = as_int(field(f, "count"), f"PointField {name!r} count")
        offset = as_int(field(f, "offset"), f"PointField {name!r} offset")
        if datatype != FLOAT32 or count != 1:
            raise MessageError(f"field {name!r} is not a single float32 (datatype {datatype}, count {count})")
        if offset + 4 > point_step:
            raise MessageError(f"field {name!r} at offset {offset} does not fit a {point_step}-byte point")
        names.append(name)
        offsets.append(offset)
    if len(set(offsets)) != len(offsets):
        raise MessageError("PointCloud2 fields overlap")
    if row_step < width * point_step:
        raise MessageError(f"row_step {row_step} is smaller than {width} points of {point_step} bytes")
    raw = buffer_view(field(msg, "data"), np.uint8, "PointCloud2.data")
    if raw.size < height * row_step:
        raise MessageError(
            f"PointCloud2.data holds {raw.size} bytes, less than height*row_step = {height * row_step}"
        )
    n = height * width
    out = np.empty((n, len(names)), dtype=np.float32)
    if n:
        rows = raw[: height * row_step].reshape(height, row_step)[:, : width * point_step]
        points = rows.reshape(n, point_step)  # [N, point_step] bytes
        dtype = np.dtype(">f4" if bigendian else "<f4")
        for i, offset in enumerate(offsets):
            out[:, i] = points[:, offset : offset + 4].copy().view(dtype)[:, 0]
    return tuple(names), out


def array_point_cloud(
    points: np.ndarray,
    names: tuple[str, ...],
    factory: MessageFactory,
    *,
    stamp_ns: int,
    frame_id: str,
) -> Any:
    """A dense PointCloud2 of ``points`` [N, len(names)] as little-endian float32 fields."""
    pts = np.ascontiguousarray(np.asarray(points, dtype="<f4"))
    if pts.ndim != 2 or pts.shape[1] != len(names):
        raise MessageError(f"points are {pts.shape}, expected [N, {len(names)}] for fields {names}")
    step = 4 * len(names)
    fields = [
        factory.new("sensor_msgs/msg/PointField", name=name, offset=4 * i, datatype=FLOAT32, count=1)
        for i, name in enumerate(names)
    ]
    return factory.new(
        "sensor_msgs/msg/PointCloud2",
        header=make_header(factory, stamp_ns, frame_id),
        height=1,
        width=int(pts.shape[0]),
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * int(pts.shape[0]),
        data=factory.sequence(pts.reshape(-1).view(np.uint8)),
        is_dense=True,
    )


def point_cloud_xyz(msg: Any) -> np.ndarray:
    """x, y, z of a PointCloud2 as [N, 3] float64 (rows with a non-finite coordinate dropped).

    Fields other than x, y, z (intensity, ring, time...) may have any type and are skipped.

    Raises:
        MessageError: no float32/float64 x, y and z fields, fields beyond the point, a row_step
            smaller than a row, or data shorter than ``height * row_step``.
    """
    height = as_int(field(msg, "height"), "PointCloud2.height")
    width = as_int(field(msg, "width"), "PointCloud2.width")
    point_step = as_int(field(msg, "point_step"), "PointCloud2.point_step")
    row_step = as_int(field(msg, "row_step"), "PointCloud2.row_step")
    bigendian = bool(field(msg, "is_bigendian"))
    found: dict[str, tuple[int, int]] = {}
    for f in field(msg, "fields"):
        name = as_str(field(f, "name"), "PointField.name")
        if name in ("x", "y", "z"):
            datatype = as_int(field(f, "datatype"), f"PointField {name!r} datatype")
            offset = as_int(field(f, "offset"), f"PointField {name!r} offset")
            if datatype not in (FLOAT32, FLOAT64):
                raise MessageError(f"field {name!r} is neither float32 nor float64 (datatype {datatype})")
            size = 4 if datatype == FLOAT32 else 8
            if offset + size > point_step:
                raise MessageError(f"field {name!r} at offset {offset} does not fit a {point_step}-byte point")
            found[name] = (offset, size)
    missing = [k for k in ("x", "y", "z") if k not in found]
    if missing:
        raise MessageError(f"PointCloud2 has no {', '.join(missing)} field(s)")
    if row_step < width * point_step:
        raise MessageError(f"row_step {row_step} is smaller than {width} points of {point_step} bytes")
    raw = buffer_view(field(msg, "data"), np.uint8, "PointCloud2.data")
    if raw.size < height * row_step:
        raise MessageError(
            f"PointCloud2.data holds {raw.size} bytes, less than height*row_step = {height * row_step}"
        )
    n = height * width
    out = np.empty((n, 3), dtype=np.float64)
    if n:
        rows = raw[: height * row_step].reshape(height, row_step)[:, : width * point_step]
        points = rows.reshape(n, point_step)  # [N, point_step] bytes
        for i, name in enumerate(("x", "y", "z")):
            offset, size = found[name]
            dtype = np.dtype((">" if bigendian else "<") + ("f4" if size == 4 else "f8"))
            out[:, i] = points[:, offset : offset + size].copy().view(dtype)[:, 0]
    return out[np.isfinite(out).all(axis=1)]
