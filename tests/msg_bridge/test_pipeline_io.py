"""The node's output messages from a pipeline output: the far-field map beside the grid's."""

from __future__ import annotations

from typing import Any

import numpy as np

from msg_bridge import bag_factory
from msg_bridge.grid_map import grid_map_to_arrays
from msg_bridge.pipeline_io import output_messages
from roadbev_core.config import GridSpec, RoadbevConfig, StereoCamera
from roadbev_core.frame import Estimate, Frame
from roadbev_core.geometry import Attitude
from roadbev_core.pipeline import Pipeline

CAMERA = StereoCamera.rsrd_half().scaled(0.25)


class Ramp:
    """Height 1 mm per metre of x on any grid (the far-field one too)."""

    name = "ramp"
    needs_stereo = False
    far_field = True

    def __init__(self, grid: GridSpec, **_: Any) -> None:
        self.grid = grid

    def estimate(self, frame: Frame) -> Estimate:
        x = np.broadcast_to(self.grid.x_centres()[:, None], self.grid.shape)
        return Estimate((0.001 * x).astype(np.float32), np.full(self.grid.shape, 0.02, np.float32))


def _output(far: bool) -> tuple[Any, RoadbevConfig]:
    config = RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": far})
    pipeline = Pipeline(config, backend_factory=lambda name, grid, **o: Ramp(grid), configure_process=False)
    image = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
    return pipeline.process_frame(Frame(image, None, CAMERA, Attitude.from_degrees(0.0, 19.0), 7)), config


def test_the_far_field_map_has_the_grid_maps_layers_on_its_own_grid() -> None:
    output, config = _output(far=True)
    messages = output_messages(output, config, bag_factory(), with_points=False)
    assert messages.elevation_far is not None
    far = grid_map_to_arrays(messages.elevation_far, config.far_grid)
    assert far.grid == config.far_grid and far.stamp_ns == 7 and far.frame_id == config.topics.frame_id
    np.testing.assert_array_equal(far.layers["elevation"], output.far.elevation)
    np.testing.assert_array_equal(far.layers["uncertainty"], output.far.uncertainty)
    near = grid_map_to_arrays(messages.elevation)
    assert near.grid == config.grid and list(near.layers) == list(far.layers) == ["elevation", "uncertainty"]
    # off: no far-field map, the rest the same messages
    plain, plain_config = _output(far=False)
    without = output_messages(plain, plain_config, bag_factory(), with_points=False)
    assert without.elevation_far is None
    np.testing.assert_array_equal(grid_map_to_arrays(without.elevation).layers["elevation"], near.layers["elevation"])
