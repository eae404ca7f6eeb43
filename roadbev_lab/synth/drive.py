"""Synthetic drives and single samples: stereo frames, IMU, LiDAR-like points and labels.

A drive is a vehicle going along a synthetic road at constant speed. Its body moves on the
suspension: a second-order low-pass response (body modes 1.2-1.8 Hz) to the road under the four
wheels, plus a slow random component for what the road model leaves out (driver inputs, load),
scaled to the attitude spread of the real RSRD drives. The IMU (100 Hz) reports that motion; each
5 Hz stereo frame's attitude is the slerp of the IMU orientations at its stamp, so a consumer
that interpolates the IMU recovers the exact attitude the frame was rendered with.

Ground truth is a dense LiDAR-like point cloud sampled from the height field over the grid
(jittered 1 cm spacing, optional noise, dropout and range fall-off) turned into labels by
:func:`roadbev_core.labels.elevation_map`, exactly as the real labels are made. With a far-field
grid (``DriveConfig.far_grid``, ``make_sample(far_grid=...)``) the same is done over it too
(``DriveSample.far_truth``), after everything else a frame draws, so the frame and its grid's
truth are those of the same drive without it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple, cast

import numpy as np

from roadbev_core.attitude import quaternion_from_rotation, slerp
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame
from roadbev_core.geometry import (
    Attitude,
    attitude_from_rotation,
    quaternion_to_rotation,
    road_to_camera,
    rotation_from_rpy,
)
from roadbev_core.labels import ElevationLabel, elevation_map
from roadbev_lab.synth.appearance import REAL_ROAD, AppearanceRange
from roadbev_lab.synth.heightfield import FEATURE_NAMES, SynthError
from roadbev_lab.synth.render import LOOK_AHEAD_M, CameraPose, render_stereo, sensor_image, shift_rows
from roadbev_lab.synth.scene import RoadConfig, Scene, build_scene

__all__ = [
    "RSRD_ATTITUDE",
    "DriveConfig",
    "DriveSample",
    "ImuSample",
    "LidarConfig",
    "SyntheticDrive",
    "check_far_grid",
    "corner_heights",
    "make_sample",
    "render_sample",
    "sample_points",
    "visible_points",
]

GRAVITY = 9.80665
MAX_DRIVE_M = 600.0  # the road rasters of a drive are held in memory (1 cm cells, 7.2 m wide)

# Left-camera attitude of the 1,581 real RSRD samples (train + test), degrees, derived with
# geometry.rsrd_camera_attitude from the pinned sample_info and calibrations: mean, standard
# deviation, extremes, and the mean within-sequence standard deviation (the part that moves
# while driving; the rest differs between drives).
RSRD_ATTITUDE = {
    "pitch_mean": 19.137,
    "pitch_std": 0.682,
    "pitch_min": 16.216,
    "pitch_max": 21.607,
    "pitch_std_in_drive": 0.354,
    "roll_mean": -0.377,
    "roll_std": 0.780,
    "roll_min": -2.457,
    "roll_max": 1.955,
    "roll_std_in_drive": 0.388,
}

# Vehicle geometry relative to the left camera (m): axles ahead/behind, half track.
FRONT_AXLE = 0.6
WHEELBASE = 2.7
HALF_TRACK = 0.8
PITCH_PER_ACCEL = 0.003  # body pitch (rad) per m/s^2 of braking: about 1.7 deg per g


class ImuSample(NamedTuple):
    """One IMU message (camera body == IMU body, orientation relative to ENU).

    Attributes:
        stamp_ns: time (ns).
        orientation_xyzw: unit quaternion of the body in ENU.
        angular_velocity: body rates (rad/s, body axes).
        linear_acceleration: specific force (m/s^2, body axes; +9.81 on z when level at rest).
    """

    stamp_ns: int
    orientation_xyzw: tuple[float, float, float, float]
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]


class DriveSample(NamedTuple):
    """One stereo frame with its ground truth.

    Attributes:
        frame: the images, rig, true attitude and stamp.
        truth: labels from the LiDAR-like points (elevation NaN where no point fell).
        points_road: [N, 3] float32 LiDAR-like points in the road frame.
        far_truth: the labels of the far-field grid (None without one).
    """

    frame: Frame
    truth: ElevationLabel
    points_road: np.ndarray
    far_truth: ElevationLabel | None = None


@dataclass(frozen=True)
class LidarConfig:
    """The LiDAR-like ground truth.

    Attributes:
        spacing_m: mean point spacing on the ground (jittered grid).
        noise_m: Gaussian range-like noise on z (1-sigma, m).
        dropout: share of points removed at random.
        range_falloff: points beyond the grid's near edge are kept with probability
            ``(x_min / x) ** range_falloff`` (0 = uniform density).
        margin_m: points are sampled this far beyond the grid on every side.
    """

    spacing_m: float = 0.01
    noise_m: float = 0.0
    dropout: float = 0.0
    range_falloff: float = 0.0
    margin_m: float = 0.03

    def __post_init__(self) -> None:
        if not 0.002 <= self.spacing_m <= 0.1:
            raise SynthError(f"LiDAR spacing must be in [0.002, 0.1] m, got {self.spacing_m}")
        if self.noise_m < 0 or not 0.0 <= self.dropout < 1.0 or self.range_falloff < 0:
            raise SynthError("LiDAR noise must be >= 0, dropout in [0, 1), range_falloff >= 0")


@dataclass(frozen=True)
class DriveConfig:
    """A synthetic drive.

    Attributes:
        frames: stereo frames to render.
        speed_mps: vehicle speed (m/s).
        frame_rate_hz, imu_rate_hz: camera and IMU rates.
        seed: everything (road, appearance, motion, noise) follows from it.
        road: the road.
        camera: the stereo rig.
        grid: the BEV grid (labels and base height).
        far_grid: a far-field grid to label too (:meth:`roadbev_core.config.FarFieldConfig.grid`;
            None: none).
        start_stamp_ns: time of the first IMU sample.
        lidar: the ground-truth point cloud.
        gyro_noise, accel_noise: white noise on the IMU rates (rad/s) and specific force (m/s^2),
            1-sigma; the orientation is the filtered (exact) one.
    """

    frames: int = 20
    speed_mps: float = 5.0
    frame_rate_hz: float = 5.0
    imu_rate_hz: float = 100.0
    seed: int = 0
    road: RoadConfig = field(default_factory=RoadConfig)
    camera: StereoCamera = field(default_factory=StereoCamera.rsrd_half)
    grid: GridSpec = field(default_factory=GridSpec)
    start_stamp_ns: int = 1_700_000_000_000_000_000
    lidar: LidarConfig = field(default_factory=LidarConfig)
    gyro_noise: float = 0.002
    accel_noise: float = 0.03
    far_grid: GridSpec | None = None

    def __post_init__(self) -> None:
        check_far_grid(self.far_grid)
        if self.frames < 1:
            raise SynthError(f"a drive needs at least one frame, got {self.frames}")
        if not 0.0 <= self.speed_mps <= 40.0:
            raise SynthError(f"speed must be in [0, 40] m/s, got {self.speed_mps}")
        if not 0.1 <= self.frame_rate_hz <= 60.0:
            raise SynthError(f"frame rate must be in [0.1, 60] Hz, got {self.frame_rate_hz}")
        if not self.frame_rate_hz < self.imu_rate_hz <= 2000.0:
            raise SynthError(f"IMU rate must exceed the frame rate and be <= 2000 Hz, got {self.imu_rate_hz}")
        if self.speed_mps * self.frames / self.frame_rate_hz > MAX_DRIVE_M:
            raise SynthError(
                f"a drive of {self.speed_mps * self.frames / self.frame_rate_hz:.0f} m is longer than "
                f"{MAX_DRIVE_M:.0f} m (its rasters take ~1 GB per km); split it into several drives"
            )
        if self.start_stamp_ns < 0:
            raise SynthError("start_stamp_ns must be >= 0")
        if self.gyro_noise < 0 or self.accel_noise < 0:
            raise SynthError("IMU noise must be >= 0")


def check_far_grid(far_grid: GridSpec | None) -> None:
    """Refuse a far-field grid beyond the road the scenes draw (:data:`LOOK_AHEAD_M`; farther the road
    is its bare plane, with no texture to match).

    Raises:
        SynthError: naming the limit.
    """
    if far_grid is not None and far_grid.x_max > LOOK_AHEAD_M - 2.0:
        raise SynthError(f"a far-field grid to {far_grid.x_max:g} m reaches beyond the {LOOK_AHEAD_M - 2.0:g} m of "
                         "road the scenes draw ahead of the camera")


# --- rotations ------------------------------------------------------------------------------
def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) of a rotation matrix (small angles are exact enough)."""
    angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0)))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    return v if angle < 1e-9 else v * angle / math.sin(angle)


