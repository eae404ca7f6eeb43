"""``sensor_msgs/CameraInfo`` <-> :class:`roadbev_core.config.StereoCamera`.

The pipeline works on rectified images, so the projection matrix ``P`` is what counts
(docs/interface/topics.md): K is taken from the left ``P``; the baseline from the right ``P`` as
``B = -P[3] / P[0]`` (ROS: ``Tx = -fx' * B``). The checks make sure the pair really is a
rectified stereo pair: equal sizes and equal rectified intrinsics, a left ``P`` without
translation, a right ``P`` shifted along x only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_int,
    buffer_view,
    field,
    make_header,
)
from roadbev_core.config import ConfigError, StereoCamera

__all__ = ["camera_info_from_stereo", "projection_matrix", "stereo_camera_from_camera_info"]

# Relative tolerance on the left/right rectified intrinsics being equal.
_INTRINSICS_RTOL = 1e-6


def projection_matrix(msg: Any, which: str = "CameraInfo") -> np.ndarray:
    """[3, 4] ``P`` of a CameraInfo, checked to be a usable rectified projection.

    Raises:
        MessageError: P with the wrong size, non-finite entries, zero or negative focal
            lengths, or a third row other than [0, 0, 1, 0].
    """
    p = buffer_view(field(msg, "p"), np.float64, f"{which}.p")
    if p.size != 12:
        raise MessageError(f"{which}.p must hold 12 numbers, got {p.size}")
    P = p.reshape(3, 4).astype(np.float64)
    if not np.all(np.isfinite(P)):
        raise MessageError(f"{which}.p has non-finite entries")
    if P[0, 0] <= 0 or P[1, 1] <= 0:
        raise MessageError(
            f"{which} has no usable focal length (P[0]={P[0, 0]}, P[5]={P[1, 1]}): "
            "is the camera calibrated?"
        )
    if not np.allclose(P[2], [0.0, 0.0, 1.0, 0.0]):
        raise MessageError(f"{which}.p third row must be [0 0 1 0] for rectified images, got {P[2]}")
    if P[0, 1] != 0.0 or P[1, 0] != 0.0:
        raise MessageError(f"{which}.p has skew, which rectified images do not")
    return P


def _image_size(msg: Any, which: str) -> tuple[int, int]:
    width = as_int(field(msg, "width"), f"{which}.width")
    height = as_int(field(msg, "height"), f"{which}.height")
    if width == 0 or height == 0:
        raise MessageError(f"{which} has an empty image size {width}x{height}")
    for axis in ("binning_x", "binning_y"):
        binning = as_int(field(msg, axis), f"{which}.{axis}")
        if binning > 1:
            raise MessageError(f"{which}.{axis}={binning}: binned images are not supported")
    roi = field(msg, "roi")
    if as_int(field(roi, "width"), f"{which}.roi.width") or as_int(
        field(roi, "height"), f"{which}.roi.height"
    ):
        raise MessageError(f"{which} has a region of interest set, which is not supported")
    return width, height


def stereo_camera_from_camera_info(left: Any, right: Any | None = None) -> StereoCamera:
    """The rectified rig described by the left (and right) CameraInfo.

    Args:
        left: the left camera's CameraInfo (the reference camera).
        right: the right camera's CameraInfo, or None for a mono rig (baseline 0).

    Raises:
        MessageError: zero focal length, a translated left P, a right camera that is not the
            left one shifted to the right along x (different size or intrinsics, vertical shift,
            zero or negative baseline).
    """
    P_left = projection_matrix(left, "left CameraInfo")
    width, height = _image_size(left, "left CameraInfo")
    if P_left[0, 3] != 0.0 or P_left[1, 3] != 0.0:
        raise MessageError(
            f"left CameraInfo.p has a translation ({P_left[0, 3]}, {P_left[1, 3]}); the left "
            "camera must be the reference of the rectified pair"
        )
    baseline = 0.0
    if right is not None:
        P_right = projection_matrix(right, "right CameraInfo")
        if _image_size(right, "right CameraInfo") != (width, height):
            raise MessageError(
                f"left ({width}x{height}) and right ({right.width}x{right.height}) image sizes differ"
            )
        intrinsics_left = P_left[:2, :3]
        intrinsics_right = P_right[:2, :3]
        if not np.allclose(intrinsics_left, intrinsics_right, rtol=_INTRINSICS_RTOL, atol=1e-9):
            raise MessageError(
                "left and right CameraInfo.p have different rectified intrinsics: the images "
                f"are not a rectified pair (left {intrinsics_left.tolist()}, "
                f"right {intrinsics_right.tolist()})"
            )
        if P_right[1, 3] != 0.0:
            raise MessageError(f"right CameraInfo.p has a vertical shift P[7]={P_right[1, 3]}")
        # rounded to the picometre so that B -> P -> B gives B back exactly (fx*B/fx is not exact)
        baseline = round(-P_right[0, 3] / P_right[0, 0], 12)
        if not math.isfinite(baseline) or baseline <= 0:
            raise MessageError(
                f"right CameraInfo.p gives baseline {baseline + 0.0:.6g} m (B = -P[3]/P[0]); it must be "
                "positive (the right camera lies to the right of the left one)"
            )
    try:
        return StereoCamera.from_K(P_left[:, :3], baseline, width, height)
    except ConfigError as exc:
        raise MessageError(f"CameraInfo: {exc}") from None


def camera_info_from_stereo(
    camera: StereoCamera,
    factory: MessageFactory,
    *,
    right: bool = False,
    stamp_ns: int = 0,
    frame_id: str = "",
) -> Any:
    """The CameraInfo of the left (or right) rectified camera of ``camera``.

    K = the rectified intrinsics, D = 0 ("plumb_bob"), R = identity, P = [K | 0] for the
    left camera and P = [K | (-fx * B, 0, 0)] for the right one.
    """
    if right and camera.baseline <= 0:
        raise MessageError("a right CameraInfo needs a stereo baseline > 0")
    K = camera.K
    P = np.zeros((3, 4))
    P[:, :3] = K
    if right:
        P[0, 3] = -camera.fx * camera.baseline
    return factory.new(
        "sensor_msgs/msg/CameraInfo",
        header=make_header(factory, stamp_ns, frame_id),
        height=int(camera.height),
        width=int(camera.width),
        distortion_model="plumb_bob",
        d=factory.sequence(np.zeros(5, dtype=np.float64)),
        k=K.reshape(-1).copy(),
        r=np.eye(3).reshape(-1),
        p=P.reshape(-1),
    )
