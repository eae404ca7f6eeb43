"""CameraInfo <-> StereoCamera: K from the left P, B = -P[3]/P[0] of the right, rectification checks."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory
from msg_bridge.camera_info import camera_info_from_stereo, stereo_camera_from_camera_info
from roadbev_core.config import StereoCamera

RIG = StereoCamera.rsrd_half()


def test_round_trip_of_the_rsrd_rig(factory: MessageFactory) -> None:
    left = camera_info_from_stereo(RIG, factory, stamp_ns=5, frame_id="left")
    right = camera_info_from_stereo(RIG, factory, right=True, stamp_ns=5, frame_id="right")
    assert right.p[3] == pytest.approx(-RIG.fx * RIG.baseline)
    camera = stereo_camera_from_camera_info(left, right)
    assert camera == RIG
    assert camera.baseline == pytest.approx(0.118809, abs=1e-12)


def test_mono_rig_has_zero_baseline(factory: MessageFactory) -> None:
    camera = stereo_camera_from_camera_info(camera_info_from_stereo(RIG, factory))
    assert camera.baseline == 0.0
    assert (camera.fx, camera.cx, camera.size) == (RIG.fx, RIG.cx, RIG.size)


def test_K_comes_from_P_not_from_the_raw_K() -> None:
    factory = bag_factory()
    left = camera_info_from_stereo(RIG, factory)
    left.k = np.array([900.0, 0, 400, 0, 900, 300, 0, 0, 1])  # the unrectified camera's K
    assert stereo_camera_from_camera_info(left).fx == RIG.fx


def _pair() -> tuple[Any, Any]:
    factory = bag_factory()
    return camera_info_from_stereo(RIG, factory), camera_info_from_stereo(RIG, factory, right=True)


@pytest.mark.parametrize(
    ("side", "index", "value", "message"),
    [
        ("left", 0, 0.0, "no usable focal length"),
        ("left", 5, 0.0, "no usable focal length"),
        ("left", 3, -10.0, "left CameraInfo.p has a translation"),
        ("right", 3, 0.0, "baseline 0"),
        ("right", 3, 50.0, "baseline -0.0497"),
        ("right", 7, 3.0, "vertical shift"),
        ("right", 2, 400.0, "different rectified intrinsics"),
        ("left", 10, 0.5, "third row"),
        ("left", 1, 0.2, "skew"),
        ("right", 0, np.nan, "non-finite"),
    ],
)
def test_bad_projection_matrices(side: str, index: int, value: float, message: str) -> None:
    left, right = _pair()
    msg = left if side == "left" else right
    p = np.array(msg.p, dtype=np.float64)
    p[index] = value
    msg.p = p
    with pytest.raises(MessageError, match=message):
        stereo_camera_from_camera_info(left, right)


def test_size_binning_and_roi_checks() -> None:
    left, right = _pair()
    right.width = 100
    with pytest.raises(MessageError, match="sizes differ"):
        stereo_camera_from_camera_info(left, right)
    left, right = _pair()
    left.height = 0
    with pytest.raises(MessageError, match="empty image size"):
        stereo_camera_from_camera_info(left, right)
    left, right = _pair()
    left.binning_x = 2
    with pytest.raises(MessageError, match="binned"):
        stereo_camera_from_camera_info(left, right)
    left, right = _pair()
    right.roi.width = 10
    with pytest.raises(MessageError, match="region of interest"):
        stereo_camera_from_camera_info(left, right)
    left, _ = _pair()
    left.p = np.zeros(9)
    with pytest.raises(MessageError, match="12 numbers"):
        stereo_camera_from_camera_info(left)


def test_a_right_info_needs_a_baseline(factory: MessageFactory) -> None:
    mono = StereoCamera(100.0, 100.0, 50.0, 40.0, 0.0, 100, 80)
    with pytest.raises(MessageError, match="baseline"):
        camera_info_from_stereo(mono, factory, right=True)
