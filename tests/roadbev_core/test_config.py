from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from roadbev_core.config import ConfigError, GridSpec, StereoCamera, grid_preset
from roadbev_core.config.grid import whole_cells_end


def test_default_grid_matches_contract() -> None:
    g = GridSpec()
    assert g.shape == (164, 64)
    assert (g.n_z, g.n_classes) == (40, 80)
    assert g.x_centres()[0] == pytest.approx(7.08 - 0.015)  # row 0 is the farthest
    assert g.x_centres()[-1] == pytest.approx(2.16 + 0.015)
    assert g.y_centres()[0] == pytest.approx(1.00 - 0.015)  # col 0 is the leftmost
    assert g.y_centres()[-1] == pytest.approx(-0.92 + 0.015)
    assert g.class_centres()[0] == pytest.approx(-0.1975)
    assert g.class_centres()[-1] == pytest.approx(0.1975)
    assert g.centre == pytest.approx((4.62, 0.04))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"resolution": -0.03}, "resolution must be positive"),
        ({"resolution": 0.07}, "not a whole number"),
        ({"x_max": 1.0}, "inverted"),
        ({"x_min": -0.5, "x_max": 4.54}, "ahead of the camera"),
        ({"base_height": 0.1}, "below the camera"),
        ({"z_resolution": float("nan")}, "finite"),
        ({"class_resolution": 0.003}, "elevation classes"),
    ],
)
def test_grid_validation_gives_reasons(overrides: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        GridSpec().with_overrides(**overrides)


def test_unknown_grid_parameter_is_rejected() -> None:
    with pytest.raises(ConfigError, match="unknown grid parameter"):
        GridSpec().with_overrides(cell=0.03)
    with pytest.raises(ConfigError, match="unknown grid preset"):
        grid_preset("huge")


def test_cell_index_is_inverse_of_centres() -> None:
    g = GridSpec()
    xx, yy = np.meshgrid(g.x_centres(), g.y_centres(), indexing="ij")
    rows, cols, inside = g.cell_index(xx.ravel(), yy.ravel())
    assert inside.all()
    np.testing.assert_array_equal(rows, np.repeat(np.arange(g.n_rows), g.n_cols))
    np.testing.assert_array_equal(cols, np.tile(np.arange(g.n_cols), g.n_rows))
    _, _, inside = g.cell_index(np.array([2.0, 7.2, 4.0]), np.array([0.0, 0.0, 1.2]))
    assert not inside.any()


def test_bands_split_rows_near_to_far() -> None:
    bands = GridSpec().band_of_rows(15)
    assert bands[-1] == 0 and bands[0] == 14  # last row is nearest
    assert np.all(np.diff(bands) <= 0)
    counts = np.bincount(bands)
    assert counts.min() >= 10 and counts.max() <= 11


def test_grid_round_trips_through_dict_and_scales() -> None:
    g = GridSpec(base_height=1.3)
    assert GridSpec.from_dict(g.to_dict()) == g
    half = g.scaled(2)
    assert half.shape == (82, 32) and half.base_height == 1.3


def test_camera_resize_keeps_pixel_centres() -> None:
    cam = StereoCamera.rsrd_half()
    assert cam.size == (960, 528)
    small = cam.scaled(0.5)
    assert small.size == (480, 264)
    # A ray through pixel centre u maps to (u + 0.5) * s - 0.5 after resizing.
    u = 100.0
    x_over_z = (u - cam.cx) / cam.fx
    assert small.fx * x_over_z + small.cx == pytest.approx((u + 0.5) * 0.5 - 0.5)
    assert StereoCamera.from_dict(cam.to_dict()) == cam


def test_camera_validation() -> None:
    with pytest.raises(ConfigError, match="focal"):
        StereoCamera(0.0, 1.0, 1.0, 1.0, 0.1, 10, 10)
    with pytest.raises(ConfigError, match="baseline"):
        StereoCamera(1.0, 1.0, 1.0, 1.0, -0.1, 10, 10)
    with pytest.raises(ConfigError, match="does not fit"):
        StereoCamera.rsrd_half().cropped(0, 0, 961, 528)


def test_whole_cells_end_keeps_a_fitting_end_and_moves_another_to_the_next_whole_cell() -> None:
    assert whole_cells_end(7.08, 15.0, 0.12) == 15.0  # 66 cells: kept to the bit
    assert whole_cells_end(7.08, 15.0, 0.1) == 15.08  # 79.2 cells -> 80
    assert whole_cells_end(0.0, 1.00001, 0.5) == 1.00001  # within the grid's tolerance of whole
    assert whole_cells_end(-0.92, 1.0, 0.5) == 1.08
