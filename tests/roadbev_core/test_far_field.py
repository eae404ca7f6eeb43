"""The far field's physics on the RSRD rig: ground sampling, height precision, view, the cell."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.config import FarFieldConfig, GridSpec, StereoCamera
from roadbev_core.far_field import (
    cell_row_length,
    far_cell_size,
    farthest_road_in_view,
    height_sigma,
    road_sampling,
)
from roadbev_core.geometry import Attitude
from roadbev_lab.synth import RSRD_ATTITUDE

RIG = StereoCamera.rsrd_half()
PITCH = math.radians(RSRD_ATTITUDE["pitch_mean"])  # 19.1 deg
H = 1.1


def test_ground_sampling_and_height_precision_at_range() -> None:
    s = road_sampling(RIG, PITCH, H, [7.08, 11.0, 15.0])
    # about 5 image rows per metre of road at 15 m (a row covers 19 cm), 22 at the grid's far edge
    np.testing.assert_allclose(s.rows_per_m, [22.2, 9.6, 5.2], atol=0.1)
    np.testing.assert_allclose(s.row_length_m, 1.0 / s.rows_per_m)
    # a tenth of a pixel of disparity: h * Z * 0.1 / (fx B), 1.3 cm at 15 m; the same as h * 0.1 / d
    np.testing.assert_allclose(s.height_sigma_m, H * 0.1 / s.disparity_px, rtol=1e-9)
    assert s.height_sigma_m[-1] == pytest.approx(0.0134, abs=2e-4)
    np.testing.assert_allclose(s.disparity_px, RIG.fx * RIG.baseline / s.depth_m)
    np.testing.assert_allclose(s.cols_per_m, RIG.fx / s.depth_m)
    # the analytic derivative of the image row: fy h / ((x^2 + h^2) cos^2(atan(h / x) - pitch))
    x = s.distance_m
    analytic = RIG.fy * H / ((x**2 + H**2) * np.cos(np.arctan2(H, x) - PITCH) ** 2)
    np.testing.assert_allclose(s.rows_per_m, analytic, rtol=1e-5)
    assert s.in_view.tolist() == [True, True, False]  # 15 m is above the image at the mean pitch


def test_the_view_ends_where_the_top_row_meets_the_road() -> None:
    farthest = farthest_road_in_view(RIG, PITCH, H)
    assert farthest == pytest.approx(13.6, abs=0.05)
    assert road_sampling(RIG, PITCH, H, farthest - 0.01).in_view[0]
    assert not road_sampling(RIG, PITCH, H, farthest + 0.01).in_view[0]
    # 15 m needs a pitch of at most 18.7 deg; a camera looking above the horizon sees the road to the end
    assert farthest_road_in_view(RIG, math.radians(18.6), H) > 15.0 > farthest_road_in_view(RIG, math.radians(18.8), H)
    assert farthest_road_in_view(RIG, math.radians(5.0), H) == math.inf


def test_the_far_cell_is_one_image_row_at_the_middle_in_whole_cells() -> None:
    near = GridSpec()
    far = FarFieldConfig().grid(near)
    # one row covers 10.5 cm at 11.04 m; the next size that cuts 7.92 m by 1.92 m into whole cells is 12 cm
    assert road_sampling(RIG, PITCH, H, 0.5 * (far.x_min + far.x_max)).row_length_m[0] == pytest.approx(0.105, abs=1e-3)
    size = far_cell_size(RIG, PITCH, H, far.x_min, far.x_max, far.y_max - far.y_min)
    assert size == pytest.approx(0.12) == FarFieldConfig().resolution
    # a window no cell tiles is refused
    with pytest.raises(ValueError, match="whole cells"):
        far_cell_size(RIG, PITCH, H, 7.08, 15.0, 1.9137)


def test_every_cell_gets_its_row_length() -> None:
    far = FarFieldConfig().grid(GridSpec())
    lengths = cell_row_length(RIG, Attitude(0.0, PITCH), far)
    assert lengths.shape == far.shape and lengths.dtype == np.float32
    centre_col = far.n_cols // 2  # y = 0.02 m: straight ahead
    expected = road_sampling(RIG, PITCH, H, far.x_centres()).row_length_m
    np.testing.assert_allclose(lengths[:, centre_col], expected, rtol=2e-3)
    assert np.all(np.diff(lengths[:, centre_col]) < 0)  # row 0 is the farthest: the longest footprint


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="baseline"):
        road_sampling(StereoCamera(RIG.fx, RIG.fy, RIG.cx, RIG.cy, 0.0, RIG.width, RIG.height), PITCH, H, 10.0)
    with pytest.raises(ValueError, match="ahead"):
        road_sampling(RIG, PITCH, H, [5.0, -1.0])
    assert height_sigma(np.array([10.0]), H, RIG, 1.0)[0] == pytest.approx(H * 10.0 / (RIG.fx * RIG.baseline))
