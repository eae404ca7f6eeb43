"""The pipeline's map stage: on with odometry, the per-frame pipeline without it, resets and refusals; the far
field beside the grid."""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from roadbev_core.backends.ensemble import EnsembleBackend
from roadbev_core.config import GridSpec, ParamError, RoadbevConfig, StereoCamera
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude
from roadbev_core.pipeline import (
    CameraInput,
    FarFieldUnsupported,
    Pipeline,
    build_far_backend,
    build_pace_backends,
    check_config,
)
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, REFERENCE_ROAD

S = 1_000_000_000
CAMERA = StereoCamera.rsrd_half().scaled(0.25)


class FlatRoad:
    """A backend that sees a flat road 1 cm above the reference plane everywhere."""

    name = "flat"
    needs_stereo = False

    def __init__(self, grid: GridSpec, **_: Any) -> None:
        self.grid = grid

    def estimate(self, frame: Frame) -> Estimate:
        return Estimate(np.full(self.grid.shape, 0.01, np.float32), np.full(self.grid.shape, 0.004, np.float32))


def _pipeline(**params: Any) -> Pipeline:
    config = RoadbevConfig.from_params({"require_imu": False, **params})
    return Pipeline(config, backend_factory=lambda name, grid, **o: FlatRoad(grid), configure_process=False)


