"""GridMap <-> arrays: grid_map's storage order, info, start indices, grid recovery, errors."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory
from msg_bridge.grid_map import ROAD_FRAME, elevation_grid_map, grid_map_message, grid_map_to_arrays
from roadbev_core.config import GridSpec

GRID = GridSpec()
RNG = np.random.default_rng(3)


def _maps() -> tuple[np.ndarray, np.ndarray]:
    elevation = RNG.normal(0, 0.03, GRID.shape).astype(np.float32)
    elevation[:7, :] = np.nan
    uncertainty = np.abs(RNG.normal(0, 0.01, GRID.shape)).astype(np.float32)
    return elevation, uncertainty


def test_contract_fields_and_round_trip(factory: MessageFactory) -> None:
    elevation, uncertainty = _maps()
    msg = elevation_grid_map(elevation, uncertainty, GRID, factory, stamp_ns=42_000_000_007)
    assert msg.header.frame_id == ROAD_FRAME == "roadbev_road"
    assert list(msg.layers) == ["elevation", "uncertainty"]
    assert list(msg.basic_layers) == ["elevation"]
    assert msg.info.resolution == pytest.approx(0.03)
    assert (msg.info.length_x, msg.info.length_y) == pytest.approx((4.92, 1.92))
    assert (msg.info.pose.position.x, msg.info.pose.position.y) == pytest.approx((4.62, 0.04))
    dims = msg.data[0].layout.dim
    assert [(d.label, d.size, d.stride) for d in dims] == [
        ("column_index", 64, 164 * 64),
        ("row_index", 164, 164),
    ]
    decoded = grid_map_to_arrays(msg)
    assert decoded.grid == GRID
    assert decoded.stamp_ns == 42_000_000_007
    np.testing.assert_array_equal(decoded.layers["elevation"], elevation)  # NaN where NaN
    np.testing.assert_array_equal(decoded.layers["uncertainty"], uncertainty)


def test_storage_is_column_major_with_cell_0_0_far_left(factory: MessageFactory) -> None:
    values = np.arange(GRID.n_rows * GRID.n_cols, dtype=np.float32).reshape(GRID.shape)
    msg = grid_map_message({"elevation": values}, GRID, factory, stamp_ns=0)
    data = np.asarray(msg.data[0].data)
    # grid_map: index (0,0) at (+length_x/2, +length_y/2), consecutive values go down a column
    assert data[0] == values[0, 0] and data[1] == values[1, 0] and data[GRID.n_rows] == values[0, 1]


def test_row_major_layers_and_start_indices_are_understood() -> None:
    factory = bag_factory()
    elevation, _ = _maps()
    msg = grid_map_message({"elevation": elevation}, GRID, factory, stamp_ns=0)
    # row-major layout, as grid_map writes for row-major Eigen storage
    row_major = msg.data[0]
    row_major.data = elevation.reshape(-1).copy()
    row_major.layout.dim[0].label, row_major.layout.dim[0].size = "row_index", GRID.n_rows
    row_major.layout.dim[1].label, row_major.layout.dim[1].size = "column_index", GRID.n_cols
    np.testing.assert_array_equal(grid_map_to_arrays(msg).layers["elevation"], elevation)
    # circular buffer: map cell (0,0) stored at buffer index (start_row, start_col)
    msg = grid_map_message({"elevation": elevation}, GRID, factory, stamp_ns=0)
    buffer = np.roll(elevation, (5, 9), axis=(0, 1))
    msg.data[0].data = buffer.flatten(order="F")
    msg.outer_start_index, msg.inner_start_index = 5, 9
    np.testing.assert_array_equal(grid_map_to_arrays(msg).layers["elevation"], elevation)


def test_grid_is_recovered_from_info_with_other_windows(factory: MessageFactory) -> None:
    other = GridSpec(x_min=3.0, x_max=9.0, y_min=-1.5, y_max=1.5, resolution=0.05, base_height=1.6)
    values = np.zeros(other.shape, np.float32)
    msg = grid_map_message({"elevation": values}, other, factory, stamp_ns=0)
    recovered = grid_map_to_arrays(msg, base=GridSpec(base_height=1.6)).grid
    assert recovered == other
    assert grid_map_to_arrays(msg).grid.base_height == 1.1  # vertical fields come from the base


def _bad(change: Callable[[Any], object]) -> None:
    msg = elevation_grid_map(*_maps(), GRID, bag_factory(), stamp_ns=0)
    change(msg)
    grid_map_to_arrays(msg)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda m: setattr(m.data[0], "data", m.data[0].data[:100]), "holds 100 values"),
        (lambda m: setattr(m.data[1].layout.dim[0], "size", 63), "is 164 rows x 63 columns but the info"),
        (lambda m: setattr(m.info, "length_x", 4.935), "not a whole number"),
        (lambda m: setattr(m.info, "resolution", 0.0), "resolution must be positive"),
        (lambda m: setattr(m.info, "resolution", float("nan")), "finite"),
        (lambda m: setattr(m, "layers", ["elevation"]), "names 1 layers but carries 2"),
        (lambda m: setattr(m, "layers", ["elevation", "elevation"]), "duplicate"),
        (lambda m: setattr(m.info.pose.orientation, "z", 0.5), "rotated"),
        (lambda m: setattr(m.info.pose.position, "x", -10.0), "usable grid"),
        (lambda m: setattr(m, "outer_start_index", 164), "start index"),
        (lambda m: setattr(m.data[0].layout.dim[0], "label", "x"), "unknown dimension labels"),
        (lambda m: setattr(m.data[0].layout, "dim", m.data[0].layout.dim[:1]), "1 dimensions"),
    ],
)
def test_malformed_grid_maps_raise_message_error(change: Callable[[Any], object], message: str) -> None:
    with pytest.raises(MessageError, match=message):
        _bad(change)


def test_building_checks_shapes_and_basic_layers(factory: MessageFactory) -> None:
    with pytest.raises(MessageError, match="the grid is"):
        grid_map_message({"elevation": np.zeros((3, 3))}, GRID, factory, stamp_ns=0)
    with pytest.raises(MessageError, match="basic layer"):
        grid_map_message({"height": np.zeros(GRID.shape)}, GRID, factory, stamp_ns=0)
    with pytest.raises(MessageError, match="at least one layer"):
        grid_map_message({}, GRID, factory, stamp_ns=0)


def test_a_fused_map_window_round_trips_and_an_elevation_map_is_not_one(factory: MessageFactory) -> None:
    from msg_bridge.grid_map import fused_map_message, map_window_from_message
    from roadbev_core.fusion import MapWindow

    rng = np.random.default_rng(3)
    elevation, sigma, count, age = (rng.normal(0, 0.02, (30, 12)).astype(np.float32) for _ in range(4))
    elevation[0, 0] = np.nan
    window = MapWindow(elevation, sigma, count, age, resolution=0.03, centre=(12.345, -1.5), stamp_ns=77)
    out = map_window_from_message(fused_map_message(window, factory, frame_id="odom"))
    for a, b in zip(out.layers().values(), window.layers().values(), strict=True):
        np.testing.assert_array_equal(a, b)
    assert out.resolution == pytest.approx(0.03) and out.stamp_ns == 77
    assert out.centre == pytest.approx((12.345, -1.5))
    assert out.datum_uncertainty is None  # a map without the layer
    with_datum = window._replace(datum_uncertainty=np.full(elevation.shape, 0.004, np.float32))
    out = map_window_from_message(fused_map_message(with_datum, factory, frame_id="odom"))
    assert out.datum_uncertainty is not None
    np.testing.assert_array_equal(out.datum_uncertainty, with_datum.datum_uncertainty)
    per_frame, uncertainty = _maps()
    with pytest.raises(MessageError, match="not a fused map"):
        map_window_from_message(elevation_grid_map(per_frame, uncertainty, GRID, factory, stamp_ns=1))
