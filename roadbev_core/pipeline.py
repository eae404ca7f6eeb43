"""The ROS-free pipeline: what a vehicle delivers in, the outputs out, one object for every entry point.

The node, ``roadbev eval``, the online evaluation, the demo and the benchmarks all drive a
:class:`Pipeline`, so a number in one is the number in all::

    IMU samples ──► add_imu ──► ImuBuffer (roadbev_core.attitude: the one attitude path)
    speed       ──► add_speed                                   │
    CameraInput ──► process ──► attitude at the stamp ─► Frame ─► backend.estimate ─► Estimate
                                                                          │
                                              wheel_track_profiles ◄──────┘ ─► PipelineOutput

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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roadbev_core.attitude import ImuBuffer, ImuSample, ImuStale
from roadbev_core.backends import Backend, BackendError, create
from roadbev_core.config import RoadbevConfig, StereoCamera, check_image_size
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame
from roadbev_core.geometry import Attitude
from roadbev_core.preview import PreviewError, PreviewProfiles, check_tracks, wheel_track_profiles
from roadbev_core.runtime import configure_threads, flush_denormals

__all__ = [
    "SPEED_MAX_AGE_S",
    "BackendFactory",
    "CameraInput",
    "ImuFeed",
    "Pipeline",
    "PipelineOutput",
    "build_backend",
    "replay",
]

# create(name, grid, **options) -> Backend; injectable so tests can run a stub backend.
BackendFactory = Callable[..., Backend]
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
            (:func:`roadbev_core.evaluation.pipeline_for`: a validated config always fits).
        timings_ms: ``estimate`` and ``preview`` wall times (the backend's own stages are in
            ``estimate.timings_ms``).
    """

    frame: Frame
    estimate: Estimate
    preview: PreviewProfiles | None
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def stamp_ns(self) -> int:
        return self.frame.stamp_ns


def build_backend(config: RoadbevConfig, factory: BackendFactory | None = None) -> Backend:
    """The config's backend on the config's grid.

    Any failure while building (a missing checkpoint, an option the backend refuses, a
    checkpoint whose network cannot be allocated) is a :class:`BackendError` with the reason:
    a parameter change must never take a running node down.

    Raises:
        BackendError: the backend cannot be built.
    """
    name = config.backend.name
    try:
        return (factory or create)(name, config.grid, **config.backend.options_of())
    except RoadbevError as exc:
        raise BackendError(f"backend {name!r} cannot run: {exc}") from exc
    except Exception as exc:  # any failure of a backend constructor is a refusal, never a crash
        raise BackendError(f"backend {name!r} cannot run: {type(exc).__name__}: {exc}") from exc


