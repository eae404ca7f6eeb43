"""The robustness sweep's perturbations act on what they name and nothing else."""

from __future__ import annotations

import numpy as np

from benchmarks.robustness import LEVELS, UNITS, perturb
from roadbev_core.config import StereoCamera
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude


def _frame() -> Frame:
    rows = np.repeat((np.arange(40, dtype=np.uint8) * 5)[:, None], 30, axis=1)  # [40, 30]: row r is 5 r
    image = np.ascontiguousarray(np.stack([rows] * 3, axis=2))
    camera = StereoCamera(100.0, 100.0, 15.0, 20.0, 0.5, 30, 40)
    return Frame(image, image.copy(), camera, Attitude(0.0, 0.0), 0)


def test_a_row_offset_moves_the_right_image_down_by_sub_pixels_and_leaves_the_left_alone() -> None:
    frame = _frame()
    moved = perturb(frame, "row_offset_px", 0.5, seed=0)
    assert moved.right is not None and frame.right is not None
    np.testing.assert_array_equal(moved.left, frame.left)
    # row r of the moved image holds row r - 0.5 of the original: 5 r - 2.5, rounded by uint8
    column = moved.right[5:35, 10, 0].astype(np.float64)
    np.testing.assert_allclose(column, 5 * np.arange(5, 35) - 2.5, atol=0.51)
    up = perturb(frame, "row_offset_px", -1.0, seed=0)
    assert up.right is not None
    np.testing.assert_array_equal(up.right[5:35, 10, 0], frame.right[6:36, 10, 0])


def test_the_zero_row_offset_is_the_clean_frame_and_every_level_has_a_unit() -> None:
    frame = _frame()
    assert perturb(frame, "row_offset_px", 0.0, seed=0) is frame
    assert 0.0 in LEVELS["row_offset_px"] and set(LEVELS) == set(UNITS)