# --- motion -----------------------------------------------------------------------------------
def _cascade(x: np.ndarray, a: float, stages: int) -> np.ndarray:
    """``stages`` first-order low-passes y[k] = a y[k-1] + (1 - a) x[k] in series, from rest."""
    for _ in range(stages):
        y = np.empty_like(x)
        acc = 0.0
        for k in range(x.shape[0]):
            acc = a * acc + (1 - a) * x[k]
            y[k] = acc
        x = y
    return x


def _smooth_process(n: int, dt: float, tau: float, std: float, rng: np.random.Generator) -> np.ndarray:
    """[n] smooth stationary Gaussian process: white noise through four first-order low-passes
    of time constant ``tau`` (its first and second derivatives stay bounded, as body motion
    and the accelerometer need), with standard deviation ``std``.

    The scale comes from the filter's own gain (not from the sample), so short drives are not
    blown up to the full spread.
    """
    warm = int(8 * tau / dt) + 1  # brings the filters to steady state
    a = math.exp(-dt / tau)
    impulse = np.zeros(warm * 4)
    impulse[0] = 1.0
    gain = math.sqrt(float(np.sum(_cascade(impulse, a, 4) ** 2)))  # output std for unit white noise
    x = _cascade(rng.standard_normal(n + warm), a, 4)[warm:]
    return x * (std / gain)