class Pipeline:
    """Camera sets, IMU and speed in; estimates and previews out (see the module docstring).

    Args:
        config: a validated config (:meth:`RoadbevConfig.from_params`).
        backend_factory: ``factory(name, grid, **options) -> Backend`` (default: the registry).
        configure_process: apply the config's thread count process-wide (the node and the
            command line do; a library user embedding the pipeline may keep its own settings).

    Raises:
        BackendError: the backend cannot be built.
    """

    def __init__(
        self,
        config: RoadbevConfig,
        *,
        backend_factory: BackendFactory | None = None,
        configure_process: bool = True,
    ) -> None:
        self._factory = backend_factory
        self._configure_process = configure_process
        self._lock = threading.Lock()
        self.config = config
        self.backend = build_backend(config, backend_factory)
        self.imu = self._imu_buffer(config)
        self._speed: tuple[int, float] | None = None  # (stamp ns, m/s)
        self._with_preview = self._tracks_fit(config)
        if configure_process:
            configure_threads(config.backend.inference_threads)

    # --- configuration -------------------------------------------------------------------------
    @staticmethod
    def _imu_buffer(config: RoadbevConfig) -> ImuBuffer:
        return ImuBuffer(
            max_age_s=config.imu.max_age_s,
            max_gap_s=config.imu.max_age_s,
            horizon_s=config.imu.buffer_s,
            imu_to_camera_rpy_deg=config.imu.imu_to_camera_rpy_deg,
        )

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
        with self._lock:
            self.config = config
            self.backend = backend
            self._with_preview = self._tracks_fit(config)
            if config.imu != old.imu:
                self.imu.max_age_s = self.imu.max_gap_s = config.imu.max_age_s
                self.imu.horizon_s = config.imu.buffer_s
                self.imu.imu_to_camera_rpy_deg = config.imu.imu_to_camera_rpy_deg
        if self._configure_process and config.backend.inference_threads != old.backend.inference_threads:
            configure_threads(config.backend.inference_threads)

    def reset(self) -> None:
        """Forget the IMU history and the speed (the clock jumped back: a bag started again)."""
        with self._lock:
            self.imu.clear()
            self._speed = None

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

    def attitude_ready(self, stamp_ns: int) -> bool:
        """Whether the IMU has a sample at or after ``stamp_ns`` (the attitude will not change)."""
        with self._lock:
            return self.imu.brackets(stamp_ns)

    def wait_for_attitude(self, stamp_ns: int, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> float:
        """Wait (live) up to ``timeout_s`` for an IMU sample at or after ``stamp_ns``, so the
        attitude is interpolated rather than taken from an older sample; returns the seconds
        waited (``stop()`` true ends the wait early)."""
        start = time.monotonic()
        while not self.attitude_ready(stamp_ns) and time.monotonic() - start < timeout_s and not stop():
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

    # --- processing ----------------------------------------------------------------------------
    def process(self, inputs: CameraInput, attitude: Attitude | None = None) -> PipelineOutput:
        """Estimate the elevation and the preview for one camera set.

        Args:
            inputs: the images, rig and stamp.
            attitude: the camera attitude when it is known otherwise (synthetic data); None =
                from the IMU samples added so far.

        Raises:
            ConfigError: an image larger than the configured limit.
            ImuStale: no trustworthy attitude (see :meth:`attitude_at`).
            FrameError: images and calibration that do not fit together.
            PreviewError: the estimate cannot be sampled along the wheel tracks.
        """
        with self._lock:
            config, backend = self.config, self.backend
        check_image_size(inputs.camera.width, inputs.camera.height)
        if attitude is None:
            attitude = self.attitude_at(inputs.stamp_ns)
        frame = Frame(inputs.left, inputs.right, inputs.camera, attitude, inputs.stamp_ns)
        return self._run(frame, config, backend)

    def process_frame(self, frame: Frame) -> PipelineOutput:
        """:meth:`process` for a frame whose attitude is already known."""
        return self.process(CameraInput(frame.left, frame.right, frame.camera, frame.stamp_ns), frame.attitude)

    def _run(self, frame: Frame, config: RoadbevConfig, backend: Backend) -> PipelineOutput:
        flush_denormals()
        t0 = time.perf_counter()
        estimate = backend.estimate(frame)
        t1 = time.perf_counter()
        estimate.check_grid(config.grid)
        p = config.preview
        preview = None
        if self._with_preview:
            preview = wheel_track_profiles(
                estimate.elevation, estimate.uncertainty, config.grid,
                track_offsets_m=p.track_offsets_m, tyre_width_m=p.tyre_width_m, spacing_m=p.spacing_m,
                vehicle_speed=self.speed_at(frame.stamp_ns), reference_distance=p.reference_distance_m,
            )
        t2 = time.perf_counter()
        return PipelineOutput(frame, estimate, preview, {"estimate": 1e3 * (t1 - t0), "preview": 1e3 * (t2 - t1)})

    def warm_up(self) -> None:
        """Run the backend once on a blank frame, so one-time costs (torch kernels and thread
        pools, OpenCV buffers: about 30 ms on bev_sweep, more on the networks) stay out of the
        first real frame. A backend that cannot run on the stand-in rig is simply not warmed."""
        camera = StereoCamera.rsrd_half().scaled(0.5)
        blank = np.zeros((camera.height, camera.width, 3), np.uint8)
        with self._lock:
            backend = self.backend
        frame = Frame(blank, blank if backend.needs_stereo else None, camera, Attitude.from_degrees(0.0, 19.0))
        flush_denormals()
        with contextlib.suppress(Exception):  # a warm-up failure must never stop the caller
            backend.estimate(frame)


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
) -> Iterator[tuple[Any, PipelineOutput | RoadbevError]]:
    """Drive ``pipeline`` offline: IMU samples and frames merged in time order (:class:`ImuFeed`).

    Args:
        frames: recorded items in stamp order (anything ``inputs_of`` turns into a CameraInput).
        imu: IMU samples in stamp order.
        inputs_of: item -> its camera set.

    Yields:
        (item, output) per frame, or (item, error) for a frame the pipeline refused (bad input:
        no attitude, a malformed frame): the caller counts it and goes on.
    """
    feed = ImuFeed(imu)
    for item in frames:
        inputs = inputs_of(item)
        feed.until(pipeline, inputs.stamp_ns)
        try:
            yield item, pipeline.process(inputs)
        except RoadbevError as exc:
            yield item, exc
