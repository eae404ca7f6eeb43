from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import (
    Attitude,
    GeometryError,
    attitude_from_quaternion,
    attitude_from_rotation,
    camera_to_road,
    project_points,
    project_voxels,
    quaternion_to_rotation,
    ray_terms,
    road_to_camera,
    rotation_from_rpy,
    rsrd_camera_attitude,
    voxel_centres,
)

CAM = StereoCamera(fx=1000.0, fy=1000.0, cx=480.0, cy=264.0, baseline=0.12, width=960, height=528)


def _quat_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def test_level_camera_sees_road_point_on_the_expected_row() -> None:
    h, d = 1.1, 4.0
    cam_pt = road_to_camera(np.array([d, 0.0, 0.0]), Attitude(), h)
    np.testing.assert_allclose(cam_pt, [0.0, h, d], atol=1e-12)
    u, v, depth = project_points(cam_pt, CAM)
    assert v == pytest.approx(CAM.cy + CAM.fy * h / d)
    assert u == pytest.approx(CAM.cx)
    assert depth == pytest.approx(d)


def test_left_of_the_road_is_left_in_the_image() -> None:
    cam_pt = road_to_camera(np.array([4.0, 0.5, 0.0]), Attitude(), 1.1)
    u, _, _ = project_points(cam_pt, CAM)
    assert u < CAM.cx


def test_right_image_shifts_by_disparity() -> None:
    pt = np.array([0.3, 0.9, 5.0])
    ul, vl, z = project_points(pt, CAM)
    ur, vr, _ = project_points(pt, CAM, right=True)
    assert ul - ur == pytest.approx(CAM.fx * CAM.baseline / z)
    assert vl == pytest.approx(vr)


def test_pitched_down_camera_sees_far_points_higher() -> None:
    # Looking down by 10 deg moves the horizon up in the image (lower v) for a fixed road point.
    pt = np.array([5.0, 0.0, 0.0])
    _, v_level, _ = project_points(road_to_camera(pt, Attitude(), 1.1), CAM)
    _, v_down, _ = project_points(road_to_camera(pt, Attitude.from_degrees(0.0, 10.0), 1.1), CAM)
    assert v_down < v_level
    # The optical axis of a camera pitched by p hits the road at h / tan(p).
    p = math.radians(15.0)
    axis_hit = np.array([1.1 / math.tan(p), 0.0, 0.0])
    u, v, _ = project_points(road_to_camera(axis_hit, Attitude(0.0, p), 1.1), CAM)
    assert (u, v) == pytest.approx((CAM.cx, CAM.cy), abs=1e-9)


def test_road_camera_round_trip() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1, -1, -0.2], [8, 1, 0.2], size=(100, 3))
    att = Attitude.from_degrees(1.7, 18.3)
    back = camera_to_road(road_to_camera(pts, att, 1.1), att, 1.1)
    np.testing.assert_allclose(back, pts, atol=1e-12)


@pytest.mark.parametrize(("roll", "pitch", "yaw"), [(0.0, 0.0, 0.0), (2.0, 18.0, 45.0), (-1.5, -3.0, -170.0)])
def test_quaternion_attitude_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = _quat_from_rpy(*(math.radians(a) for a in (roll, pitch, yaw)))
    R = quaternion_to_rotation(*q)
    np.testing.assert_allclose(R, rotation_from_rpy(*(math.radians(a) for a in (roll, pitch, yaw))), atol=1e-12)
    att = attitude_from_quaternion(*q)
    assert att.degrees == pytest.approx((roll, pitch), abs=1e-9)


def test_imu_extrinsic_is_applied() -> None:
    level = _quat_from_rpy(0.0, 0.0, 0.3)
    att = attitude_from_quaternion(*level, imu_to_camera_rpy_deg=(0.0, 18.0, 0.0))
    assert att.degrees == pytest.approx((0.0, 18.0), abs=1e-9)


def test_bad_quaternions_are_rejected() -> None:
    with pytest.raises(GeometryError, match="non-finite"):
        quaternion_to_rotation(float("nan"), 0, 0, 1)
    with pytest.raises(GeometryError, match="unit length"):
        quaternion_to_rotation(0, 0, 0, 0.5)
    with pytest.raises(GeometryError, match="beyond"):
        Attitude(0.0, math.radians(95))


def test_attitude_ignores_yaw() -> None:
    R = rotation_from_rpy(0.02, 0.3, 2.5)
    assert attitude_from_rotation(R).degrees == pytest.approx((math.degrees(0.02), math.degrees(0.3)))


def test_voxel_centres_layout() -> None:
    g = GridSpec()
    v = voxel_centres(g)
    assert v.shape == (40, 164, 64, 3)
    assert v[0, 0, 0].tolist() == pytest.approx([7.065, 0.985, -0.195])
    assert v[-1, -1, -1].tolist() == pytest.approx([2.175, -0.905, 0.195])