def _frame(k: int) -> Frame:
    image = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
    return Frame(image, None, CAMERA, Attitude(0.0, 0.0), (1 + k) * S // 10)


def _drive(pipeline: Pipeline, frames: int, speed: float = 10.0) -> list[Any]:
    outputs = []
    for k in range(frames + 1):  # odometry one step ahead of the frames, as the node waits for it
        pipeline.add_odometry(PlanarPose((1 + k) * S // 10, 0.1 * k * speed, 0.0, 0.0, speed, 0.0))
    for k in range(frames):
        outputs.append(pipeline.process_frame(_frame(k)))
    return outputs


@pytest.mark.parametrize(
    "params, reason",
    [
        ({"preview.track_offsets_m": [3.0, -0.8]}, "preview settings do not fit the grid: .*leaves the grid"),
        ({"preview.tyre_width_m": 0.0}, "preview settings do not fit the grid: .*tyre width"),
    ],
)
def test_check_config_refuses_tracks_off_the_grid(params: dict[str, Any], reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        check_config(RoadbevConfig.from_params(params))


def test_check_config_refuses_map_settings_the_map_cannot_use() -> None:
    config = RoadbevConfig()
    assert check_config(config) is config
    broken = replace(config, map=replace(config.map, reset_after=0))  # built around from_params' ranges
    with pytest.raises(ParamError, match="map settings do not work: gate_sigma must be > 0 and reset_after >= 1"):
        check_config(broken)


def test_without_odometry_the_pipeline_is_per_frame() -> None:
    pipeline = _pipeline()
    out = pipeline.process_frame(_frame(0))
    assert not pipeline.map_active and out.map is None and out.fusion is None
    assert out.preview is not None and out.preview.reference == REFERENCE_ROAD


def test_with_odometry_frames_are_fused_and_the_preview_comes_from_the_map() -> None:
    pipeline = _pipeline()
    pipeline.set_camera_mount([1.6, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    outputs = _drive(pipeline, 8)
    assert all(o.map is not None and o.fusion is not None for o in outputs)
    first, last = outputs[0].preview, outputs[-1].preview
    # one stream: every preview in base_link against a contact plane, with the speed, from the first frame
    assert all(o.preview is not None and o.preview.reference == REFERENCE_CONTACT_PLANE
               and o.preview.vehicle_speed == pytest.approx(10.0) for o in outputs)
    assert first is not None and first.contact_plane is not None
    assert first.contact_plane.source == "road"  # no tyre contact on the map yet: the road ahead
    assert first.contact_plane.height_sigma_m > 0.0005  # and it says it is a guess
    values = np.concatenate([t.elevation[np.isfinite(t.elevation)] for t in first.tracks])
    assert np.max(np.abs(values)) < 1e-3  # the flat road lies on that plane
    assert last is not None and last.reference == REFERENCE_CONTACT_PLANE
    assert last.contact_plane is not None and last.contact_plane.source == "map"
    assert [t.name for t in last.tracks] == ["front_left", "front_right"]
    assert last.start_distance == pytest.approx(2.8) and last.vehicle_speed == pytest.approx(10.0)
    values = np.concatenate([t.elevation[np.isfinite(t.elevation)] for t in last.tracks])
    assert values.size > 100 and np.max(np.abs(values)) < 1e-4  # flat relative to the contact plane
    assert "map" in outputs[-1].timings_ms


def test_the_map_stage_waits_for_the_pose_after_the_estimate_is_made() -> None:
    """The estimate needs only the attitude: a node waits for the odometry sample after the stamp
    just before the map stage, and the frame is placed at the pose interpolated at its stamp."""
    pipeline = _pipeline()
    pipeline.set_camera_mount([1.6, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    pipeline.add_odometry(PlanarPose(S // 10, 0.0, 0.0, 0.0, 10.0, 0.0))
    frame = _frame(1)  # stamped 0.2 s: after the only odometry sample
    assert not pipeline.odometry_ready(frame.stamp_ns)
    assert pipeline.wait_for_pose(frame.stamp_ns, 0.01) >= 0.01  # waits out its timeout
    calls: list[bool] = []

    def odometry_arrives() -> None:  # while the estimate was being made
        calls.append(pipeline.odometry_ready(frame.stamp_ns))
        pipeline.add_odometry(PlanarPose(3 * S // 10, 2.0, 0.0, 0.0, 10.0, 0.0))
        assert pipeline.wait_for_pose(frame.stamp_ns, 1.0) < 0.5

    inputs = CameraInput(frame.left, frame.right, frame.camera, frame.stamp_ns)
    out = pipeline.process(inputs, frame.attitude, before_map=odometry_arrives)
    assert calls == [False] and out.map is not None and out.fusion is not None
    assert out.base_pose is not None and out.base_pose.x == pytest.approx(1.0)  # halfway between the two samples
    assert "map" in out.timings_ms


def test_rear_axle_tracks_start_at_the_rear_axle() -> None:
    pipeline = _pipeline(**{"preview.rear_axle": True})
    preview = _drive(pipeline, 8)[-1].preview
    assert preview is not None and len(preview.tracks) == 4 and preview.start_distance == 0.0
    front = preview.track("front_left").elevation
    assert np.all(np.isnan(front[: int(2.7 / 0.03)]))  # behind the front contact


def test_map_off_by_parameter_is_per_frame_and_a_frame_without_a_pose_keeps_the_stream() -> None:
    off = _pipeline(**{"map.enabled": False})
    assert all(o.map is None and o.preview is not None and o.preview.reference == REFERENCE_ROAD
               for o in _drive(off, 2))
    pipeline = _pipeline()
    pipeline.set_camera_mount([1.6, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    pipeline.add_odometry(PlanarPose(S // 10, 0.0, 0.0, 0.0, 10.0, 0.0))
    late = pipeline.process_frame(_frame(20))  # 2 s after the only odometry sample: not fused
    assert late.map is None and late.fusion is None and sum(pipeline.map_skipped.values()) == 1
    # its preview comes from that frame alone, in the stream's reference, with the last known speed
    preview = late.preview
    assert preview is not None and preview.reference == REFERENCE_CONTACT_PLANE
    assert preview.contact_plane is not None and preview.contact_plane.source == "road"
    assert preview.vehicle_speed == pytest.approx(10.0)
    values = np.concatenate([t.elevation[np.isfinite(t.elevation)] for t in preview.tracks])
    assert values.size > 100 and np.max(np.abs(values)) < 1e-3  # the frame's flat road, on its plane
    assert pipeline.fused is None or pipeline.fused.empty  # and the map was left alone


def test_reset_forgets_the_map_and_the_odometry() -> None:
    pipeline = _pipeline()
    _drive(pipeline, 3)
    assert pipeline.fused is not None and not pipeline.fused.empty
    pipeline.reset()
    assert pipeline.fused.empty and not pipeline.map_active


def test_a_camera_mount_that_is_not_a_rotation_is_refused() -> None:
    pipeline = _pipeline()
    with pytest.raises(RoadbevError, match="rotation"):
        pipeline.set_camera_mount([1.6, 0.0, 1.1], 2 * np.eye(3))
    with pytest.raises(RoadbevError, match="finite"):
        pipeline.set_camera_mount([np.nan, 0.0, 1.1], np.eye(3))


def test_a_camera_moving_on_its_bracket_keeps_the_map_and_a_larger_move_restarts_it() -> None:
    pipeline = _pipeline()
    pipeline.set_camera_mount([1.6, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    _drive(pipeline, 3)
    fused = pipeline.fused
    assert fused is not None and not fused.empty
    half = 0.5 * pipeline.config.grid.resolution
    for step in (0.3, 0.6, 0.9):  # the bracket moves, within half a cell of where the map began
        pipeline.set_camera_mount([1.6 - step * half, 0.0, 1.1 + step * half], R_BODY_FROM_OPTICAL)
        assert pipeline.fused is fused
    np.testing.assert_allclose(pipeline.camera_mount[0], [1.6 - 0.9 * half, 0.0, 1.1 + 0.9 * half])  # in use
    pipeline.set_camera_mount([1.6 + 1.1 * half, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    assert pipeline.fused is None  # the corridor is laid out again at the next frame


def test_without_odometry_a_speed_and_the_imu_yaw_are_dead_reckoned() -> None:
    pipeline = _pipeline()
    for k in range(60):  # 100 Hz IMU, level, heading constant
        pipeline.add_imu(S // 10 + k * S // 100, (0.0, 0.0, 0.0, 1.0))
    poses = []
    for k in range(4):
        pipeline.add_speed((1 + k) * S // 10, 10.0)
        out = pipeline.process_frame(_frame(k))
        assert out.base_pose is not None and out.map is not None
        poses.append(out.base_pose.x)
    np.testing.assert_allclose(np.diff(poses), 1.0, atol=1e-9)  # 10 m/s for 0.1 s per frame
    assert pipeline.map_active


def test_an_odometry_teleport_is_refused_and_a_sustained_jump_restarts_the_map() -> None:
    from roadbev_core.ego_motion import OdometryJump

    pipeline = _pipeline(**{"map.odom_reanchor_samples": 3})
    pipeline.set_camera_mount([1.6, 0.0, 1.1], R_BODY_FROM_OPTICAL)
    _drive(pipeline, 4)
    assert pipeline.fused is not None and not pipeline.fused.empty
    with pytest.raises(OdometryJump, match="refused"):  # one sample 1e6 m away: refused, the map kept
        pipeline.add_odometry(PlanarPose(S // 10 * 6, 1e6, 0.0, 0.0, 10.0, 0.0))
    assert not pipeline.fused.empty and pipeline.ego.newest is not None and pipeline.ego.newest.x == 4.0
    jumped = [PlanarPose(S // 10 * (6 + k), 300.0 + k, 0.0, 0.0, 10.0, 0.0) for k in range(3)]
    for pose in jumped[:2]:
        with pytest.raises(OdometryJump):
            pipeline.add_odometry(pose)
    assert pipeline.add_odometry(jumped[2]) is True  # three that agree: the odometry jumped
    assert pipeline.fused.empty and pipeline.last_map is None  # the map built in the old frame is gone


@pytest.mark.parametrize("change, cause", [
    ({"baseline": 1e6}, r"stereo baseline 1e\+06 m"),
    ({"fx": 1e5, "fy": 1e5}, "horizontal field of view"),
    ({"fx": 350.0}, "fx / fy"),
    ({"cx": -50.0}, "principal point"),
    ({"attitude": Attitude.from_degrees(60.0, 0.0)}, "roll 60.0 deg"),
    ({"attitude": Attitude.from_degrees(0.0, 60.0)}, "pitch 60.0 deg"),
])
def test_a_rig_or_attitude_no_road_camera_has_is_refused_with_its_cause(change: dict[str, Any], cause: str) -> None:
    from dataclasses import replace

    from roadbev_core.frame import ImplausibleFrame

    attitude = change.pop("attitude", Attitude(0.0, 0.0))
    camera = replace(CAMERA, **change)
    image = np.zeros((camera.height, camera.width, 3), np.uint8)
    frame = Frame(image, image, camera, attitude, S)
    with pytest.raises(ImplausibleFrame, match=cause):
        _pipeline().process_frame(frame)
    _pipeline().process_frame(Frame(image, image, CAMERA, Attitude.from_degrees(5.0, 8.0), S))  # a real one passes


class FarRoad(FlatRoad):
    """A flat road that answers any grid, the far-field one too (a cell per 10 cm of x in its
    elevation, so the grids can be told apart); out of view beyond ``view_m``."""

    name = "far_flat"
    far_field = True

    def __init__(self, grid: GridSpec, view_m: float = 100.0, **_: Any) -> None:
        super().__init__(grid)
        self.view_m = view_m

    def estimate(self, frame: Frame) -> Estimate:
        if self.grid.x_min >= self.view_m:
            raise FrameError("the grid does not fall inside the image at this attitude")
        x = np.broadcast_to(self.grid.x_centres()[:, None], self.grid.shape)
        return Estimate((0.001 * x).astype(np.float32), np.full(self.grid.shape, 0.004, np.float32),
                        {"matching": 1.0})


def _far_pipeline(view_m: float = 100.0, **params: Any) -> Pipeline:
    config = RoadbevConfig.from_params({"require_imu": False, **params})
    return Pipeline(config, backend_factory=lambda name, grid, **o: FarRoad(grid, view_m), configure_process=False)


def test_the_far_field_is_estimated_beside_the_grid_and_leaves_its_estimate_alone() -> None:
    off = _far_pipeline(**{"far_field.enabled": False}).process_frame(_frame(0))
    assert off.far is None and "estimate_far" not in off.timings_ms
    pipeline = _far_pipeline(**{"far_field.enabled": True})
    on = pipeline.process_frame(_frame(0))
    far_grid = pipeline.config.far_grid
    assert far_grid is not None and on.far is not None and on.far.elevation.shape == far_grid.shape
    np.testing.assert_allclose(on.far.elevation[:, 0], 0.001 * far_grid.x_centres(), rtol=1e-6)
    assert on.timings_ms["estimate_far"] >= 0.0
    np.testing.assert_array_equal(on.estimate.elevation, off.estimate.elevation)
    np.testing.assert_array_equal(on.estimate.uncertainty, off.estimate.uncertainty)
    assert on.preview is not None and off.preview is not None
    for with_far, without in zip(on.preview.tracks, off.preview.tracks, strict=True):
        np.testing.assert_array_equal(with_far.elevation, without.elevation)


def test_an_ensemble_estimates_the_far_field_on_the_grids_workers_with_the_same_answer() -> None:
    config = RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": True})
    pipeline = Pipeline(config, configure_process=False)
    near, far = pipeline.backend, pipeline.far_backend
    assert isinstance(near, EnsembleBackend) and isinstance(far, EnsembleBackend)
    assert far._pool is near._pool  # one pool: the far matchers take the worker the grid's free first
    from roadbev_lab.synth import make_sample

    frame = make_sample(31, camera=StereoCamera.rsrd_half().scaled(0.5), far_grid=config.far_grid).frame
    out = pipeline.process_frame(frame)
    alone = far.estimate(frame)
    assert out.far is not None and np.isfinite(alone.elevation).any()
    np.testing.assert_array_equal(out.far.elevation, alone.elevation)
    np.testing.assert_array_equal(out.far.uncertainty, alone.uncertainty)
    np.testing.assert_array_equal(out.estimate.elevation, near.estimate(frame).elevation)


class MeetingRoad(FarRoad):
    """A far-flat road whose grid estimate waits (up to 5 s) for the far field's to have started:
    it can only see it started when the two run at once."""

    def __init__(self, grid: GridSpec, far_started: threading.Event, threads: dict[str, str]) -> None:
        super().__init__(grid)
        self.far_started, self.threads = far_started, threads

    def estimate(self, frame: Frame) -> Estimate:
        far = self.grid.x_min >= GridSpec().x_max
        self.threads["far" if far else "near"] = threading.current_thread().name
        if far:
            self.far_started.set()
        else:
            self.threads["met"] = str(self.far_started.wait(5.0))
        return super().estimate(frame)


def test_a_backend_without_workers_of_its_own_estimates_the_far_field_beside_the_grid_at_once() -> None:
    started = threading.Event()
    threads: dict[str, str] = {}
    config = RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": True})
    pipeline = Pipeline(config, backend_factory=lambda name, grid, **o: MeetingRoad(grid, started, threads),
                        configure_process=False)
    out = pipeline.process_frame(_frame(0))
    assert threads["met"] == "True"  # the far field's estimate began while the grid's was being made
    assert threads["near"] == threading.current_thread().name and threads["far"].startswith("roadbev-far-field")
    plain = _far_pipeline(**{"far_field.enabled": True}).process_frame(_frame(0))
    assert out.far is not None and plain.far is not None
    np.testing.assert_array_equal(out.far.elevation, plain.far.elevation)
    np.testing.assert_array_equal(out.estimate.elevation, plain.estimate.elevation)


def test_a_far_field_out_of_view_is_empty_not_an_error() -> None:
    out = _far_pipeline(view_m=7.0, **{"far_field.enabled": True}).process_frame(_frame(0))
    assert out.far is not None and np.isnan(out.far.elevation).all() and np.isnan(out.far.uncertainty).all()
    assert np.isfinite(out.estimate.elevation).all()


def test_a_backend_without_a_far_field_runs_as_with_it_off_and_says_why() -> None:
    asked = RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": True})
    pipeline = Pipeline(asked, backend_factory=lambda name, grid, **o: FlatRoad(grid), configure_process=False)
    assert "backend 'flat' does not estimate the far field" in pipeline.far_field_off
    assert pipeline.far_backend is None and pipeline.config == asked.with_params({"far_field.enabled": False})
    out = pipeline.process_frame(_frame(0))
    assert out.far is None and np.isfinite(out.estimate.elevation).all()
    # asked for directly, the far-field backend of such a backend is refused
    with pytest.raises(FarFieldUnsupported, match="backend 'flat' does not estimate the far field"):
        build_far_backend(asked, FlatRoad(GridSpec()))
    off_config = RoadbevConfig.from_params({"far_field.enabled": False})
    assert build_far_backend(off_config, FlatRoad(GridSpec())) is None  # off: nothing to build
    # a parameter change to a backend that has one turns it on, and back
    far_capable = _far_pipeline(**{"far_field.enabled": True})
    assert far_capable.far_field_off == "" and far_capable.far_backend is not None
    off = Pipeline(RoadbevConfig.from_params({"require_imu": False, "far_field.enabled": False}),
                   backend_factory=lambda name, grid, **o: FlatRoad(grid), configure_process=False)
    assert off.far_field_off == "" and off.far_backend is None
    off.reconfigure(asked)
    assert "does not estimate the far field" in off.far_field_off and off.config.far_grid is None


def test_a_grid_that_reaches_the_far_edge_runs_alone_and_says_why() -> None:
    pipeline = _far_pipeline(**{"far_field.enabled": True, "far_field.x_max": 7.0})
    assert pipeline.far_field_off.startswith("the grid already reaches far_field.x_max (7 m)")
    assert pipeline.far_backend is None and pipeline.config.far_grid is None
    out = pipeline.process_frame(_frame(0))
    assert out.far is None and np.isfinite(out.estimate.elevation).all()
    # moved back out of the grid's reach, the far field is estimated again
    pipeline.reconfigure(pipeline.config.with_params({"far_field.enabled": True, "far_field.x_max": 15.0}))
    assert pipeline.far_field_off == "" and pipeline.far_backend is not None
    assert pipeline.process_frame(_frame(1)).far is not None


def test_reconfiguring_the_far_field_rebuilds_its_backend_only() -> None:
    pipeline = _far_pipeline(**{"far_field.enabled": True})
    near, far = pipeline.backend, pipeline.far_backend
    assert far is not None and far.grid == pipeline.config.far_grid
    pipeline.reconfigure(pipeline.config.with_params({"far_field.x_max": 12.12}))
    assert pipeline.backend is near and pipeline.far_backend is not far
    assert pipeline.far_backend is not None and pipeline.far_backend.grid.x_max == 12.12
    same = pipeline.far_backend
    pipeline.reconfigure(pipeline.config.with_params({"map.gate_sigma": 4.0}))
    assert pipeline.far_backend is same
    out = pipeline.process_frame(_frame(0))
    assert out.far is not None and out.far.elevation.shape == (42, 16)


def _far_drive(pipeline: Pipeline, frames: int) -> list[Any]:
    outputs = []
    for k in range(frames + 1):
        pipeline.add_odometry(PlanarPose((1 + k) * S // 10, 0.1 * k, 0.0, 0.0, 1.0, 0.0))
    for k in range(frames):
        outputs.append(pipeline.process_frame(_frame(k)))
    return outputs


def test_with_the_far_field_and_the_map_on_the_map_and_its_preview_reach_the_far_edge() -> None:
    off = _far_drive(_far_pipeline(**{"far_field.enabled": False}), 3)[-1]
    on_pipeline = _far_pipeline(**{"far_field.enabled": True})
    on = _far_drive(on_pipeline, 3)[-1]
    far_grid = on_pipeline.config.far_grid
    camera_x = on_pipeline.config.vehicle.camera_position_m[0]
    assert far_grid is not None and on.map is not None and off.map is not None and on.fusion is not None
    assert on.map.resolution == off.map.resolution  # one resolution: the grid's
    x_on, _ = on.map.cell_centres()
    x_off, _ = off.map.cell_centres()
    base_x = on.base_pose.x
    assert x_off.max() - base_x < camera_x + 7.2 < x_on.max() - base_x
    seen = np.isfinite(on.map.elevation).any(axis=1)
    assert (x_on[seen] - base_x - camera_x).max() > far_grid.x_max - 0.1  # the far field is in the map
    assert on.preview is not None and off.preview is not None
    assert on.preview.n_samples > off.preview.n_samples
    for track in on.preview.tracks:
        reach = on.preview.distances()[np.isfinite(track.elevation)].max() - camera_x
        assert reach >= 14.9
    # the near part is the grid's alone: fused alike with the far field on or off
    rows = (x_on - base_x - camera_x) < 6.5
    rows_off = (x_off - base_x - camera_x) < 6.5
    np.testing.assert_allclose(on.map.elevation[rows][-rows_off.sum():], off.map.elevation[rows_off], atol=1e-6,
                               equal_nan=True)


class NamedRoad(FlatRoad):
    """A flat road at a height of its own, named after the backend it stands for."""

    def __init__(self, name: str, grid: GridSpec, height: float, *, stereo: bool = True) -> None:
        super().__init__(grid)
        self.name, self.height, self.needs_stereo = name, height, stereo
        self.far_field = True

    def estimate(self, frame: Frame) -> Estimate:
        return Estimate(np.full(self.grid.shape, self.height, np.float32), np.full(self.grid.shape, 0.004, np.float32))


def _named(name: str, grid: GridSpec, **_: Any) -> NamedRoad:
    return NamedRoad(name, grid, {"bm": 0.02, "sgbm": 0.03}.get(name, 0.01), stereo=name != "mono")


def test_a_paced_frame_is_answered_by_the_pace_backend_on_both_grids() -> None:
    config = RoadbevConfig.from_params({"require_imu": False, "backend": "sgbm", "far_field.enabled": True})
    pipeline = Pipeline(config, backend_factory=_named, configure_process=False)
    assert pipeline.pace.near is not None and pipeline.pace.near.name == "bm"
    assert pipeline.pace.far is not None and pipeline.pace.far.grid == config.far_grid
    chosen = pipeline.process_frame(_frame(0))
    paced = pipeline.process(CameraInput(_frame(1).left, None, CAMERA, _frame(1).stamp_ns), Attitude(0.0, 0.0),
                             paced=True)
    assert not chosen.paced and paced.paced
    assert np.all(chosen.estimate.elevation == np.float32(0.03))
    assert np.all(paced.estimate.elevation == np.float32(0.02))
    assert chosen.far is not None and paced.far is not None
    assert np.all(chosen.far.elevation == np.float32(0.03)) and np.all(paced.far.elevation == np.float32(0.02))


def test_a_pace_backend_given_with_options_is_built_with_them_over_the_nodes_own() -> None:
    built: list[tuple[str, GridSpec, dict[str, Any]]] = []

    def recording(name: str, grid: GridSpec, **options: Any) -> NamedRoad:
        built.append((name, grid, options))
        return _named(name, grid)

    config = RoadbevConfig.from_params({"require_imu": False, "backend": "sgbm", "far_field.enabled": True,
                                        "pace_backend": "bm:plane_parallax_px=16,block_size=9",
                                        "bm.block_size": 7, "bm.uniqueness_ratio": 20})
    pipeline = Pipeline(config, backend_factory=recording, configure_process=False)
    assert pipeline.pace.near is not None and pipeline.pace.near.name == "bm"
    pace = {"plane_parallax_px": 16, "block_size": 9, "uniqueness_ratio": 20}
    assert [(n, g, o) for n, g, o in built if n == "bm"] == [("bm", config.grid, pace), ("bm", config.far_grid, pace)]
    # naming the chosen backend, with options or not, is no pace backend
    same = Pipeline(config.with_params({"pace_backend": "sgbm:block_size=5"}), backend_factory=_named,
                    configure_process=False)
    assert same.pace.near is None and same.pace.off_reason == ""
    with pytest.raises(ParamError, match=r"pace_backend takes NAME=VALUE, got 'block_size'"):
        RoadbevConfig.from_params({"pace_backend": "bm:plane_parallax_px=16,block_size"})
    with pytest.raises(ParamError, match=r"pace_backend must be empty or one of .*; got 'bmm:block_size=9'"):
        RoadbevConfig.from_params({"pace_backend": "bmm:block_size=9"})


def test_without_a_pace_backend_a_paced_frame_is_answered_by_the_chosen_one() -> None:
    for params in ({"backend": "sgbm", "pace_backend": ""}, {"backend": "bm"}):
        pipeline = Pipeline(RoadbevConfig.from_params({"require_imu": False, **params}), backend_factory=_named,
                            configure_process=False)
        assert pipeline.pace.near is None and pipeline.pace.off_reason == ""
        out = pipeline.process(CameraInput(_frame(0).left, None, CAMERA, 1), Attitude(0.0, 0.0), paced=True)
        assert not out.paced


def test_a_stereo_pace_backend_does_not_stand_in_for_a_monocular_one_and_says_why() -> None:
    pipeline = Pipeline(RoadbevConfig.from_params({"require_imu": False, "backend": "mono"}), backend_factory=_named,
                        configure_process=False)
    assert pipeline.pace.near is None
    assert pipeline.pace.off_reason == (
        "pace_backend 'bm' needs both images and backend 'mono' is given the left one only")


def test_a_pace_backend_that_cannot_run_or_is_unknown_is_refused_with_its_name() -> None:
    def refuses(name: str, grid: GridSpec, **options: Any) -> NamedRoad:
        if name == "bm":
            raise RoadbevError("no such checkpoint")
        return _named(name, grid)

    with pytest.raises(RoadbevError, match=r"pace_backend: backend 'bm' cannot run: no such checkpoint"):
        Pipeline(RoadbevConfig.from_params({"require_imu": False, "backend": "sgbm"}), backend_factory=refuses,
                 configure_process=False)
    with pytest.raises(ParamError, match=r"pace_backend must be empty or one of .*; got 'bmm'"):
        RoadbevConfig.from_params({"pace_backend": "bmm"})


def test_reconfiguring_rebuilds_the_pace_backend_only_when_its_settings_change() -> None:
    pipeline = Pipeline(RoadbevConfig.from_params({"require_imu": False, "backend": "sgbm"}), backend_factory=_named,
                        configure_process=False)
    pace = pipeline.pace
    pipeline.reconfigure(pipeline.config.with_params({"pace_load": 0.5, "map.gate_sigma": 4.0}))
    assert pipeline.pace is pace
    pipeline.reconfigure(pipeline.config.with_params({"bm.block_size": 9}))
    assert pipeline.pace is not pace and pipeline.pace.near is not None
    pipeline.reconfigure(pipeline.config.with_params({"pace_backend": ""}))
    assert pipeline.pace.near is None
    assert build_pace_backends(pipeline.config, pipeline.backend, _named).near is None
