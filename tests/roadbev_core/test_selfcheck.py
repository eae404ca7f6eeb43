from __future__ import annotations

import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame
from roadbev_core.geometry import Attitude
from roadbev_core.selfcheck import self_check, vertical_offset_px

GRID = GridSpec()
CAMERA = StereoCamera.rsrd_half().scaled(0.5)


def _textured(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    import cv2

    noise = rng.normal(128, 40, (CAMERA.height, CAMERA.width)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 1.2), 0, 255).astype(np.uint8)


def _pair(vertical_shift: int = 0, texture: bool = True) -> Frame:
    left = _textured() if texture else np.full((CAMERA.height, CAMERA.width), 120, np.uint8)
    right = np.roll(left, -6, axis=1)  # a disparity of 6 px
    if vertical_shift:
        right = np.roll(right, vertical_shift, axis=0)
    return Frame(left, right, CAMERA, Attitude.from_degrees(0.0, 18.0))


def _estimate(value: float | None, share: float = 1.0) -> Estimate:
    elevation = np.full(GRID.shape, np.nan, np.float32)
    rows = int(share * GRID.n_rows)
    if value is not None:
        elevation[:rows] = value
    return Estimate(elevation, np.where(np.isfinite(elevation), 0.005, np.nan).astype(np.float32))


@pytest.mark.parametrize("shift", [-3, 0, 2])
def test_vertical_offset_is_measured_despite_disparity(shift: int) -> None:
    frame = _pair(shift)
    assert frame.right is not None
    assert vertical_offset_px(frame.left, frame.right) == pytest.approx(shift, abs=0.3)


def test_good_coverage_is_ok_without_causes() -> None:
    check = self_check(_estimate(0.0), _pair(), GRID)
    assert check.ok and check.causes == () and check.coverage_pct == pytest.approx(100.0)
    assert check.message == "coverage 100.0 %"


def test_zero_coverage_on_a_textureless_pair_says_no_texture() -> None:
    check = self_check(_estimate(None), _pair(texture=False), GRID)
    assert not check.ok and check.coverage_pct == 0.0
    assert any("no texture" in c for c in check.causes)


def test_low_coverage_on_a_shifted_pair_says_bad_rectification() -> None:
    check = self_check(_estimate(0.0, share=0.1), _pair(vertical_shift=3), GRID)
    assert not check.ok
    assert any("bad rectification" in c and "+3." in c for c in check.causes), check.causes


def test_a_road_far_from_z0_says_base_height() -> None:
    check = self_check(_estimate(-0.15, share=0.2), _pair(), GRID)
    assert not check.ok and check.plane_offset_m == pytest.approx(-0.15, abs=1e-3)
    assert check.causes and "base_height inconsistent" in check.causes[0]
    # nothing matched although texture and rectification are fine: base_height is the suspect
    nothing = self_check(_estimate(None), _pair(), GRID)
    assert nothing.causes and "base_height" in nothing.causes[0]
    assert "coverage 0.0 % (low)" in nothing.message
