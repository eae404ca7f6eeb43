"""Elevation -> PointCloud2 (x, y, z, uncertainty) and reading clouds back."""

from __future__ import annotations

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory
from msg_bridge.point_cloud import elevation_point_cloud, point_cloud_to_array
from roadbev_core.config import GridSpec

GRID = GridSpec(resolution=0.06)


def test_one_point_per_estimated_cell_at_the_cell_centre(factory: MessageFactory) -> None:
    elevation = np.full(GRID.shape, np.nan, np.float32)
    uncertainty = np.full(GRID.shape, 0.01, np.float32)
    elevation[0, 0], elevation[10, 5], elevation[-1, -1] = 0.05, -0.02, 0.0
    msg = elevation_point_cloud(elevation, uncertainty, GRID, factory, stamp_ns=9)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 3, 16, 48)
    assert msg.header.frame_id == "roadbev_road" and msg.is_dense
    names, points = point_cloud_to_array(msg)
    assert names == ("x", "y", "z", "uncertainty")
    expected = [
        [GRID.x_max - 0.03, GRID.y_max - 0.03, 0.05, 0.01],
        [GRID.x_max - 10.5 * 0.06, GRID.y_max - 5.5 * 0.06, -0.02, 0.01],
        [GRID.x_min + 0.03, GRID.y_min + 0.03, 0.0, 0.01],
    ]
    np.testing.assert_allclose(points, expected, atol=1e-6)


def test_empty_map_gives_an_empty_cloud(factory: MessageFactory) -> None:
    msg = elevation_point_cloud(np.full(GRID.shape, np.nan), None, GRID, factory, stamp_ns=0)
    _names, points = point_cloud_to_array(msg)
    assert points.shape == (0, 4)


def test_malformed_clouds_raise_message_error() -> None:
    factory = bag_factory()
    msg = elevation_point_cloud(np.zeros(GRID.shape), None, GRID, factory, stamp_ns=0)
    msg.data = msg.data[:-1]
    with pytest.raises(MessageError, match="less than height\\*row_step"):
        point_cloud_to_array(msg)
    msg = elevation_point_cloud(np.zeros(GRID.shape), None, GRID, factory, stamp_ns=0)
    msg.point_step = 8
    with pytest.raises(MessageError, match="does not fit"):
        point_cloud_to_array(msg)
    msg = elevation_point_cloud(np.zeros(GRID.shape), None, GRID, factory, stamp_ns=0)
    msg.fields[1].datatype = 8
    with pytest.raises(MessageError, match="not a single float32"):
        point_cloud_to_array(msg)
    with pytest.raises(MessageError, match="the grid is"):
        elevation_point_cloud(np.zeros((2, 2)), None, GRID, factory, stamp_ns=0)