def _second_order(u: np.ndarray, dt: float, freq_hz: float, damping: float, substeps: int = 10) -> np.ndarray:
    """Response [n] of a base-excited 2nd-order low-pass to the input [n] (starts at rest on u[0])."""
    wn = 2 * math.pi * freq_hz
    h = dt / substeps
    y, v = float(u[0]), 0.0
    out = np.empty_like(u)
    for k in range(u.shape[0]):
        target = u[k]
        for _ in range(substeps):
            acc = wn * wn * (target - y) - 2 * damping * wn * v
            v += acc * h
            y += v * h
        out[k] = y
    return out


def corner_heights(
    scene: Scene, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, corners: np.ndarray
) -> np.ndarray:
    """[len(corners), n] road height under tyres at body points ``corners`` [K, 2] (x, y) of a
    body at (x, y, yaw) [n]: the mean over the contact patch (-6, 0, +6 cm along the tyre)."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = []
    for ax, ay in np.asarray(corners, np.float64):
        total = np.zeros_like(x)
        for dx in (-0.06, 0.0, 0.06):  # contact patch along x
            wx = x + c * (ax + dx) - s * ay
            wy = y + s * (ax + dx) + c * ay
            total += scene.height(wx, wy)
        out.append(total / 3)
    return np.array(out)


def _wheel_heights(scene: Scene, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, ...]:
    """Mean road height under the front, rear, left and right wheels (tyre patch averaged)."""
    corners = [(FRONT_AXLE, HALF_TRACK), (FRONT_AXLE, -HALF_TRACK),
               (FRONT_AXLE - WHEELBASE, HALF_TRACK), (FRONT_AXLE - WHEELBASE, -HALF_TRACK)]
    heights = corner_heights(scene, x, y, yaw, np.array(corners))
    out = {(name, side): heights[2 * i + j] for i, name in enumerate(("front", "rear"))
           for j, side in enumerate(("left", "right"))}
    front = (out[("front", "left")] + out[("front", "right")]) / 2
    rear = (out[("rear", "left")] + out[("rear", "right")]) / 2
    left = (out[("front", "left")] + out[("rear", "left")]) / 2
    right = (out[("front", "right")] + out[("rear", "right")]) / 2
    return front, rear, left, right


def draw_mount_attitude(rng: np.random.Generator, *, in_drive: bool) -> tuple[float, float]:
    """Camera (roll, pitch) in degrees from the RSRD distribution.

    Args:
        in_drive: draw only the per-drive part (the suspension adds the in-drive spread);
            otherwise draw from the whole distribution (independent samples).
    """
    a = RSRD_ATTITUDE
    if in_drive:
        p_std = math.sqrt(a["pitch_std"] ** 2 - a["pitch_std_in_drive"] ** 2)
        r_std = math.sqrt(a["roll_std"] ** 2 - a["roll_std_in_drive"] ** 2)
    else:
        p_std, r_std = a["pitch_std"], a["roll_std"]
    pitch = float(np.clip(rng.normal(a["pitch_mean"], p_std), a["pitch_min"] + 0.5, a["pitch_max"] - 0.5))
    roll = float(np.clip(rng.normal(a["roll_mean"], r_std), a["roll_min"] + 0.5, a["roll_max"] - 0.5))
    return roll, pitch


# --- ground truth ---------------------------------------------------------------------------
def sample_points(
    scene: Scene, pose: CameraPose, grid: GridSpec, lidar: LidarConfig, rng: np.random.Generator,
    *, near_edge_m: float | None = None,
) -> np.ndarray:
    """[N, 3] float32 LiDAR-like road-frame points on the true surface over the grid.

    Args:
        near_edge_m: where the range fall-off starts (default the grid's ``x_min``; a far-field
            grid's points thin out as the same LiDAR's, from the grid's near edge).
    """
    m = lidar.margin_m
    xs = np.arange(grid.x_min - m, grid.x_max + m, lidar.spacing_m)
    ys = np.arange(grid.y_min - m, grid.y_max + m, lidar.spacing_m)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    jitter = rng.uniform(-0.5, 0.5, (2, *gx.shape)) * lidar.spacing_m
    pts = np.stack([gx + jitter[0], gy + jitter[1], np.zeros_like(gx)], axis=-1).reshape(-1, 3)
    keep = np.ones(pts.shape[0], bool)
    if lidar.dropout > 0:
        keep &= rng.random(pts.shape[0]) >= lidar.dropout
    if lidar.range_falloff > 0:
        start = grid.x_min if near_edge_m is None else near_edge_m
        prob = np.minimum(1.0, (start / np.maximum(pts[:, 0], 1e-3)) ** lidar.range_falloff)
        keep &= rng.random(pts.shape[0]) < prob
    pts = pts[keep]
    world = pose.road_to_world(pts, grid.base_height)
    z_world = scene.height(world[:, 0], world[:, 1])
    pts[:, 2] = z_world - (pose.z - grid.base_height)
    if lidar.noise_m > 0:
        pts[:, 2] += rng.normal(0.0, lidar.noise_m, pts.shape[0])
    return pts.astype(np.float32)


def render_sample(
    scene: Scene,
    pose: CameraPose,
    camera: StereoCamera,
    grid: GridSpec,
    lidar: LidarConfig,
    rng: np.random.Generator,
    stamp_ns: int,
    attitude: Attitude | None = None,
    *,
    hide_occluded: bool = False,
    far_grid: GridSpec | None = None,
) -> DriveSample:
    """Render the stereo pair at ``pose``, sample the LiDAR-like points, make the labels.

    Args:
        hide_occluded: mark cells the left camera cannot see NaN in the labels (outside its
            image, or more than half of the cell's points behind a nearer surface: the far
            side of a bump, the near wall of a pothole); ``points_road`` keeps every point.
        far_grid: also label this far-field grid (``far_truth``), from points drawn after
            everything else (the rest of the sample is the one without it).
    """
    road = scene.config
    left, right = render_stereo(scene, camera, pose)
    lum = left.radiance.mean(axis=2)
    ground = np.isfinite(left.depth)
    median = float(np.median(lum[ground])) if ground.any() else float(np.median(lum))
    exposure = (115.0 / 255.0) ** 2.2 / max(median, 1e-4) * rng.uniform(0.8, 1.2)
    # the right camera: another overall gain and a slightly different colour balance
    gain_right = (1.0 + rng.uniform(-road.gain_mismatch, road.gain_mismatch)) * (
        1.0 + rng.uniform(-0.25, 0.25, 3) * road.gain_mismatch
    )
    sense = functools.partial(
        sensor_image,
        noise_sigma=road.noise_sigma,
        blur_sigma_px=road.blur_sigma_px,
        jpeg_quality=road.jpeg_quality,
        vignetting=road.vignetting,
    )
    img_left = sense(left.radiance, exposure=exposure, gain=1.0, rng=rng)
    img_right = None
    if right is not None:
        # a rectification residual moves the scene in the right image, not its sensor noise
        radiance = shift_rows(right.radiance, road.row_offset_px) if road.row_offset_px else right.radiance
        img_right = sense(radiance, exposure=exposure, gain=tuple(gain_right), rng=rng)
    points = sample_points(scene, pose, grid, lidar, rng)
    frame = Frame(
        left=img_left, right=img_right, camera=camera, attitude=attitude or pose.attitude, stamp_ns=int(stamp_ns)
    )
    def labels(points: np.ndarray, on: GridSpec) -> ElevationLabel:
        truth = elevation_map(points, on)
        if not hide_occluded:
            return truth
        seen = elevation_map(points[visible_points(scene, points, pose, camera, on.base_height, left.depth)], on)
        hidden = truth.mask & (2 * seen.count < truth.count)
        return ElevationLabel(
            elevation=np.where(hidden, np.float32(np.nan), truth.elevation).astype(np.float32),
            mask=truth.mask & ~hidden,
            count=np.where(hidden, 0, truth.count).astype(truth.count.dtype),
        )

    truth = labels(points, grid)
    far_truth = None
    if far_grid is not None:
        far_truth = labels(sample_points(scene, pose, far_grid, lidar, rng, near_edge_m=grid.x_min), far_grid)
    return DriveSample(frame=frame, truth=truth, points_road=points, far_truth=far_truth)


def visible_points(
    scene: Scene,
    points_road: np.ndarray,
    pose: CameraPose,
    camera: StereoCamera,
    base_height: float,
    depth: np.ndarray,
    *,
    step_m: float = 0.02,
    tolerance_m: float = 0.005,
) -> np.ndarray:
    """[N] bool: which road-frame points on the surface the left camera sees.

    A point is seen when it projects inside the image in front of the camera and the line of
    sight from the camera to it (on the true surface, without LiDAR noise) stays above the
    surface. Only points whose pixel in the rendered ``depth`` map shows a nearer surface
    (by 2 cm) are marched (every ``step_m`` horizontally, ``tolerance_m`` below the surface
    counts as blocked): the depth map narrows the search, the march decides.

    Args:
        points_road: [N, 3] in the road frame of ``pose`` (z is replaced by the true surface).
        depth: [H, W] optical-frame z of the surface seen at each pixel (inf for sky).
    """
    pts = np.asarray(points_road, np.float64)
    world = pose.road_to_world(pts, base_height)  # [N, 3]
    world[:, 2] = scene.height(world[:, 0], world[:, 1])
    on_surface = pose.world_to_road(world, base_height)
    cam = road_to_camera(on_surface, pose.attitude, base_height)  # [N, 3] optical
    z = cam[:, 2]
    ok = z > 0.05
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(camera.fx * cam[:, 0] / z + camera.cx)
        v = np.rint(camera.fy * cam[:, 1] / z + camera.cy)
    ok &= (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= camera.height - 1)
    seen = ok.copy()
    idx = np.flatnonzero(ok)
    surface = depth[v[idx].astype(np.int64), u[idx].astype(np.int64)]
    suspect = idx[surface < z[idx] - 0.02]
    if suspect.size == 0:
        return cast("np.ndarray", seen)
    origin = np.array([pose.x, pose.y, pose.z])
    p = world[suspect]  # [M, 3]
    horizontal = np.hypot(p[:, 0] - origin[0], p[:, 1] - origin[1])  # [M]
    top = float(np.max(scene.plane(p[:, 0], p[:, 1]))) + 0.5 + scene.displacement_range[1]
    drop = np.maximum(origin[2] - p[:, 2], 1e-3)
    reach = np.minimum((top - p[:, 2]) * horizontal / drop, horizontal)  # the ray is above ``top`` beyond
    blocked = np.zeros(suspect.size, bool)
    for chunk in np.array_split(np.arange(suspect.size), max(1, suspect.size // 4096)):
        n_steps = int(np.ceil(reach[chunk].max() / step_m))
        d = step_m * np.arange(1, n_steps + 1)[None, :]  # [1, J] back from the point toward the camera
        t = np.minimum(d / horizontal[chunk, None], 1.0)  # [m, J] fraction of the way to the camera
        q = p[chunk, None, :] + t[..., None] * (origin - p[chunk, None, :])  # [m, J, 3]
        below = q[..., 2] < scene.height(q[..., 0], q[..., 1]) - tolerance_m
        blocked[chunk] = np.any(below & (d <= reach[chunk, None]), axis=1)
    seen[suspect[blocked]] = False
    return cast("np.ndarray", seen)


# --- drives --------------------------------------------------------------------------------------
class SyntheticDrive:
    """A deterministic synthetic drive: 5 Hz stereo frames with labels and a 100 Hz IMU.

    Frames are rendered on demand (``drive[i]`` or iteration); the road, the motion and the IMU
    are made up front.
    """

    def __init__(self, config: DriveConfig | None = None) -> None:
        self.config = config = config or DriveConfig()
        seq = np.random.SeedSequence([int(config.seed) & 0xFFFFFFFF, 0xD417E])
        self._rng_motion, self._rng_frames = (np.random.default_rng(s) for s in seq.spawn(2))
        self._frame_seeds = self._rng_frames.integers(0, 2**63 - 1, config.frames)
        rng = self._rng_motion
        frame_dt = 1.0 / config.frame_rate_hz
        imu_dt = 1.0 / config.imu_rate_hz
        # Frames fall between IMU samples (a real camera is not triggered by the IMU).
        first = 2 * imu_dt + rng.uniform(0.1, 0.9) * imu_dt
        frame_t = first + np.arange(config.frames) * frame_dt
        n_imu = int(math.ceil((frame_t[-1] + 2 * imu_dt) / imu_dt)) + 1
        imu_t = np.arange(n_imu) * imu_dt
        self._imu_t = imu_t
        self._frame_t = frame_t
        self.frame_stamps_ns = [config.start_stamp_ns + int(round(t * 1e9)) for t in frame_t]
        self.imu_stamps_ns = [config.start_stamp_ns + int(round(t * 1e9)) for t in imu_t]

        # Trajectory: the speed drifts by a few per cent around the set speed (throttle, gentle
        # braking), the car wanders slowly inside its lane.
        speed = config.speed_mps * np.maximum(1.0 + _smooth_process(n_imu, imu_dt, 2.0, 0.05, rng), 0.0)
        x = np.concatenate([[0.0], np.cumsum((speed[1:] + speed[:-1]) / 2 * imu_dt)])
        self.scene = build_scene(config.road, config.seed, (-4.0, float(x[-1]) + LOOK_AHEAD_M + 2.0))
        lane_offset = rng.uniform(-0.4, 0.4)
        wander = _smooth_process(n_imu, imu_dt, 3.0, 0.08, rng)
        y = lane_offset + wander
        yaw = np.gradient(y, imu_dt) / np.maximum(speed, 0.5) if n_imu > 1 else np.zeros(1)
        yaw = np.clip(yaw, -0.05, 0.05)
        accel = np.gradient(speed, imu_dt) if n_imu > 1 else np.zeros(1)
        # Body on the suspension: filtered road input plus a slow random part.
        front, rear, left, right = _wheel_heights(self.scene, x, y, yaw)
        road_pitch = np.arctan2(rear - front, WHEELBASE)
        road_roll = np.arctan2(left - right, 2 * HALF_TRACK)
        road_heave = (front + rear) / 2
        a = RSRD_ATTITUDE
        # The RSRD attitudes already include the usual road slopes: the drive's mean slope is
        # taken out of the mount attitude so that the total stays in the real distribution.
        body_pitch = _second_order(road_pitch, imu_dt, 1.5, 0.35) - float(np.mean(road_pitch))
        body_roll = _second_order(road_roll, imu_dt, 1.8, 0.3) - float(np.mean(road_roll))
        heave = _second_order(road_heave, imu_dt, 1.2, 0.3)
        body_pitch += np.radians(_smooth_process(n_imu, imu_dt, 0.6, a["pitch_std_in_drive"] * 0.8, rng))
        body_pitch -= PITCH_PER_ACCEL * accel  # the nose dives when braking
        body_roll += np.radians(_smooth_process(n_imu, imu_dt, 0.6, a["roll_std_in_drive"] * 0.8, rng))
        heave += _smooth_process(n_imu, imu_dt, 0.4, 0.004, rng)
        mount_roll, mount_pitch = draw_mount_attitude(rng, in_drive=True)
        height_offset = float(np.clip(rng.normal(0.0, 0.008), -0.015, 0.015))
        heading = rng.uniform(-math.pi, math.pi)  # the road's direction in ENU
        roll = np.radians(mount_roll) + body_roll
        pitch = np.radians(mount_pitch) + body_pitch
        z = heave + config.grid.base_height + height_offset
        self._x, self._y, self._z, self._yaw, self._speed = x, y, z, yaw, speed
        self._heading = heading
        self._R = [
            rotation_from_rpy(float(r), float(p), float(heading + w)) for r, p, w in zip(roll, pitch, yaw, strict=True)
        ]
        self._q = np.array([quaternion_from_rotation(R) for R in self._R])
        for k in range(1, n_imu):  # keep the quaternion sign continuous
            if self._q[k] @ self._q[k - 1] < 0:
                self._q[k] = -self._q[k]
        # Specific force: R^T (a_world + g z).
        acc = np.zeros((n_imu, 3))  # in the road's world axes, then turned to ENU by the heading
        if n_imu > 2:
            acc[:, 0] = accel
            acc[:, 1] = np.gradient(np.gradient(y, imu_dt), imu_dt)
            acc[:, 2] = np.gradient(np.gradient(z, imu_dt), imu_dt)
        acc[:, :2] = acc[:, :2] @ np.array(
            [[math.cos(heading), math.sin(heading)], [-math.sin(heading), math.cos(heading)]]
        )
        acc[:, 2] += GRAVITY
        self._acc_body = np.einsum("kji,kj->ki", np.array(self._R), acc)
        self._acc_body += rng.normal(0.0, config.accel_noise, self._acc_body.shape)
        self._gyro_noise = rng.normal(0.0, config.gyro_noise, (n_imu, 3))

    def __len__(self) -> int:
        return self.config.frames

    def __iter__(self) -> Iterator[DriveSample]:
        for i in range(len(self)):
            yield self[i]

    def pose(self, index: int) -> tuple[CameraPose, Attitude]:
        """The left camera's pose at frame ``index`` and its attitude (slerp of the IMU)."""
        t = self._frame_t[index]
        imu_dt = 1.0 / self.config.imu_rate_hz
        k = int(math.floor(t / imu_dt))
        frac = (t - self._imu_t[k]) / imu_dt
        q = slerp(self._q[k], self._q[k + 1], frac)
        R = quaternion_to_rotation(*q)
        attitude = attitude_from_rotation(R)
        yaw_world = math.atan2(R[1, 0], R[0, 0])

        def lerp(arr: np.ndarray) -> float:
            return float(arr[k] * (1 - frac) + arr[k + 1] * frac)

        pose = CameraPose(
            x=lerp(self._x),
            y=lerp(self._y),
            z=lerp(self._z),
            attitude=attitude,
            yaw=math.remainder(yaw_world - self._heading, 2 * math.pi),
        )
        return pose, attitude

    def __getitem__(self, index: int) -> DriveSample:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} of a {len(self)}-frame drive")
        index %= len(self)
        pose, attitude = self.pose(index)
        rng = np.random.default_rng(int(self._frame_seeds[index]))
        c = self.config
        return render_sample(self.scene, pose, c.camera, c.grid, c.lidar, rng, self.frame_stamps_ns[index], attitude,
                             far_grid=c.far_grid)

    def trajectory(self) -> dict[str, np.ndarray]:
        """The left camera's path at the IMU stamps (road world frame: x along the road).

        Returns:
            ``stamp_ns`` [K] int64, ``x``, ``y``, ``z`` [K] (m), ``yaw`` [K] (rad, w.r.t. the
            road), ``speed`` [K] (m/s), ``heading`` (rad, the road's direction in ENU).
        """
        return {
            "stamp_ns": np.array(self.imu_stamps_ns, dtype=np.int64),
            "x": self._x.copy(),
            "y": self._y.copy(),
            "z": self._z.copy(),
            "yaw": self._yaw.copy(),
            "speed": self._speed.copy(),
            "heading": np.array(self._heading),
        }

    def imu_samples(self) -> list[ImuSample]:
        """The IMU stream (covers every frame stamp with samples on both sides)."""
        imu_dt = 1.0 / self.config.imu_rate_hz
        out = []
        n = len(self._R)
        for k in range(n):
            a, b = max(k - 1, 0), min(k + 1, n - 1)
            omega = _rotvec(self._R[a].T @ self._R[b]) / (max(b - a, 1) * imu_dt) + self._gyro_noise[k]
            q, acc = self._q[k], self._acc_body[k]
            out.append(
                ImuSample(
                    stamp_ns=self.imu_stamps_ns[k],
                    orientation_xyzw=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                    angular_velocity=(float(omega[0]), float(omega[1]), float(omega[2])),
                    linear_acceleration=(float(acc[0]), float(acc[1]), float(acc[2])),
                )
            )
        return out


