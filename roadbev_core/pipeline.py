"""The ROS-free pipeline: what a vehicle delivers in, the outputs out, one object for every entry point.

The node, ``roadbev eval``, the online evaluation, the demo and the benchmarks all drive a
:class:`Pipeline`, so a number in one is the number in all::

    IMU samples ──► add_imu ──► ImuBuffer (roadbev_core.attitude: the one attitude path)
    speed       ──► add_speed                                   │
    odometry    ──► add_odometry ──► EgoMotion                  │
    CameraInput ──► process ──► attitude at the stamp ─► Frame ─► backend.estimate ─► Estimate
                                                                          │
                           map off: wheel_track_profiles ◄────────────────┤ ─► PipelineOutput
                           map on:  FusedMap.integrate ─► map_preview ◄───┘    (+ map window)

With ``far_field.enabled`` a second backend of the same kind answers the far-field grid beyond
the grid on the same frame (:func:`build_far_backend`; ``PipelineOutput.far``) where the backend
has a far field and the grid leaves it a window; otherwise (``far_field_off_reason``: a backend
with none, or a grid that already reaches ``far_field.x_max``) the pipeline runs as with the
far field off and says why in :attr:`Pipeline.far_field_off` (the node's diagnostics, ``roadbev
eval``'s ``far_field`` key). The grid's
own estimate is the same with it on or off. With the map on it is fused too, on the map's cells
with the frame's alignment (:meth:`roadbev_core.fusion.FusedMap.integrate_far`), so the map and
its contact-plane previews reach the far-field grid's far edge; the per-frame (map off) preview
stays on the grid.

With ``pace_backend`` (default ``bm``) a second, cheaper backend is built beside the chosen one
(:func:`build_pace_backends`, and its far-field twin): :meth:`Pipeline.process` runs it on a frame
when asked (``paced``; the node asks while the chosen backend cannot keep pace with the camera:
:mod:`roadbev_core.pacing`). ``roadbev eval`` and the benchmarks never ask.

The map stage (roadbev_core.fusion) runs when ``map.enabled`` and an ego-motion source exists:
odometry samples (``add_odometry``) or, without them, a speed (dead reckoned with the IMU's
yaw). With the map on every preview is a contact-plane one in ``base_link``: a frame whose pose
cannot be had (odometry too old) is not fused (counted in ``map_skipped``) and its preview comes
from that frame alone, in the same reference.

It owns the backend (built from the config through the registry), the attitude rules, the
process-wide compute settings (threads; denormals flushed in the thread that runs the backend)
and the checks on what comes in (image size). It is thread-safe for one producer of IMU and
speed samples and one thread calling :meth:`process`, as the node uses it.

Offline, :func:`replay` feeds recorded IMU samples and frames in time order, exactly as they
would arrive live, so the offline attitude of a frame is the one the node computes.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from roadbev_core.attitude import ImuSample, ImuStale, imu_buffer
from roadbev_core.backends import Backend, BackendError, SubmitsEstimates, create, start_estimate
from roadbev_core.config import (
    GridSpec,
    ParamError,
    RoadbevConfig,
    StereoCamera,
    check_image_size,
    split_backend_spec,
)
from roadbev_core.ego_motion import EgoMotion, EgoMotionStale, PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame, FrameError, ImplausibleFrame, implausible
from roadbev_core.fusion import (
    FrameFusion,
    FramePlacement,
    FusedMap,
    FusionError,
    MapSettings,
    MapWindow,
    map_settings,
    place_frame,
)
from roadbev_core.geometry import Attitude, quaternion_to_rotation
from roadbev_core.map_preview import contact_plane_on_map, map_preview
from roadbev_core.pacing import stand_in
from roadbev_core.preview import PreviewError, PreviewProfiles, check_tracks, wheel_track_profiles
from roadbev_core.runtime import configure_threads, flush_denormals
from roadbev_core.vehicle import planar_yaw

__all__ = [
    "SPEED_MAX_AGE_S",
    "BackendFactory",
    "CameraInput",
    "FarFieldUnsupported",
    "ImuFeed",
    "MapFactory",
    "OdometryFeed",
    "PaceBackends",
    "Pipeline",
    "PipelineOutput",
    "build_backend",
    "build_far_backend",
    "build_pace_backends",
    "check_config",
    "far_field_off_reason",
    "replay",
]

# create(name, grid, **options) -> Backend; injectable so tests can run a stub backend.
BackendFactory = Callable[..., Backend]
# FusedMap(settings) -> the map; injectable so the lab can run a map that takes part of the truth.
MapFactory = Callable[[MapSettings], FusedMap]
# A speed older than this (in stamp time) is treated as unknown.
SPEED_MAX_AGE_S = 1.0


@dataclass(frozen=True)
class CameraInput:
    """The pixels and calibration of one synchronised camera set.

    Attributes:
        left: [H, W, 3] uint8 RGB (or [H, W] grey) rectified left image.
        right: the right image (same size), or None for one camera.
        camera: the rig.
        stamp_ns: the left image's stamp.
    """

    left: np.ndarray
    right: np.ndarray | None
    camera: StereoCamera
    stamp_ns: int


@dataclass
class PipelineOutput:
    """What one frame produced.

    Attributes:
        frame: the frame the backend saw (with its attitude).
        estimate: elevation and 1-sigma uncertainty on the config's grid.
        preview: the wheel-track profiles of the estimate (times of arrival when a speed is known);
            None only for a pipeline around a backend whose grid the tracks do not fit
            (:func:`roadbev_lab.evaluation.frames.pipeline_for`: a validated config always fits).
        timings_ms: ``estimate``, ``preview`` (and with the map ``map``) wall times (the
            backend's own stages are in ``estimate.timings_ms``).
        map: the fused map's window after this frame (None with the map off).
        fusion: what fusing this frame did (None with the map off).
        base_pose: ``base_link``'s planar pose in ``odom`` at the stamp (map on).
        far: elevation and 1-sigma on the far-field grid (``config.far_grid``) with
            ``far_field.enabled``, else None; all NaN when that grid is out of view. With the map on
            it is fused into ``map`` too.
        paced: the pace backend answered the frame (``Pipeline.process(paced=True)``).
    """

    frame: Frame
    estimate: Estimate
    preview: PreviewProfiles | None
    timings_ms: dict[str, float] = field(default_factory=dict)
    map: MapWindow | None = None
    fusion: FrameFusion | None = None
    base_pose: PlanarPose | None = None
    far: Estimate | None = None
    paced: bool = False

    @property
    def stamp_ns(self) -> int:
        return self.frame.stamp_ns


def check_config(config: RoadbevConfig) -> RoadbevConfig:
    """``config``, checked against the components that judge it: the fused map's settings
    (:func:`roadbev_core.fusion.map_settings`) and the wheel tracks on the grid
    (:func:`roadbev_core.preview.check_tracks`). Every entry point that builds a config from
    parameters calls it after :meth:`RoadbevConfig.from_params` (which checks names, types,
    ranges, the backend's name and the costs).

    Raises:
        ParamError: naming what does not work.
    """
    try:
        map_settings(config)
    except FusionError as exc:
        raise ParamError(f"map settings do not work: {exc}") from None
    p = config.preview
    try:
        check_tracks(config.grid, p.track_offsets_m, p.tyre_width_m, p.spacing_m)
    except PreviewError as exc:
        raise ParamError(f"preview settings do not fit the grid: {exc}") from None
    return config


def build_backend(config: RoadbevConfig, factory: BackendFactory | None = None, *,
                  grid: GridSpec | None = None) -> Backend:
    """The config's backend on the config's grid (or on ``grid``: the far-field one).

    Any failure while building (a missing checkpoint, an option the backend refuses, a
    checkpoint whose network cannot be allocated) is a :class:`BackendError` with the reason:
    a parameter change must never take a running node down.

    Raises:
        BackendError: the backend cannot be built.
    """
    name = config.backend.name
    try:
        return (factory or create)(name, grid or config.grid, **config.backend.options_of())
    except RoadbevError as exc:
        raise BackendError(f"backend {name!r} cannot run: {exc}") from exc
    except Exception as exc:  # any failure of a backend constructor is a refusal, never a crash
        raise BackendError(f"backend {name!r} cannot run: {type(exc).__name__}: {exc}") from exc


class FarFieldUnsupported(BackendError):
    """``far_field.enabled`` with a backend that does not answer the far-field grid."""


def far_field_off_reason(config: RoadbevConfig, backend: Backend) -> str:
    """Why the far field ``config`` asks for is not estimated, or "" (asked for and estimated, or
    not asked for): the grid already reaches its far edge
    (:meth:`~roadbev_core.config.FarFieldConfig.off_reason`), or ``backend`` has none (no true
    ``far_field`` attribute)."""
    if not config.far_field.enabled:
        return ""
    beyond = config.far_field.off_reason(config.grid)
    if beyond:
        return beyond
    if not getattr(backend, "far_field", False):
        return f"backend {backend.name!r} does not estimate the far field (far_field.enabled): bm, sgbm and their " \
               "ensemble do"
    return ""


def build_far_backend(config: RoadbevConfig, backend: Backend, factory: BackendFactory | None = None
                      ) -> Backend | None:
    """The far-field backend: ``backend``'s kind with the same options on ``config.far_grid``
    (None with the far field off).

    Raises:
        FarFieldUnsupported: ``backend`` does not answer a far-field grid (its ``far_field``
            attribute: the image-view backends and their ensemble do).
        BackendError: the backend cannot be built on that grid.
    """
    far_grid = config.far_grid
    if far_grid is None:
        return None
    unsupported = far_field_off_reason(config, backend)
    if unsupported:
        raise FarFieldUnsupported(unsupported)
    far = build_backend(config, factory, grid=far_grid)
    if isinstance(far, SubmitsEstimates) and type(far) is type(backend):
        far.share_workers(backend)  # near and far matchers queue on one pool (Pipeline._run)
    return far


class PaceBackends(NamedTuple):
    """The pace backend (``pace_backend``: :mod:`roadbev_core.pacing`) on the grid and on the
    far-field grid, or why there is none that can stand in for the chosen backend."""

    near: Backend | None = None
    far: Backend | None = None
    off_reason: str = ""


def build_pace_backends(config: RoadbevConfig, backend: Backend, factory: BackendFactory | None = None
                        ) -> PaceBackends:
    """The pace backend on the grid and, where ``backend`` answers the far field and it can, on the
    far-field grid. None where ``pace_backend`` is empty or ``backend``'s own name; None with the
    reason where it needs both images and ``backend`` is given the left one only (a monocular
    backend).

    Raises:
        BackendError: it cannot be built (a missing checkpoint, an option it refuses).
    """
    spec = stand_in(config.backend.pace_backend, backend.name)
    if not spec:
        return PaceBackends()
    try:
        pace = config.with_params(_pace_params(spec))
        near = build_backend(pace, factory)
        far = (build_backend(pace, factory, grid=config.far_grid)
               if config.far_grid is not None and not far_field_off_reason(pace, near) else None)
    except (BackendError, ParamError) as exc:
        raise BackendError(f"pace_backend: {exc}") from exc
    if near.needs_stereo and not backend.needs_stereo:
        return PaceBackends(off_reason=f"pace_backend {spec!r} needs both images and backend {backend.name!r} is "
                                       "given the left one only")
    return PaceBackends(near, far)


def _pace_key(config: RoadbevConfig, backend: Backend) -> tuple[Any, ...]:
    """What :func:`build_pace_backends` builds from: equal keys, the same pace backends."""
    spec = stand_in(config.backend.pace_backend, backend.name)
    if not spec:
        return ()
    name = split_backend_spec(spec, "pace_backend")[0]
    return spec, config.backend.options_of(name), config.grid, config.far_grid, backend.needs_stereo


def _pace_params(spec: str) -> dict[str, Any]:
    """The node parameters that make ``pace_backend``'s backend the chosen one: its name, and the
    options its spec gives (``bm:plane_parallax_px=16``) over the node's own for it."""
    name, options = split_backend_spec(spec, "pace_backend")
    return {"backend": name, **{f"{name}.{key}": value for key, value in options.items()}}


def _no_estimate(grid: GridSpec) -> Estimate:
    """An estimate without any answer on ``grid`` (all NaN)."""
    empty = np.full(grid.shape, np.nan, np.float32)
    return Estimate(elevation=empty, uncertainty=empty.copy())


class Pipeline:
    """Camera sets, IMU and speed in; estimates and previews out (see the module docstring).

    Args:
        config: a validated config (:meth:`RoadbevConfig.from_params`, :func:`check_config`).
        backend_factory: ``factory(name, grid, **options) -> Backend`` (default: the registry).
        map_factory: ``factory(settings) -> FusedMap`` (default: :class:`FusedMap`).
        configure_process: apply the config's thread count process-wide (the node and the
            command line do; a library user embedding the pipeline may keep its own settings).

    Attributes:
        config: the config it runs: the one given, with the far field off where it is not
            estimated (``far_field_off`` says why).
        far_field_off: why the far field the config asks for is not estimated
            (:func:`far_field_off_reason`), or "".
        pace: the pace backend on the grid and the far-field grid (:func:`build_pace_backends`).

    Raises:
        BackendError: the backend (or the far-field one, or the pace backend) cannot be built.
    """

    def __init__(
        self,
        config: RoadbevConfig,
        *,
        backend_factory: BackendFactory | None = None,
        map_factory: MapFactory = FusedMap,
        configure_process: bool = True,
    ) -> None:
        self._factory = backend_factory
        self._map_factory = map_factory
        self._configure_process = configure_process
        self._lock = threading.Lock()
        self.backend = build_backend(config, backend_factory)
        self.far_field_off = far_field_off_reason(config, self.backend)
        self.config = config = self._runnable(config, self.far_field_off)
        self.far_backend = build_far_backend(config, self.backend, backend_factory)
        self.pace = build_pace_backends(config, self.backend, backend_factory)
        self.imu = imu_buffer(config.imu)
        self._speed: tuple[int, float] | None = None  # (stamp ns, m/s)
        self._with_preview = self._tracks_fit(config)
        self.ego = EgoMotion(**self._ego_settings(config))
        self._odometry_seen = False
        # the left camera on base_link: position [3] and R optical -> base_link (None until /tf_static)
        self._camera_mount: tuple[np.ndarray, np.ndarray | None] = (
            np.array(config.vehicle.camera_position_m, np.float64), None)
        self._mount_from_tf = False
        self._corridor_mount = self._camera_mount[0]  # where the camera was when the map's corridor was laid out
        self.fused: FusedMap | None = None
        self.last_map: MapWindow | None = None  # the newest window (``~/save_map``)
        self.map_skipped: dict[str, int] = {}
        self._far_thread: ThreadPoolExecutor | None = None
        if configure_process:
            configure_threads(config.backend.inference_threads)

    # --- configuration -------------------------------------------------------------------------
    @staticmethod
    def _runnable(config: RoadbevConfig, far_field_off: str) -> RoadbevConfig:
        """``config``, with the far field off where it is not estimated (``far_field_off``): the
        map's corridor and the previews then end at the grid's far edge, as with it off."""
        return config.with_params({"far_field.enabled": False}) if far_field_off else config

    @staticmethod
    def _tracks_fit(config: RoadbevConfig) -> bool:
        p = config.preview
        try:
            check_tracks(config.grid, p.track_offsets_m, p.tyre_width_m, p.spacing_m)
        except PreviewError:
            return False
        return True

    def reconfigure(self, config: RoadbevConfig) -> None:
        """Switch to ``config``; the backend is rebuilt only when its settings or the grid change.

        On failure nothing changes (the old backend keeps running).

        Raises:
            BackendError: the new backend cannot be built.
        """
        old = self.config
        rebuild = (
            config.backend.name != old.backend.name
            or config.grid != old.grid
            or config.backend.options_of() != old.backend.options_of()
        )
        backend = build_backend(config, self._factory) if rebuild else self.backend
        far_field_off = far_field_off_reason(config, backend)
        config = self._runnable(config, far_field_off)
        far_backend = (build_far_backend(config, backend, self._factory)
                       if rebuild or config.far_grid != old.far_grid else self.far_backend)
        pace = (build_pace_backends(config, backend, self._factory)
                if _pace_key(config, backend) != _pace_key(self.config, self.backend) else self.pace)
        with self._lock:
            self.config = config
            self.backend = backend
            self.far_backend = far_backend
            self.pace = pace
            self.far_field_off = far_field_off
            self._with_preview = self._tracks_fit(config)
            if config.imu != old.imu:
                self.imu.configure(config.imu)
            for name, value in self._ego_settings(config).items():
                setattr(self.ego, name, value)
            if not self._mount_from_tf:
                self._camera_mount = (np.array(config.vehicle.camera_position_m, np.float64), None)
            if (map_settings(config), config.vehicle) != (map_settings(old), old.vehicle):
                self.fused = None  # rebuilt with the new settings at the next frame (not for map.save_dir)
        if self._configure_process and config.backend.inference_threads != old.backend.inference_threads:
            configure_threads(config.backend.inference_threads)

    def reset(self) -> None:
        """Forget the IMU history, the speed, the odometry and the map (the clock jumped back: a
        bag started again)."""
        with self._lock:
            self.imu.clear()
            self._speed = None
            self.ego.clear()
            self._odometry_seen = False
            if self.fused is not None:
                self.fused.reset()
            self.last_map = None

    def clear_map(self) -> None:
        """Forget the fused map only (``~/clear_map``)."""
        with self._lock:
            if self.fused is not None:
                self.fused.reset()
            self.last_map = None

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None:
        """The left camera on ``base_link`` from TF (wins over ``vehicle.camera_position_m``):
        position [3] and R [3, 3] optical -> base_link. The fused map's corridor is laid out
        around the camera (:func:`roadbev_core.fusion.map_settings`): the map starts again when the
        camera has moved more than half a cell from where it was when the map began, so a camera
        on a moving bracket (a mount from ``/tf`` at every frame) keeps its map, each frame placed
        where the camera is (the corridor's edges then lie less than half a cell off).

        Raises:
            RoadbevError: a non-finite position or a matrix that is not a rotation.
        """
        pos = np.asarray(list(position), np.float64)
        R = np.asarray(R_base_optical, np.float64)
        if pos.shape != (3,) or R.shape != (3, 3) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(R))):
            raise RoadbevError("camera mount must be a finite position [3] and rotation [3, 3]")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
            raise RoadbevError("camera mount rotation is not a rotation")
        with self._lock:
            moved = float(np.max(np.abs(pos - self._corridor_mount))) if self._mount_from_tf else math.inf
            self._camera_mount = (pos, R)
            self._mount_from_tf = True
            if moved > 0.5 * self.config.grid.resolution:
                self.fused = None  # the corridor depends on where the camera sits
                self._corridor_mount = pos

    @property
    def camera_mount(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The left camera on ``base_link``: position [3], R optical -> base_link (None without TF)."""
        with self._lock:
            return self._camera_mount

    # --- inputs --------------------------------------------------------------------------------
    def add_imu(self, stamp_ns: int, orientation_xyzw: Iterable[float]) -> None:
        """One IMU orientation.

        Raises:
            ImuError: a sample that cannot be used (it is not kept).
        """
        with self._lock:
            self.imu.add(stamp_ns, orientation_xyzw)

    def add_speed(self, stamp_ns: int, speed_mps: float) -> None:
        """The vehicle's speed along x at ``stamp_ns``.

        Raises:
            RoadbevError: a non-finite speed.
        """
        if not math.isfinite(speed_mps):
            raise RoadbevError(f"non-finite vehicle speed {speed_mps}")
        with self._lock:
            self._speed = (int(stamp_ns), float(speed_mps))

    @staticmethod
    def _ego_settings(config: RoadbevConfig) -> dict[str, Any]:
        """The :class:`EgoMotion` fields the config sets (at start and on a parameter change)."""
        m = config.map
        return {"max_age_s": m.odom_max_age_s, "max_speed_mps": m.odom_max_speed_mps,
                "max_yaw_rate": m.odom_max_yaw_rate, "reanchor_samples": m.odom_reanchor_samples}

    def add_odometry(self, pose: PlanarPose) -> bool:
        """One odometry sample (``base_link`` in ``odom``, planar).

        Returns:
            True when the odometry jumped and is followed from its new frame: the fused map,
            built in the old one, starts again (:meth:`EgoMotion.add`).

        Raises:
            EgoMotionError: a sample that cannot be used (it is not kept): an OdometryJump for one
                no car could have produced from the one before.
        """
        with self._lock:
            reanchored = self.ego.add(pose)
            self._odometry_seen = True
            if reanchored:
                if self.fused is not None:
                    self.fused.reset()
                self.last_map = None
            return reanchored

    def attitude_ready(self, stamp_ns: int) -> bool:
        """Whether the IMU has a sample at or after ``stamp_ns`` (the attitude will not change)."""
        with self._lock:
            return self.imu.brackets(stamp_ns)

    def odometry_ready(self, stamp_ns: int) -> bool:
        """Whether the pose at ``stamp_ns`` will not change: an odometry sample at or after it has
        arrived (always true while no odometry is coming)."""
        with self._lock:
            return not self._odometry_seen or self.ego.brackets(stamp_ns)

    @property
    def map_active(self) -> bool:
        """Whether frames are fused now (``map.enabled`` and odometry or a speed has arrived)."""
        with self._lock:
            return self.config.map.enabled and (self._odometry_seen or self._speed is not None)

    def wait_for_attitude(self, stamp_ns: int, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> float:
        """Wait (live) up to ``timeout_s`` for an IMU sample at or after ``stamp_ns``, so the
        attitude is interpolated rather than taken from older samples; returns the seconds waited
        (``stop()`` true ends the wait early). The pose waits later (:meth:`wait_for_pose`)."""
        return self._wait(lambda: self.attitude_ready(stamp_ns), timeout_s, stop)

    def wait_for_pose(self, stamp_ns: int, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> float:
        """Wait (live) up to ``timeout_s`` for an odometry sample at or after ``stamp_ns`` (none
        while no odometry is coming), so the pose the map places the frame at is interpolated;
        returns the seconds waited. The estimate does not need it: a node waits for it only
        before the map stage (``process(..., before_map=...)``), by when it has mostly come."""
        return self._wait(lambda: self.odometry_ready(stamp_ns), timeout_s, stop)

    @staticmethod
    def _wait(ready: Callable[[], bool], timeout_s: float, stop: Callable[[], bool]) -> float:
        start = time.monotonic()
        while not ready() and time.monotonic() - start < timeout_s and not stop():
            time.sleep(0.002)
        return time.monotonic() - start

    def imu_age_s(self, stamp_ns: int) -> float | None:
        """Seconds from the newest IMU sample to ``stamp_ns`` (None without IMU)."""
        with self._lock:
            return self.imu.age_s(stamp_ns)

    def attitude_at(self, stamp_ns: int) -> Attitude:
        """The camera attitude at ``stamp_ns`` (the configured default when the IMU cannot answer
        and ``require_imu`` is false).

        Raises:
            ImuStale: no trustworthy attitude and ``require_imu`` is true.
        """
        with self._lock:
            config = self.config
            try:
                return self.imu.attitude_at(stamp_ns)
            except ImuStale:
                if config.imu.require:
                    raise
        return Attitude.from_degrees(config.imu.default_roll_deg, config.imu.default_pitch_deg)

    def speed_at(self, stamp_ns: int) -> float | None:
        """The latest speed if it is at most :data:`SPEED_MAX_AGE_S` from ``stamp_ns``."""
        with self._lock:
            speed = self._speed
        if speed is None or abs(stamp_ns - speed[0]) > SPEED_MAX_AGE_S * 1e9:
            return None
        return speed[1]

    def latest_speed(self, stamp_ns: int) -> float | None:
        """The car's latest speed near ``stamp_ns`` (m/s): the newest odometry pose's where
        odometry comes, else the speed's (:meth:`speed_at`); None where neither is known."""
        with self._lock:
            newest = self.ego.newest if self._odometry_seen else None
        return newest.speed if newest is not None else self.speed_at(stamp_ns)

    # --- processing ----------------------------------------------------------------------------
    def process(self, inputs: CameraInput, attitude: Attitude | None = None, *,
                before_map: Callable[[], object] | None = None, paced: bool = False) -> PipelineOutput:
        """Estimate the elevation and the preview for one camera set.

        Args:
            inputs: the images, rig and stamp.
            attitude: the camera attitude when it is known otherwise (synthetic data); None =
                from the IMU samples added so far.
            before_map: called once the estimate is made, before the map stage reads the pose at
                the stamp (the node waits there for the odometry sample after the stamp:
                :meth:`wait_for_pose`).
            paced: the pace backend answers (where there is one; ``PipelineOutput.paced`` says
                whether it did).

        Raises:
            ConfigError: an image larger than the configured limit.
            ImuStale: no trustworthy attitude (see :meth:`attitude_at`).
            FrameError: images and calibration that do not fit together.
            PreviewError: the estimate cannot be sampled along the wheel tracks.
        """
        with self._lock:
            config, backend, far_backend = self.config, self.backend, self.far_backend
            pace = self.pace.near if paced else None
            if pace is not None:
                backend, far_backend = pace, self.pace.far
        check_image_size(inputs.camera.width, inputs.camera.height)
        if attitude is None:
            attitude = self.attitude_at(inputs.stamp_ns)
        frame = Frame(inputs.left, inputs.right, inputs.camera, attitude, inputs.stamp_ns)
        output = self._run(frame, config, backend, far_backend, before_map)
        output.paced = pace is not None
        return output

    def process_frame(self, frame: Frame) -> PipelineOutput:
        """:meth:`process` for a frame whose attitude is already known."""
        return self.process(CameraInput(frame.left, frame.right, frame.camera, frame.stamp_ns), frame.attitude)

    def _run(self, frame: Frame, config: RoadbevConfig, backend: Backend, far_backend: Backend | None,
             before_map: Callable[[], object] | None = None) -> PipelineOutput:
        why = implausible(frame)
        if why:
            raise ImplausibleFrame(why)
        flush_denormals()
        t0 = time.perf_counter()
        # The far field's estimate starts with the grid's: on a backend that shares its workers
        # (an ensemble) its matchers queue behind the grid's members and take whichever worker
        # they free first; another backend's runs on the pipeline's far-field worker while this
        # thread makes the grid's (its start is a call made below, after the far field's began).
        finish = start_estimate(backend, frame)
        finish_far = (start_estimate(far_backend, frame, self._far_worker(far_backend))
                      if far_backend is not None else None)
        estimate = finish()
        t1 = time.perf_counter()
        estimate.check_grid(config.grid)
        timings = {"estimate": 1e3 * (t1 - t0)}
        far = None
        if finish_far is not None:
            far = self._far_estimate(finish_far, config)
            t2 = time.perf_counter()
            timings["estimate_far"] = 1e3 * (t2 - t1)  # what the far field adds to the frame's time
            t1 = t2
        if before_map is not None:
            before_map()
            t1 = time.perf_counter()  # the map's and the preview's times leave the wait out
        mapped = self._map_stage(frame, estimate, config, far)
        if mapped is not None:
            timings["map"] = 1e3 * (time.perf_counter() - t1)
            preview, window, fusion, base = mapped
            return PipelineOutput(frame, estimate, preview, timings, window, fusion, base, far)
        preview = self._frame_preview(estimate, frame, config)
        timings["preview"] = 1e3 * (time.perf_counter() - t1)
        return PipelineOutput(frame, estimate, preview, timings, far=far)

    def _far_worker(self, far_backend: Backend) -> ThreadPoolExecutor | None:
        """The thread that makes the far field's estimates of a backend without workers of its
        own (started with the first; None for one that has them)."""
        if isinstance(far_backend, SubmitsEstimates):
            return None
        if self._far_thread is None:
            self._far_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="roadbev-far-field")
        return self._far_thread

    @staticmethod
    def _far_estimate(finish: Callable[[], Estimate], config: RoadbevConfig) -> Estimate:
        """The far-field backend's estimate (``finish``: :func:`start_estimate`'s call), all NaN
        where the far-field grid is out of view at the frame's attitude (a steep pitch sees the
        road only to 9 m)."""
        far_grid = config.far_field.grid(config.grid)
        try:
            estimate = finish()
        except FrameError:  # the far-field grid is not in the image (the frame itself was fine)
            return _no_estimate(far_grid)
        estimate.check_grid(far_grid)
        return estimate

    def _base_pose(self, stamp_ns: int) -> PlanarPose:
        """``base_link``'s planar pose at a frame: the odometry's, else dead reckoned from the
        speed along the IMU's yaw.

        Raises:
            EgoMotionStale: no pose at the stamp.
        """
        with self._lock:
            if self._odometry_seen:
                return self.ego.pose_at(stamp_ns)
            try:
                q = self.imu.orientation_at(stamp_ns)
            except ImuStale as exc:
                raise EgoMotionStale(f"no IMU yaw to dead reckon with: {exc}") from None
        speed = self.speed_at(stamp_ns)
        if speed is None:
            raise EgoMotionStale("no odometry and no recent speed")
        yaw = float(planar_yaw(quaternion_to_rotation(*q)))
        with self._lock:
            return self.ego.dead_reckon(stamp_ns, speed, yaw)

    def _map_stage(self, frame: Frame, estimate: Estimate, config: RoadbevConfig, far: Estimate | None = None
                   ) -> tuple[PreviewProfiles | None, MapWindow | None, FrameFusion | None, PlanarPose | None] | None:
        """Fuse the estimate (and the far-field one, ``far``, with the frame's alignment:
        :meth:`roadbev_core.fusion.FusedMap.integrate_far`) and read the preview off the map
        (None: the map is off).

        With the map on every preview is a contact-plane one in ``base_link`` (one stream:
        docs/concepts/preview.md, "One reference per drive"): before the map holds three tyre
        contacts its plane is the road's ahead (``source`` ``"road"``) or the body's (``"body"``), with that plane's
        sigma; a frame without a pose (stale odometry: counted in ``map_skipped``) is not fused
        and its preview comes from this frame alone (:meth:`_frame_only_preview`).
        """
        if not self.map_active:
            return None
        try:
            base = self._base_pose(frame.stamp_ns)
        except EgoMotionStale as exc:
            reason = str(exc).split(" (")[0]
            self.map_skipped[reason] = self.map_skipped.get(reason, 0) + 1
            return self._frame_only_preview(frame, estimate, config, far), None, None, None
        position, R_mount = self.camera_mount
        if self.fused is None:
            self.fused = self._map_factory(map_settings(config, position))
        fused = self.fused
        placement = place_frame(base, frame.attitude, position, R_mount)
        p = config.preview
        plane = contact_plane_on_map(fused, placement, config.vehicle, tyre_width_m=p.tyre_width_m,
                                     spacing_m=p.spacing_m)[2]
        plane_z = None
        if plane.source == "map" and fused.base_z is not None:
            plane_z = fused.base_z + plane.height_m  # the contact plane under base_link's origin
        fusion = fused.integrate(estimate.elevation, estimate.uncertainty, config.grid, placement, frame.stamp_ns,
                                 base_z_prediction=fused.predicted_base_z(plane_z))
        self._integrate_far(fused, far, config, placement, frame.stamp_ns)
        preview = self._map_preview(fused, placement, config,
                                    base.speed if self._odometry_seen else self.speed_at(frame.stamp_ns))
        window = fused.window(base, frame.stamp_ns)
        self.last_map = window
        return preview, window, fusion, base

    def _map_preview(self, fused: FusedMap, placement: FramePlacement, config: RoadbevConfig,
                     speed: float | None) -> PreviewProfiles | None:
        """The contact-plane wheel-track profiles of ``fused`` at ``placement`` (``base_link``)."""
        if not self._with_preview:
            return None
        p = config.preview
        return map_preview(fused, placement, config.vehicle, tyre_width_m=p.tyre_width_m, spacing_m=p.spacing_m,
                           rear_axle=p.rear_axle, vehicle_speed=speed, max_gap_m=p.max_gap_m)

    @staticmethod
    def _integrate_far(fused: FusedMap, far: Estimate | None, config: RoadbevConfig, placement: FramePlacement,
                       stamp_ns: int) -> None:
        """Fuse the far-field estimate of the frame just fused (nothing without one)."""
        far_grid = config.far_grid
        if far is not None and far_grid is not None:
            fused.integrate_far(far.elevation, far.uncertainty, far_grid, placement, stamp_ns)

    def _frame_only_preview(self, frame: Frame, estimate: Estimate, config: RoadbevConfig,
                            far: Estimate | None = None) -> PreviewProfiles | None:
        """The contact-plane preview of one frame on its own (the map cannot place it): the frame
        fused into an empty map at the origin, so its plane is the road's it sees ahead (or the
        body's), with the last known speed."""
        speed = self.latest_speed(frame.stamp_ns)
        position, R_mount = self.camera_mount
        alone = self._map_factory(map_settings(config, position))
        placement = place_frame(PlanarPose(frame.stamp_ns, 0.0, 0.0, 0.0, speed or 0.0), frame.attitude, position,
                                R_mount)
        alone.integrate(estimate.elevation, estimate.uncertainty, config.grid, placement, frame.stamp_ns,
                        base_z_prediction=0.0)
        self._integrate_far(alone, far, config, placement, frame.stamp_ns)
        return self._map_preview(alone, placement, config, speed)

    def _frame_preview(self, estimate: Estimate, frame: Frame, config: RoadbevConfig) -> PreviewProfiles | None:
        """The per-frame wheel-track profiles of an estimate (``roadbev_road``)."""
        if not self._with_preview:
            return None
        p = config.preview
        return wheel_track_profiles(
            estimate.elevation, estimate.uncertainty, config.grid,
            track_offsets_m=p.track_offsets_m, tyre_width_m=p.tyre_width_m, spacing_m=p.spacing_m,
            vehicle_speed=self.speed_at(frame.stamp_ns), reference_distance=p.reference_distance_m,
            max_gap_m=p.max_gap_m,
        )

    def warm_up(self) -> None:
        """Run the backend once on a blank frame, so one-time costs (torch kernels and thread
        pools, OpenCV buffers; more on the networks) stay out of the first real frame. A backend
        that cannot run on the stand-in rig is simply not warmed.

        The stand-in is the RSRD half-resolution rig at its full 960 x 528: an ONNX engine
        prepares per input shape (OpenVINO compiles a fixed-shape graph for each one it meets,
        and the int8 graph's first run at a new shape takes over a second), so a warm-up at
        another size would leave that cost to the first real frame of the common rig, and a node
        at 5 Hz would drop the frames that arrive meanwhile."""
        camera = StereoCamera.rsrd_half()
        blank = np.zeros((camera.height, camera.width, 3), np.uint8)
        with self._lock:
            backends = [b for b in (self.backend, self.far_backend, self.pace.near, self.pace.far) if b is not None]
        flush_denormals()
        for backend in backends:
            frame = Frame(blank, blank if backend.needs_stereo else None, camera, Attitude.from_degrees(0.0, 19.0))
            with contextlib.suppress(Exception):  # a warm-up failure must never stop the caller
                backend.estimate(frame)


