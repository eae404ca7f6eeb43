"""The renderer is geometrically right: pixel convention, parallax, occlusion, stereo consistency."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, project_points, road_to_camera
from roadbev_lab.synth import RoadConfig, SynthError, make_sample
from roadbev_lab.synth.drive import DriveSample, LidarConfig
from roadbev_lab.synth.heightfield import SpeedBump
from roadbev_lab.synth.render import (
    CameraPose,
    ego_shadow,
    ray_directions,
    render_stereo,
    render_view,
    sensor_image,
)
from roadbev_lab.synth.scene import Scene, build_scene
from roadbev_lab.synth.texture import remap_points
from tests.roadbev_core._frames import right_of

RIG = StereoCamera.rsrd_half()
GRID = GridSpec()


def _flat_scene(features: list[tuple[str, float, float]] | None = None, **road: Any) -> Scene:
    cfg = RoadConfig(road_class="A", roughness_scale=0.0, features=(), cross_slope=0.0, **road)
    return build_scene(cfg, 0, (-4.0, 36.0), features or [])


def test_rays_go_through_pixel_centres_at_integer_coordinates() -> None:
    """A hit point rendered for pixel (i, j) projects back to (i, j) (not i + 0.5)."""
    cam = RIG.scaled(0.25)
    scene = _flat_scene()
    att = Attitude.from_degrees(1.5, 18.0)
    pose = CameraPose(0.0, 0.1, GRID.base_height, att, yaw=0.03)  # heading slightly off the road axis
    view = render_view(scene, cam, pose)
    jj, ii = np.nonzero(np.isfinite(view.depth))
    assert ii.size > 0.9 * view.depth.size  # pitched down: almost all road
    dirs = ray_directions(cam, pose).reshape(cam.height, cam.width, 3)
    world = np.array([pose.x, pose.y, pose.z]) + view.depth[jj, ii, None] * dirs[jj, ii]
    road = pose.world_to_road(world, GRID.base_height)
    assert np.abs(road[:, 2]).max() < 1e-4  # on the flat road plane
    u, v, depth = project_points(road_to_camera(road, att, GRID.base_height), cam)
    np.testing.assert_allclose(u, ii, atol=1e-3)
    np.testing.assert_allclose(v, jj, atol=1e-3)
    np.testing.assert_allclose(depth, view.depth[jj, ii], rtol=1e-5)


def test_level_camera_sees_the_road_on_the_textbook_row() -> None:
    """v = cy + fy * h / d for a level camera at height h (pixel centres at integers)."""
    cam = StereoCamera(fx=400.0, fy=400.0, cx=99.0, cy=40.0, baseline=0.12, width=200, height=120)
    view = render_view(_flat_scene(), cam, CameraPose(0.0, 0.0, 1.1, Attitude(0.0, 0.0)))
    for row in (60, 80, 119):
        expected = 400.0 * 1.1 / (row - 40.0)  # distance d for that row
        assert view.depth[row, 99] == pytest.approx(expected, rel=1e-5)
    assert np.isinf(view.depth[:40]).all()  # at and above the horizon: sky


def test_right_view_has_the_disparity_of_the_rig() -> None:
    cam = RIG.scaled(0.25)
    pose = CameraPose(0.0, 0.0, GRID.base_height, Attitude.from_degrees(0.0, 19.0))
    left, right = render_stereo(_flat_scene(), cam, pose)
    assert right is not None
    # Flat road: a row's depth is the same in both views, shifted by the disparity fx B / Z.
    row = cam.height - 10
    z = float(left.depth[row, cam.width // 2])
    shift = cam.fx * cam.baseline / z
    u = np.arange(20, cam.width - 20, dtype=np.float64)
    lum_l = left.radiance[row, 20:-20].mean(axis=1)
    lum_right = right.radiance[row].mean(axis=1)

    def err(offset: float) -> float:
        return float(np.abs(lum_l - np.interp(u - shift + offset, np.arange(cam.width), lum_right)).mean())

    # the best match is at the rig's disparity fx B / Z (the right camera is where the rig says;
    # the absolute pixel convention is checked by the two tests above)
    offsets = np.linspace(-1.0, 1.0, 41)
    best = offsets[int(np.argmin([err(o) for o in offsets]))]
    assert abs(best) <= 0.1
    assert err(0.0) < min(err(-0.5), err(0.5))


def test_a_bump_occludes_the_road_behind_it() -> None:
    cam = RIG.scaled(0.25)
    pose = CameraPose(0.0, 0.0, GRID.base_height, Attitude.from_degrees(0.0, 10.0))
    flat = render_view(_flat_scene(), cam, pose)
    scene = _flat_scene()
    bump = SpeedBump(x=6.0, y=0.0, length=0.3, height=0.10, width=4.0, profile="circular")
    bump.apply(scene.canvas, np.random.default_rng(0))
    scene.displacement_range = (-1e-3, 0.101)
    bumpy = render_view(scene, cam, pose)
    centre = cam.width // 2
    dirs = ray_directions(cam, pose).reshape(cam.height, cam.width, 3)
    hit_x = bumpy.depth[:, centre] * dirs[:, centre, 0]
    flat_x = flat.depth[:, centre] * dirs[:, centre, 0]
    # Rays that would meet the plane just behind the bump stop on its front face instead...
    end = bump.x + bump.length / 2
    behind = (flat_x > end) & (flat_x < end + 0.3)
    assert behind.sum() >= 2
    assert np.all(hit_x[behind] < bump.x + 0.02)
    # ... so the road right behind the bump is seen by no pixel (a jump in hit distance).
    order = np.sort(hit_x[np.isfinite(hit_x)])
    gaps = np.diff(order)
    assert gaps[np.searchsorted(order, bump.x) - 1 :].max() > 0.25
    # Rays that pass well in front of the bump are unaffected.
    before = flat_x < bump.x - 0.3
    np.testing.assert_allclose(hit_x[before], flat_x[before], atol=1e-4)


def test_sensor_model_gain_noise_and_jpeg() -> None:
    rng = np.random.default_rng(0)
    radiance = np.full((32, 48, 3), 0.2, np.float32)
    clean = sensor_image(radiance, exposure=1.0, gain=1.0, noise_sigma=0.0, blur_sigma_px=0.0, rng=rng)
    assert clean.dtype == np.uint8 and clean.shape == (32, 48, 3)
    assert int(clean[0, 0, 0]) == round(255 * 0.2 ** (1 / 2.2))
    brighter = sensor_image(radiance, exposure=1.0, gain=1.1, noise_sigma=0.0, blur_sigma_px=0.0, rng=rng)
    assert brighter.mean() > clean.mean()
    noisy = sensor_image(radiance, exposure=1.0, gain=1.0, noise_sigma=3.0, blur_sigma_px=0.0, rng=rng)
    assert 2.0 < float(noisy.astype(np.float64).std()) < 5.0
    jpeg = sensor_image(radiance, exposure=1.0, gain=1.0, noise_sigma=3.0, blur_sigma_px=0.0, rng=rng, jpeg_quality=50)
    assert jpeg.shape == clean.shape and not np.array_equal(jpeg, noisy)


def test_right_view_needs_a_baseline() -> None:
    mono = StereoCamera(fx=100.0, fy=100.0, cx=10.0, cy=10.0, baseline=0.0, width=20, height=20)
    with pytest.raises(SynthError, match="baseline"):
        render_view(_flat_scene(), mono, CameraPose(0.0, 0.0, 1.1, Attitude()), right=True)


def _photometric_errors(sample: DriveSample, camera: StereoCamera, shifts: list[float], near_x: float) -> list[float]:
    """Mean |left - right| grey level at the LiDAR points moved up by each shift (metres)."""
    left = np.ascontiguousarray(sample.frame.left.astype(np.float32).mean(axis=2))
    right = np.ascontiguousarray(right_of(sample.frame).astype(np.float32).mean(axis=2))
    pts = sample.points_road.astype(np.float64)
    pts = pts[pts[:, 0] < near_x]
    out = []
    for dz in shifts:
        p = pts + np.array([0.0, 0.0, dz])
        cam_pts = road_to_camera(p, sample.frame.attitude, GRID.base_height)
        ul, vl, _ = project_points(cam_pts, camera)
        ur, vr, _ = project_points(cam_pts, camera, right=True)
        a = remap_points(left, ul, vl, cv2.BORDER_REPLICATE)
        b = remap_points(right, ur, vr, cv2.BORDER_REPLICATE)
        out.append(float(np.mean(np.abs(a - b))))
    return out


def _stereo_sample(seed: int, features: tuple[str, ...], camera: StereoCamera, **sensor: Any) -> DriveSample:
    road = RoadConfig(road_class="C", features=features, **sensor)
    return make_sample(seed, camera=camera, road=road, lidar=LidarConfig(spacing_m=0.015))


@pytest.fixture(scope="module")
def clean_sample() -> DriveSample:
    # the real half-resolution rig (960 x 528); no sensor noise, gain mismatch or JPEG
    return _stereo_sample(11, ("pothole", "speed_bump"), RIG, noise_sigma=0.0, gain_mismatch=0.0)


def test_warping_through_true_heights_beats_heights_off_by_2cm(clean_sample: DriveSample) -> None:
    """The issue's test: right warped into left through the true surface matches far better
    than through the surface shifted by +-2 cm (the renderer's parallax is right)."""
    err_down, err_true, err_up = _photometric_errors(clean_sample, RIG, [-0.02, 0.0, 0.02], near_x=4.5)
    assert err_true < 0.4 * min(err_down, err_up)
    # over the whole grid too (2 cm is under 0.2 px of disparity at its far end)
    err_down, err_true, err_up = _photometric_errors(clean_sample, RIG, [-0.02, 0.0, 0.02], near_x=GRID.x_max)
    assert err_true < 0.7 * min(err_down, err_up)


@pytest.fixture(scope="module")
def noisy_sample() -> DriveSample:
    return _stereo_sample(
        12, ("hump", "pothole"), RIG.scaled(0.5), noise_sigma=1.5, gain_mismatch=0.04, jpeg_quality=90
    )


def test_true_heights_win_even_with_sensor_noise_and_gain_mismatch(noisy_sample: DriveSample) -> None:
    errs = _photometric_errors(noisy_sample, RIG.scaled(0.5), [-0.02, -0.01, 0.0, 0.01, 0.02], near_x=4.5)
    assert int(np.argmin(errs)) == 2


def test_a_rectification_residual_moves_the_right_image_down_and_nothing_else() -> None:
    """With ``row_offset_px`` the right image matches the left through the true heights best
    when it is read that many rows lower; the left image and the labels are the perfectly
    rectified render's."""
    cam = RIG.scaled(0.5)
    clean = _stereo_sample(13, ("pothole",), cam, noise_sigma=0.0, gain_mismatch=0.0)
    moved = _stereo_sample(13, ("pothole",), cam, noise_sigma=0.0, gain_mismatch=0.0, row_offset_px=0.5)
    np.testing.assert_array_equal(moved.frame.left, clean.frame.left)
    np.testing.assert_array_equal(moved.truth.elevation, clean.truth.elevation)
    left = np.ascontiguousarray(moved.frame.left.astype(np.float32).mean(axis=2))
    right = np.ascontiguousarray(right_of(moved.frame).astype(np.float32).mean(axis=2))
    pts = moved.points_road.astype(np.float64)
    cam_pts = road_to_camera(pts[pts[:, 0] < 4.5], moved.frame.attitude, GRID.base_height)
    ul, vl, _ = project_points(cam_pts, cam)
    ur, vr, _ = project_points(cam_pts, cam, right=True)
    a = remap_points(left, ul, vl, cv2.BORDER_REPLICATE)
    errs = [float(np.mean(np.abs(a - remap_points(right, ur, vr + dv, cv2.BORDER_REPLICATE)))) for dv in (0.0, 0.5)]
    assert errs[1] < 0.8 * errs[0]


def test_glints_one_camera_sees_alone_are_texture_the_other_cannot_match() -> None:
    """Glints with a wide specular lobe (both cameras see them) keep the true heights the best
    match; with a narrow lobe each camera sees its own, which raises the left-right difference
    there. The labels never change."""
    cam = RIG.scaled(0.5)
    lambertian = _stereo_sample(14, ("pothole",), cam, noise_sigma=0.0, gain_mismatch=0.0)
    shared = _stereo_sample(14, ("pothole",), cam, noise_sigma=0.0, gain_mismatch=0.0, glint_density=0.004,
                            glint_lobe_deg=90.0)
    own = _stereo_sample(14, ("pothole",), cam, noise_sigma=0.0, gain_mismatch=0.0, glint_density=0.004,
                         glint_lobe_deg=0.2)
    for sample in (shared, own):
        np.testing.assert_array_equal(sample.truth.elevation, lambertian.truth.elevation)
        assert np.abs(sample.frame.left.astype(np.int16) - lambertian.frame.left).mean() > 0.5  # glints drawn
    shifts = [-0.02, 0.0, 0.02]
    errs_shared = _photometric_errors(shared, cam, shifts, near_x=4.5)
    errs_own = _photometric_errors(own, cam, shifts, near_x=4.5)
    assert int(np.argmin(errs_shared)) == 1
    assert errs_own[1] > 1.2 * errs_shared[1]


@pytest.mark.parametrize(
    ("field", "value"), [("glint_density", -0.001), ("glint_density", 0.5), ("glint_brightness", 0.0),
                         ("glint_lobe_deg", 0.0), ("glint_density", float("nan")), ("texture_scale", 0.0)],
)
def test_bad_glint_and_texture_settings_are_refused(field: str, value: float) -> None:
    with pytest.raises(SynthError):
        kwargs: dict[str, Any] = {field: value}
        replace(RoadConfig(), **kwargs)


def test_textures_carry_detail_a_stereo_matcher_locks_onto(noisy_sample: DriveSample) -> None:
    """OpenCV SGBM on a rendered (noisy, JPEG) pair recovers the true disparity of the road to a
    fraction of a pixel: the pavement has the fine texture real stereo relies on."""
    cam = RIG.scaled(0.5)
    left = cv2.cvtColor(noisy_sample.frame.left, cv2.COLOR_RGB2GRAY)
    right = cv2.cvtColor(right_of(noisy_sample.frame), cv2.COLOR_RGB2GRAY)
    n_disp = 48
    sgbm = cv2.StereoSGBM.create(0, n_disp, 5, P1=200, P2=800, uniquenessRatio=5, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    disparity = sgbm.compute(left, right).astype(np.float32) / 16.0
    cam_pts = road_to_camera(noisy_sample.points_road.astype(np.float64), noisy_sample.frame.attitude, GRID.base_height)
    u, v, z = project_points(cam_pts, cam)
    ok = (u >= n_disp) & (u <= cam.width - 1) & (v >= 0) & (v <= cam.height - 1)
    truth = cam.fx * cam.baseline / z[ok]
    found = disparity[np.rint(v[ok]).astype(int), np.rint(u[ok]).astype(int)]
    valid = found > 0
    assert valid.mean() > 0.9
    err = np.abs(found[valid] - truth[valid])
    assert np.median(err) < 0.35 and (err < 1.0).mean() > 0.85


def test_camera_pose_road_world_round_trip() -> None:
    pose = CameraPose(12.0, -0.4, 1.13, Attitude.from_degrees(1.0, 19.0), yaw=0.2)
    pts = np.random.default_rng(0).uniform(-5, 5, (50, 3))
    world = pose.road_to_world(pts, GRID.base_height)
    np.testing.assert_allclose(pose.world_to_road(world, GRID.base_height), pts, atol=1e-12)
    # the road origin is base_height straight below the camera; x turns with the yaw
    np.testing.assert_allclose(pose.road_to_world(np.zeros(3), GRID.base_height), [12.0, -0.4, 1.13 - GRID.base_height])
    np.testing.assert_allclose(
        pose.road_to_world(np.array([1.0, 0.0, 0.0]), 0.0) - [12.0, -0.4, 1.13], [np.cos(0.2), np.sin(0.2), 0.0]
    )


def test_ego_vehicle_shadow_falls_away_from_the_sun() -> None:
    scene = _flat_scene()
    pose = CameraPose(10.0, 0.0, GRID.base_height, Attitude.from_degrees(0.0, 19.0))
    ground = np.zeros(4)
    x = np.array([9.0, 12.0, 10.0, 10.0])  # under the car, 2 m ahead, beside it left/right
    y = np.array([0.0, 0.0, 1.5, -1.5])
    scene.sun = np.array([0.0, 0.0, 1.0])  # noon: only the footprint is shaded
    np.testing.assert_allclose(ego_shadow(scene, pose, x, y, ground), [0.0, 1.0, 1.0, 1.0])
    elev = np.radians(30.0)  # low sun behind and to the left: the shadow falls ahead-right
    scene.sun = np.array([-np.cos(elev) * np.cos(0.6), np.cos(elev) * np.sin(0.6), np.sin(elev)])
    lit = ego_shadow(scene, pose, np.array([12.0, 12.0, 8.0]), np.array([-0.8, 2.5, 0.0]), np.zeros(3))
    assert lit[0] == 0.0 and lit[1] == 1.0 and lit[2] == 0.0