# --- independent samples --------------------------------------------------------------------
def random_road(rng: np.random.Generator, appearance: AppearanceRange | None = REAL_ROAD) -> RoadConfig:
    """A random road configuration for training/evaluation sets.

    Args:
        rng: the draws.
        appearance: draw the pavement and camera appearance from this range too (after the
            other draws, so the road's geometry is the same with and without it; default the
            ``real-road`` range); None keeps the generator's own noise and a Lambertian
            pavement (the ``clean`` appearance of scene version 1).
    """
    road_class = str(rng.choice(list("ABCDE"), p=[0.1, 0.3, 0.35, 0.2, 0.05]))
    n_feat = int(rng.integers(1, 4))
    features = tuple(str(f) for f in rng.choice(FEATURE_NAMES, n_feat, replace=False))
    road = RoadConfig(
        road_class=road_class,
        features=features,
        surface=str(rng.choice(["asphalt", "concrete"], p=[0.8, 0.2])),
        cross_slope=float(rng.uniform(-0.03, 0.03)),
        grade=float(rng.uniform(-0.006, 0.006)),
        noise_sigma=float(rng.uniform(0.5, 3.0)),
        gain_mismatch=float(rng.uniform(0.0, 0.08)),
        jpeg_quality=None if rng.random() < 0.7 else int(rng.integers(70, 96)),
    )
    return road if appearance is None else appearance.draw(rng).apply(road)