class OdometryFeed:
    """Recorded odometry samples handed to a pipeline as a live stream would hand them: before a
    frame, the samples up to and including the first one at or after its stamp."""

    def __init__(self, samples: Iterable[PlanarPose]) -> None:
        self._samples = iter(samples)
        self._pending: PlanarPose | None = next(self._samples, None)

    def until(self, pipeline: Pipeline, stamp_ns: int) -> None:
        """Add the samples a frame at ``stamp_ns`` waits for (bad samples are skipped, as live)."""
        while self._pending is not None and not pipeline.ego.brackets(stamp_ns):
            with contextlib.suppress(RoadbevError):
                pipeline.add_odometry(self._pending)
            self._pending = next(self._samples, None)


class ImuFeed:
    """Recorded IMU samples handed to a pipeline as a live stream would hand them.

    Before a frame at stamp ``t`` the samples up to and including the first one at or after
    ``t`` are added (what the node waits for before it computes the attitude), so the attitude
    of a frame offline is the one the node computes.
    """

    def __init__(self, samples: Iterable[ImuSample]) -> None:
        self._samples = iter(samples)
        self._pending: ImuSample | None = next(self._samples, None)

    def until(self, pipeline: Pipeline, stamp_ns: int) -> None:
        """Add the samples a frame at ``stamp_ns`` waits for (bad samples are skipped, as live)."""
        while self._pending is not None and not pipeline.attitude_ready(stamp_ns):
            with contextlib.suppress(RoadbevError):
                pipeline.add_imu(self._pending.stamp_ns, self._pending.orientation_xyzw)
            self._pending = next(self._samples, None)


def replay(
    pipeline: Pipeline,
    frames: Iterable[Any],
    imu: Iterable[ImuSample],
    *,
    inputs_of: Callable[[Any], CameraInput],
    odometry: Iterable[PlanarPose] = (),
) -> Iterator[tuple[Any, PipelineOutput | RoadbevError]]:
    """Drive ``pipeline`` offline: IMU and odometry samples and frames merged in time order
    (:class:`ImuFeed`, :class:`OdometryFeed`).

    Args:
        frames: recorded items in stamp order (anything ``inputs_of`` turns into a CameraInput).
        imu: IMU samples in stamp order.
        inputs_of: item -> its camera set.
        odometry: odometry samples in stamp order (none: the map, if on, dead reckons).

    Yields:
        (item, output) per frame, or (item, error) for a frame the pipeline refused (bad input:
        no attitude, a malformed frame): the caller counts it and goes on.
    """
    feed = ImuFeed(imu)
    odometry_feed = OdometryFeed(odometry)
    for item in frames:
        inputs = inputs_of(item)
        feed.until(pipeline, inputs.stamp_ns)
        odometry_feed.until(pipeline, inputs.stamp_ns)
        try:
            yield item, pipeline.process(inputs)
        except RoadbevError as exc:
            yield item, exc
