"""Where road-frame points fall in the stereo images, as ``grid_sample`` coordinates (torch).

The per-frame hot path of every backend that samples images at road-frame points (the BEV
sweep, the models' voxel query): road-frame samples on a separable grid (x by row, y by column,
heights per layer or per sample) projected into the left and right rectified images through the
frames of :mod:`roadbev_core.geometry`, in float32 and without building a [..., 3] point array.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from roadbev_core.config import StereoCamera
from roadbev_core.geometry import Attitude, optical_from_road_rotation

__all__ = ["SampleCoordinates", "sample_coordinates"]


class SampleCoordinates(NamedTuple):
    """coords [2, K, Rs, Cs, 2]: (u, v) of the left / right image in grid_sample's [-1, 1]
    (align_corners=True: pixel centres 0 and W - 1 at -1 and +1); inv_depth [K, Rs, Cs] (1/m,
    negative behind the camera)."""

    coords: torch.Tensor
    inv_depth: torch.Tensor

    def inside(self, camera: StereoCamera) -> torch.Tensor:
        """[2, K, Rs, Cs] bool: in front of the camera and within half a pixel of the image
        (as ``geometry.project_voxels``), per image (left, right)."""
        slack_u = 1.0 + 1.0 / (camera.width - 1)  # half a pixel beyond the outer pixel centres
        slack_v = 1.0 + 1.0 / (camera.height - 1)
        within = (self.coords[..., 0].abs() <= slack_u) & (self.coords[..., 1].abs() <= slack_v)
        return within & (self.inv_depth > 0)


def sample_coordinates(
    x: torch.Tensor,
    y: torch.Tensor,
    heights: torch.Tensor,
    camera: StereoCamera,
    attitude: Attitude,
    base_height: float,
) -> SampleCoordinates:
    """Normalised image coordinates of the road-frame samples (x[i], y[j], heights[k, i, j]).

    Args:
        x: [Rs] longitudinal positions (m) of the sample rows.
        y: [Cs] lateral positions (m) of the sample columns.
        heights: road-frame z (m), [K, 1, 1] (horizontal planes, the cheap case) or [K, Rs, Cs].
        camera: the rectified stereo rig of the images to sample.
        attitude: the left camera's roll / pitch.
        base_height: the road frame's origin below the left camera (m).
    """
    R = torch.tensor(optical_from_road_rotation(attitude), dtype=torch.float32)  # road -> optical
    xs = x.to(torch.float32)[None, :, None]  # [1, Rs, 1]
    ys = y.to(torch.float32)[None, None, :]  # [1, 1, Cs]
    dz = heights - base_height
    w, h = camera.width, camera.height
    # u_norm = 2 u / (W - 1) - 1 with u = fx X / Z + cx (align_corners=True: centres at -1, +1).
    ax, bx = 2.0 * camera.fx / (w - 1), 2.0 * camera.cx / (w - 1) - 1.0
    ay, by = 2.0 * camera.fy / (h - 1), 2.0 * camera.cy / (h - 1) - 1.0
    # Camera coordinates are sums of separable terms ([K, Rs, 1] + [1, 1, Cs] for planes),
    # pre-scaled so that one multiply by 1/depth gives the normalised coordinate.
    inv_depth = ((R[2, 0] * xs + R[2, 2] * dz) + R[2, 1] * ys).reciprocal_()  # [K, Rs, Cs]
    coords = torch.empty(2, *inv_depth.shape, 2)
    u_left, v_norm = coords[0, ..., 0], coords[0, ..., 1]
    torch.mul((ax * R[0, 0]) * xs + (ax * R[0, 2]) * dz, inv_depth, out=u_left)
    u_left.add_(inv_depth * ((ax * R[0, 1]) * ys)).add_(bx)
    torch.mul((ay * R[1, 0]) * xs + (ay * R[1, 2]) * dz, inv_depth, out=v_norm)
    v_norm.add_(inv_depth * ((ay * R[1, 1]) * ys)).add_(by)
    # Right camera: its centre is `baseline` along the left's +x, so x' = x - B.
    torch.add(u_left, inv_depth, alpha=-ax * camera.baseline, out=coords[1, ..., 0])
    coords[1, ..., 1] = v_norm
    return SampleCoordinates(coords, inv_depth)
