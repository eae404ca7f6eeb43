"""Elevation maps <-> ``grid_map_msgs/GridMap`` (grid_map 2.2, ROS 2 Jazzy).

grid_map's conventions, which the interface adopts (docs/interface/frames-and-grid.md): cell (0, 0) is the corner at
(+length_x/2, +length_y/2) from the map centre, rows run toward -x and columns toward -y, so a
``[n_rows, n_cols]`` array of :class:`roadbev_core.config.GridSpec` (row 0 farthest, column 0
leftmost) is sent as it is. Each layer is a ``std_msgs/Float32MultiArray`` stored column-major
(``flatten(order='F')``) with the layout grid_map writes: ``dim[0]`` = "column_index" (size
n_cols, stride n_rows*n_cols), ``dim[1]`` = "row_index" (size n_rows, stride n_rows).
``info.pose`` is the grid centre in ``header.frame_id``; NaN marks cells without a value.

Reading also accepts row-major layers (``dim[0]`` = "row_index"), a ``data_offset`` and the
circular-buffer start indices, as grid_map's own converter does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_float,
    as_int,
    as_str,
    buffer_view,
    field,
    make_header,
    stamp_from_header,
)
from roadbev_core.config import ConfigError, GridSpec
from roadbev_core.fusion import MapWindow

__all__ = [
    "ROAD_FRAME",
    "GridMapData",
    "RawGridMap",
    "decode_grid_map",
    "elevation_grid_map",
    "fused_map_message",
    "grid_from_info",
    "grid_map_message",
    "grid_map_message_at",
    "grid_map_to_arrays",
    "map_window_from_message",
]

ROAD_FRAME = "roadbev_road"


class GridMapData(NamedTuple):
    """A decoded GridMap.

    Attributes:
        layers: name -> [n_rows, n_cols] float32 (row 0 farthest, col 0 leftmost).
        grid: the horizontal grid recovered from ``info`` (vertical fields from ``base``).
        stamp_ns: ``header.stamp``.
        frame_id: ``header.frame_id``.
        basic_layers: ``basic_layers``.
    """

    layers: dict[str, np.ndarray]
    grid: GridSpec
    stamp_ns: int
    frame_id: str
    basic_layers: tuple[str, ...]


def grid_map_message(
    layers: Mapping[str, np.ndarray],
    grid: GridSpec,
    factory: MessageFactory,
    *,
    stamp_ns: int,
    frame_id: str = ROAD_FRAME,
    basic_layers: Sequence[str] = ("elevation",),
) -> Any:
    """A GridMap with the given layers on ``grid``.

    Args:
        layers: name -> [n_rows, n_cols] array (stored as float32, NaN = no value).
        basic_layers: layers that must be valid for a cell to be valid (grid_map semantics).
    """
    for name, values in layers.items():
        if np.shape(values) != grid.shape:
            raise MessageError(f"layer {name!r} is {np.shape(values)}, the grid is {grid.shape}")
    return grid_map_message_at(
        layers,
        factory,
        resolution=grid.resolution,
        length=(grid.length_x, grid.length_y),
        centre=grid.centre,
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        basic_layers=basic_layers,
    )


def grid_map_message_at(
    layers: Mapping[str, np.ndarray],
    factory: MessageFactory,
    *,
    resolution: float,
    length: tuple[float, float],
    centre: tuple[float, float],
    stamp_ns: int,
    frame_id: str,
    basic_layers: Sequence[str] = ("elevation",),
) -> Any:
    """A GridMap of any axis-aligned extent (a map in ``odom``, not only a :class:`GridSpec`).

    Args:
        layers: name -> [n_rows, n_cols] array, all the same shape (row 0 at +x, col 0 at +y).
        resolution: cell size (m).
        length: (length_x, length_y) of the map (m): n_rows and n_cols cells.
        centre: (x, y) of the map centre in ``frame_id``.
    """
    if not layers:
        raise MessageError("a GridMap needs at least one layer")
    missing = [name for name in basic_layers if name not in layers]
    if missing:
        raise MessageError(f"basic layer(s) {missing} are not among the layers {list(layers)}")
    shapes = {np.shape(values) for values in layers.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise MessageError(f"layers must be equal 2-D arrays, got shapes {sorted(shapes)}")
    n_rows, n_cols = next(iter(shapes))
    if int(round(length[0] / resolution)) != n_rows or int(round(length[1] / resolution)) != n_cols:
        raise MessageError(f"a {length[0]} x {length[1]} m map of {resolution} m cells is not {n_rows}x{n_cols}")
    data = []
    for values in layers.values():
        column_major = np.asarray(values).astype(np.float32).flatten(order="F")  # [n_rows*n_cols]
        layout = factory.new(
            "std_msgs/msg/MultiArrayLayout",
            dim=[
                factory.new(
                    "std_msgs/msg/MultiArrayDimension",
                    label="column_index",
                    size=n_cols,
                    stride=n_rows * n_cols,
                ),
                factory.new(
                    "std_msgs/msg/MultiArrayDimension", label="row_index", size=n_rows, stride=n_rows
                ),
            ],
            data_offset=0,
        )
        data.append(
            factory.new(
                "std_msgs/msg/Float32MultiArray", layout=layout, data=factory.sequence(column_major)
            )
        )
    cx, cy = centre
    pose = factory.new(
        "geometry_msgs/msg/Pose",
        position=factory.new("geometry_msgs/msg/Point", x=float(cx), y=float(cy), z=0.0),
        orientation=factory.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
    )
    info = factory.new(
        "grid_map_msgs/msg/GridMapInfo",
        resolution=float(resolution),
        length_x=float(length[0]),
        length_y=float(length[1]),
        pose=pose,
    )
    return factory.new(
        "grid_map_msgs/msg/GridMap",
        header=make_header(factory, stamp_ns, frame_id),
        info=info,
        layers=list(layers),
        basic_layers=list(basic_layers),
        data=data,
        outer_start_index=0,
        inner_start_index=0,
    )


def fused_map_message(window: MapWindow, factory: MessageFactory, *, frame_id: str) -> Any:
    """The fused road map (``/roadbev/map``, docs/interface/topics.md): layers elevation, uncertainty,
    observations and age of a :class:`roadbev_core.fusion.MapWindow` (and datum_uncertainty, the
    part of uncertainty nearby cells share), in ``frame_id`` (odom)."""
    n_rows, n_cols = window.elevation.shape
    r = window.resolution
    return grid_map_message_at(window.layers(), factory, resolution=r, length=(n_rows * r, n_cols * r),
                               centre=window.centre, stamp_ns=window.stamp_ns, frame_id=frame_id)


def map_window_from_message(msg: Any) -> MapWindow:
    """The :class:`roadbev_core.fusion.MapWindow` of a fused-map GridMap (:func:`fused_map_message`).

    Raises:
        MessageError: a malformed GridMap, or one without the fused map's layers.
    """
    raw = decode_grid_map(msg)
    missing = [name for name in ("elevation", "uncertainty", "observations", "age") if name not in raw.layers]
    if missing:
        raise MessageError(f"GridMap is not a fused map: no layer(s) {missing}")
    layers = raw.layers
    return MapWindow(layers["elevation"], layers["uncertainty"], layers["observations"], layers["age"],
                     raw.resolution, raw.centre, raw.stamp_ns, layers.get("datum_uncertainty"))


def elevation_grid_map(
    elevation: np.ndarray,
    uncertainty: np.ndarray | None,
    grid: GridSpec,
    factory: MessageFactory,
    *,
    stamp_ns: int,
    frame_id: str = ROAD_FRAME,
) -> Any:
    """The per-frame elevation map (docs/interface/topics.md): layers ``elevation`` (+ ``uncertainty``),
    basic ``elevation``."""
    layers = {"elevation": elevation}
    if uncertainty is not None:
        layers["uncertainty"] = uncertainty
    return grid_map_message(layers, grid, factory, stamp_ns=stamp_ns, frame_id=frame_id)


def _round(value: float) -> float:
    # Centre +- half length in binary floating point leaves 1e-16 dust (2.1599999999999997).
    return round(value, 9)


def grid_from_info(info: Any, base: GridSpec | None = None) -> GridSpec:
    """The horizontal grid described by a ``GridMapInfo`` (vertical fields from ``base``).

    Raises:
        MessageError: non-positive resolution, lengths that are not whole cells, a rotated
            grid, or a window that :class:`GridSpec` rejects (for example behind the camera).
    """
    resolution = as_float(field(info, "resolution"), "GridMapInfo.resolution")
    length_x = as_float(field(info, "length_x"), "GridMapInfo.length_x")
    length_y = as_float(field(info, "length_y"), "GridMapInfo.length_y")
    pose = field(info, "pose")
    position = field(pose, "position")
    orientation = field(pose, "orientation")
    px = as_float(field(position, "x"), "GridMapInfo.pose.position.x")
    py = as_float(field(position, "y"), "GridMapInfo.pose.position.y")
    q = [as_float(field(orientation, k), f"GridMapInfo.pose.orientation.{k}") for k in "xyzw"]
    if not np.allclose(np.abs(q), [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise MessageError(f"GridMapInfo.pose.orientation {q} is rotated; only axis-aligned maps are supported")
    if resolution <= 0:
        raise MessageError(f"GridMapInfo.resolution must be positive, got {resolution}")
    base = base or GridSpec()
    try:
        return base.with_overrides(
            resolution=resolution,
            x_min=_round(px - 0.5 * length_x),
            x_max=_round(px + 0.5 * length_x),
            y_min=_round(py - 0.5 * length_y),
            y_max=_round(py + 0.5 * length_y),
        )
    except ConfigError as exc:
        raise MessageError(f"GridMapInfo does not describe a usable grid: {exc}") from None


def _layer_array(multi_array: Any, name: str, n_rows: int, n_cols: int) -> np.ndarray:
    values = buffer_view(field(multi_array, "data"), np.float32, f"layer {name!r} data")
    layout = field(multi_array, "layout")
    offset = as_int(field(layout, "data_offset"), f"layer {name!r} data_offset")
    dims = list(field(layout, "dim"))
    row_major = False
    if dims:
        if len(dims) != 2:
            raise MessageError(f"layer {name!r} has {len(dims)} dimensions, a grid map has 2")
        labels = [as_str(field(d, "label"), f"layer {name!r} dim label") for d in dims]
        sizes = [as_int(field(d, "size"), f"layer {name!r} dim size") for d in dims]
        if labels == ["row_index", "column_index"]:
            row_major = True
            expected = [n_rows, n_cols]
        elif labels in (["column_index", "row_index"], ["", ""]):
            expected = [n_cols, n_rows]
        else:
            raise MessageError(f"layer {name!r} has unknown dimension labels {labels}")
        if sizes != expected:
            rows, cols = sizes if row_major else sizes[::-1]
            raise MessageError(
                f"layer {name!r} is {rows} rows x {cols} columns but the info says "
                f"{n_rows} rows x {n_cols} columns"
            )
    needed = offset + n_rows * n_cols
    if values.size < needed:
        raise MessageError(
            f"layer {name!r} holds {values.size} values, the info needs {n_rows}x{n_cols}"
            + (f" after offset {offset}" if offset else "")
        )
    if not dims and values.size != n_rows * n_cols:
        raise MessageError(
            f"layer {name!r} holds {values.size} values, the info says {n_rows}x{n_cols} cells"
        )
    cells = values[offset:needed]
    return cells.reshape(n_rows, n_cols) if row_major else cells.reshape(n_rows, n_cols, order="F")


class RawGridMap(NamedTuple):
    """A decoded GridMap of any axis-aligned extent (see :func:`decode_grid_map`).

    Attributes:
        layers: name -> [n_rows, n_cols] float32 (row 0 at +x, col 0 at +y).
        resolution: cell size (m).
        centre: (x, y) of the map centre in ``frame_id`` (``info.pose``).
        stamp_ns, frame_id, basic_layers: as in the message.
    """

    layers: dict[str, np.ndarray]
    resolution: float
    centre: tuple[float, float]
    stamp_ns: int
    frame_id: str
    basic_layers: tuple[str, ...]


def decode_grid_map(msg: Any) -> RawGridMap:
    """Decode a GridMap without asking it to be a BEV window (a road map in ``odom``).

    Raises:
        MessageError: a rotated or non-positive geometry, or layers that disagree with it.
    """
    info = field(msg, "info")
    resolution = as_float(field(info, "resolution"), "GridMapInfo.resolution")
    length_x = as_float(field(info, "length_x"), "GridMapInfo.length_x")
    length_y = as_float(field(info, "length_y"), "GridMapInfo.length_y")
    pose = field(info, "pose")
    position = field(pose, "position")
    q = [as_float(field(field(pose, "orientation"), k), f"GridMapInfo.pose.orientation.{k}") for k in "xyzw"]
    if not np.allclose(np.abs(q), [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise MessageError(f"GridMapInfo.pose.orientation {q} is rotated; only axis-aligned maps are supported")
    if not (resolution > 0 and length_x > 0 and length_y > 0):
        raise MessageError(f"GridMapInfo needs a positive resolution and lengths, got {resolution}, "
                           f"{length_x}, {length_y}")
    n_rows, n_cols = int(round(length_x / resolution)), int(round(length_y / resolution))
    if abs(n_rows * resolution - length_x) > 1e-6 * max(1.0, length_x) or \
            abs(n_cols * resolution - length_y) > 1e-6 * max(1.0, length_y):
        raise MessageError(f"GridMap lengths {length_x} x {length_y} m are not whole {resolution} m cells")
    centre = (as_float(field(position, "x"), "GridMapInfo.pose.position.x"),
              as_float(field(position, "y"), "GridMapInfo.pose.position.y"))
    layers = _decode_layers(msg, n_rows, n_cols)
    frame_id = as_str(field(field(msg, "header"), "frame_id"), "GridMap.header.frame_id")
    basic = tuple(as_str(n, "GridMap.basic_layers[]") for n in field(msg, "basic_layers"))
    return RawGridMap(layers, resolution, centre, stamp_from_header(msg), frame_id, basic)


def _decode_layers(msg: Any, n_rows: int, n_cols: int) -> dict[str, np.ndarray]:
    names = [as_str(n, "GridMap.layers[]") for n in field(msg, "layers")]
    data = list(field(msg, "data"))
    if len(names) != len(data):
        raise MessageError(f"GridMap names {len(names)} layers but carries {len(data)} data arrays")
    if len(set(names)) != len(names):
        raise MessageError(f"GridMap has duplicate layer names {names}")
    start_row = as_int(field(msg, "outer_start_index"), "GridMap.outer_start_index")
    start_col = as_int(field(msg, "inner_start_index"), "GridMap.inner_start_index")
    if start_row >= n_rows or start_col >= n_cols:
        raise MessageError(
            f"GridMap start index ({start_row}, {start_col}) lies outside the {n_rows}x{n_cols} map"
        )
    layers = {}
    for name, multi_array in zip(names, data, strict=True):
        cells = _layer_array(multi_array, name, n_rows, n_cols)
        if start_row or start_col:  # undo grid_map's circular buffer
            cells = np.roll(cells, (-start_row, -start_col), axis=(0, 1))
        layers[name] = cells
    return layers


def grid_map_to_arrays(msg: Any, base: GridSpec | None = None) -> GridMapData:
    """Decode a GridMap into per-layer arrays on the grid recovered from its ``info``.

    Args:
        msg: a ``grid_map_msgs/GridMap`` (rclpy, rosbags or mcap_ros2 object).
        base: where the grid's non-horizontal fields (base_height, z range, class bins) come
            from; the interface's defaults when None.

    Raises:
        MessageError: an info that is not a grid, layer names and data that disagree in
            number, duplicate layer names, or a layer whose size disagrees with the info.
    """
    stamp_ns = stamp_from_header(msg)
    frame_id = as_str(field(field(msg, "header"), "frame_id"), "GridMap.header.frame_id")
    grid = grid_from_info(field(msg, "info"), base)
    basic = tuple(as_str(n, "GridMap.basic_layers[]") for n in field(msg, "basic_layers"))
    layers = _decode_layers(msg, *grid.shape)
    return GridMapData(layers, grid, stamp_ns, frame_id, basic)