def test_project_voxels_strides_and_integer_indices() -> None:
    g = GridSpec()
    att = Attitude.from_degrees(0.5, 19.0)
    full = project_voxels(g, CAM, att)
    half = project_voxels(g, CAM, att, stride=2)
    assert half.width == 480 and half.height == 264
    # Feature coordinate at stride 2: (u - 0.5) / 2.
    np.testing.assert_allclose(half.u, (full.u - 0.5) / 2, atol=1e-4)
    # The integer index is the feature cell holding the projection (nearest cell centre).
    assert np.abs(half.iu - half.u).max() <= 0.5 + 1e-3
    assert np.abs(half.iv - half.v).max() <= 0.5 + 1e-3
    assert full.inside.all()
    # Higher voxels of a column project higher in the image (smaller v) for a downward camera.
    assert np.all(np.diff(full.v, axis=0) < 0)


def test_integer_index_by_hand() -> None:
    # One voxel straight ahead on the optical axis of a camera pitched so the axis hits it.
    g = GridSpec(x_min=2.19, x_max=2.22, y_min=-0.015, y_max=0.015, z_min=-0.005, z_max=0.005)
    cam = StereoCamera(fx=500.0, fy=500.0, cx=10.2, cy=11.7, baseline=0.1, width=24, height=24)
    assert voxel_centres(g).reshape(-1, 3).tolist() == [pytest.approx([2.205, 0.0, 0.0])]
    att = Attitude(0.0, math.atan2(1.1, 2.205))
    proj = project_voxels(g, cam, att, stride=4)
    # Stride-4 cell 2 holds pixel centres 8..11, i.e. coordinates [7.5, 11.5): u = 10.2 is in
    # cell 2, v = 11.7 is nearest pixel 12 and so in cell 3.
    assert (proj.iu[0, 0, 0], proj.iv[0, 0, 0]) == (2, 3)
    assert proj.u[0, 0, 0] == pytest.approx((10.2 - 1.5) / 4, abs=1e-4)


def test_points_behind_camera_are_outside() -> None:
    g = GridSpec()
    proj = project_voxels(g, CAM, Attitude.from_degrees(0.0, -60.0))  # looking up: road behind the image
    assert not proj.inside.all()


def _rsrd_samples(rsrd: Path) -> list[dict[str, Any]]:
    out = []
    for f in sorted((rsrd / "sample_info").glob("*/*.pkl")):
        with f.open("rb") as fh:
            out.extend(pickle.load(fh))  # trusted: the pinned copies of the rsrd_dir fixture
    return out


def test_real_rsrd_rig_sees_the_whole_grid(rsrd_dir: Path) -> None:
    g = GridSpec()
    centres = voxel_centres(g)
    corners = centres[np.ix_([0, -1], [0, -1], [0, -1])].reshape(-1, 3)  # [8, 3]
    samples = _rsrd_samples(rsrd_dir)
    assert len(samples) == 1581
    calibs: dict[str, dict[str, Any]] = {}
    pitches = []
    for s in samples:
        day = s["time"][:8]
        if day not in calibs:
            with (rsrd_dir / f"calib_{day}_half.pkl").open("rb") as fh:
                calibs[day] = pickle.load(fh)
        c = calibs[day]
        cam = StereoCamera.from_K(c["K"], c["B"] / 1000.0, 960, 540).cropped(0, 0, 960, 528)
        att = rsrd_camera_attitude(s["roll"], s["pitch"], np.asarray(c["R"]))
        pitches.append(att.degrees[1])
        # A convex box in front of the camera projects inside the convex hull of its corners'
        # projections, so checking the voxel box's 8 corners covers every voxel.
        pts = road_to_camera(corners, att, g.base_height)
        for right in (False, True):
            u, v, z = project_points(pts, cam, right=right)
            assert np.all(z > 0) and np.all((u >= -0.5) & (u <= 959.5) & (v >= -0.5) & (v <= 527.5)), s["time"]
    # And the full voxel set for one sample per day, as a cross-check of the corner argument.
    for day, c in calibs.items():
        s = next(s for s in samples if s["time"].startswith(day))
        cam = StereoCamera.from_K(c["K"], c["B"] / 1000.0, 960, 540).cropped(0, 0, 960, 528)
        att = rsrd_camera_attitude(s["roll"], s["pitch"], np.asarray(c["R"]))
        assert project_voxels(g, cam, att, right=True).inside.all()
    # The camera looks ~2 deg further down than the LiDAR: 16-22 deg.
    assert min(pitches) > 15.5 and max(pitches) < 22.5


def test_a_pixels_ray_meets_the_road_point_that_projects_onto_it() -> None:
    attitude = Attitude(0.02, 0.3)
    base_height = 1.2
    road = np.array([[3.0, 0.4, 0.05], [6.5, -0.7, -0.02], [10.0, 0.0, 0.0]])  # [N, 3]
    u, v, depth = project_points(road_to_camera(road, attitude, base_height), CAM)
    terms = ray_terms(CAM, attitude, v, u)
    rays = terms.rays()  # [N, N, 3]: row i's term with column j's
    assert terms.per_col.shape == (3, 3) and terms.per_row.shape == (3, 3) and rays.shape == (3, 3, 3)
    for i in range(len(road)):
        point = np.array([0.0, 0.0, base_height]) + depth[i] * rays[i, i]
        np.testing.assert_allclose(point, road[i], atol=1e-9)