def _place_in_grid(
    names: tuple[str, ...], grid: GridSpec, y_cam: float, rng: np.random.Generator
) -> list[tuple[str, float, float]]:
    """World centres (the camera at x = 0, y = ``y_cam``) of features inside the grid's window,
    kept apart where possible (a feature on top of another one reads as neither)."""
    placed: list[tuple[str, float, float]] = []
    for name in names:
        best, best_gap = (0.0, 0.0), -1.0
        for _ in range(12):
            x = float(rng.uniform(grid.x_min + 0.4, grid.x_max - 0.4))
            y = y_cam + float(rng.uniform(grid.y_min + 0.2, grid.y_max - 0.2))
            gap = min((math.hypot((x - px) / 1.2, y - py) for _, px, py in placed), default=9.0)
            if gap > best_gap:
                best, best_gap = (x, y), gap
            if gap >= 1.0:
                break
        placed.append((name, *best))
    return placed


def make_sample(
    seed: int,
    *,
    camera: StereoCamera | None = None,
    grid: GridSpec | None = None,
    road: RoadConfig | None = None,
    lidar: LidarConfig | None = None,
    appearance: AppearanceRange | None = REAL_ROAD,
    far_grid: GridSpec | None = None,
) -> DriveSample:
    """One independent random scene seen by a stationary-looking rig (deterministic per seed).

    The camera attitude is drawn from the whole RSRD attitude distribution, the features of
    ``road`` (a random road when None, its appearance drawn from ``appearance``: by default the
    ``real-road`` range, None for the ``clean`` one) are
    placed inside the grid's window.

    With ``far_grid`` the same features are placed inside its window too (from a draw of their
    own: the road, the rig and the near features are the sample's without it; the surface under
    them may differ where a concrete pavement's joints fall) and the sample carries its
    ``far_truth``.
    """
    camera = camera or StereoCamera.rsrd_half()
    grid = grid or GridSpec()
    lidar = lidar or LidarConfig()
    seq = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x5A3B1E])
    rng_cfg, rng_pose, rng_render = (np.random.default_rng(s) for s in seq.spawn(3))
    road = road or random_road(rng_cfg, appearance)
    y_cam = float(rng_pose.uniform(-0.5, 0.5))
    centres = _place_in_grid(road.features, grid, y_cam, rng_pose)
    if far_grid is not None:
        check_far_grid(far_grid)
        rng_far = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0xFA4F1E]))
        centres += _place_in_grid(road.features, far_grid, y_cam, rng_far)
    scene = build_scene(road, int(seed), (-4.0, LOOK_AHEAD_M + 2.0), centres)
    roll, pitch = draw_mount_attitude(rng_pose, in_drive=False)
    front, rear, _, _ = _wheel_heights(scene, np.zeros(1), np.full(1, y_cam), np.zeros(1))
    support = float((front[0] + rear[0]) / 2)
    z = support + grid.base_height + float(np.clip(rng_pose.normal(0.0, 0.01), -0.02, 0.02))
    pose = CameraPose(0.0, y_cam, z, Attitude.from_degrees(roll, pitch))
    return render_sample(scene, pose, camera, grid, lidar, rng_render, 0, far_grid=far_grid)
