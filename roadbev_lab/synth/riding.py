"""Drives where the car rides on its road: suspension, ``base_link``, odometry, the road map.

The drive bags of docs/interface/bags.md ("Drive bags"). A :class:`RidingDrive` is a car going
along a synthetic road (:func:`roadbev_lab.synth.scene.build_scene`, the same scenes, renderer
and labels as :class:`roadbev_lab.synth.drive.SyntheticDrive`):

* **Path.** The rear-axle centre moves at the set speed (drifting a few per cent, as throttle
  and gentle braking do) along S-curves inside the (straight) road strip: the lateral offset
  ``y = y0 + A (1 - cos(2 pi x / lambda))`` with amplitude ``A = curve_amplitude_m`` and a
  wavelength chosen so that the lateral acceleration stays at ``max_lateral_accel`` (radius
  ``v^2 / a``: 50 m at 5 m/s ... 1.8 km at 30 m/s with the default 0.5 m/s^2). The yaw is the path's tangent
  (kinematic rear axle, no side slip); it is 0 at the start, so ``odom`` has the road's axes.
* **Body on its suspension** (:class:`SuspensionSpec`): a full-car model, a rigid sprung body
  (heave z of the centre of gravity, pitch, roll) on four spring-damper corners at the tyre
  contacts; the tyres follow the road (mean height over a 12 cm patch). Small angles, linear;
  the inertial moments of braking and cornering act at the centre of gravity's height. The
  defaults (1500 kg, 21 kN/m and 1.68 kNs/m per corner, radii of gyration 1.2 m in pitch and
  0.75 m in roll) give heave 1.19 Hz, pitch 1.39 Hz, roll 1.27 Hz with damping ratios 0.30,
  0.35 and 0.32 (:meth:`SuspensionSpec.modes`). Grade
  and cross slope enter through the contacts, so the body leans with the road. It is
  integrated exactly (matrix exponential, zero-order hold) at a time step where the car moves
  at most 1 cm, from static equilibrium.
* **base_link** (docs/interface/frames-and-grid.md): the body frame with its origin at the rear-axle centre at static
  ride height: at rest on a flat road it lies on the road. It heaves, pitches and rolls with the
  body; the left camera is fixed to it at ``vehicle.camera_position_m``, turned down by a mount
  pitch (and roll) drawn per drive from the real RSRD rigs; the IMU sits on the camera, aligned
  with its body axes (``imu_to_camera_rpy_deg`` = 0).
* **odom**: gravity-aligned, origin and heading of ``base_link`` at the first IMU stamp (equal to
  ``base_link`` there up to the body's initial pitch and roll, which are dropped so that
  heights in ``odom`` are vertical). ``ground_truth_poses`` is the exact 6-DoF pose of
  ``base_link`` in ``odom`` at the IMU stamps; ``odometry`` is planar dead reckoning from a
  wheel speed with a scale error and noise and a yaw rate with a bias and noise
  (:class:`OdometryNoise`), so it drifts like a vehicle's own odometry.
* **Road map**: the true road height in ``odom`` on a regular grid (``road_map``), over every
  wheel path and camera window of the drive.

Frames are rendered from the true camera pose at their stamps (between IMU samples); their
attitude is the slerp of the IMU orientations, the ``base_link`` pose the interpolation of the
ground-truth poses, so anything that interpolates the bag's messages recovers the pose each
frame was rendered with. Per-frame labels mark cells hidden from the camera NaN. Everything is
deterministic from the seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from roadbev_core.attitude import quaternion_from_rotation, slerp
from roadbev_core.config import GridSpec, StereoCamera, VehicleConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.geometry import Attitude, attitude_from_rotation, quaternion_to_rotation, rotation_from_rpy
from roadbev_core.ride.lti import expm_integral
from roadbev_core.vehicle import camera_extrinsic, planar_yaw
from roadbev_lab.evaluation.arrival import RoadMap
from roadbev_lab.synth.drive import (
    GRAVITY,
    DriveConfig,
    DriveSample,
    SyntheticDrive,
    _rotvec,
    _smooth_process,
    corner_heights,
    draw_mount_attitude,
    render_sample,
)
from roadbev_lab.synth.heightfield import SynthError
from roadbev_lab.synth.render import LOOK_AHEAD_M, CameraPose
from roadbev_lab.synth.scene import build_scene

__all__ = [
    "DRIVE_VERSION",
    "OdometryNoise",
    "PoseSeries",
    "RidingConfig",
    "RidingDrive",
    "SuspensionSpec",
    "planar_odometry",
    "simulate_suspension",
]

# Version of what a riding drive's outputs are; bump it when the same arguments give other bytes.
DRIVE_VERSION = 1


@dataclass(frozen=True)
class SuspensionSpec:
    """A full-car ride model: sprung body on four linear spring-damper corners.

    Attributes:
        sprung_mass_kg: body mass carried by the springs.
        cg_ahead_of_rear_axle_m: centre of gravity's distance ahead of the rear axle.
        cg_height_m: centre of gravity above the road (moment of braking and cornering).
        pitch_gyration_m, roll_gyration_m: radii of gyration (inertia = mass * radius^2).
        stiffness_front_n_per_m, stiffness_rear_n_per_m: spring rate per corner (at the wheel).
        damping_front_ns_per_m, damping_rear_ns_per_m: damper rate per corner (at the wheel).
    """

    sprung_mass_kg: float = 1500.0
    cg_ahead_of_rear_axle_m: float = 1.5
    cg_height_m: float = 0.55
    pitch_gyration_m: float = 1.2
    roll_gyration_m: float = 0.75
    stiffness_front_n_per_m: float = 21_000.0
    stiffness_rear_n_per_m: float = 21_000.0
    damping_front_ns_per_m: float = 1_684.0
    damping_rear_ns_per_m: float = 1_684.0

    def __post_init__(self) -> None:
        values = [getattr(self, f) for f in self.__dataclass_fields__]
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise SynthError(f"suspension parameters must be positive and finite, got {self}")

    def matrices(self, vehicle: VehicleConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Mass M [3, 3], corner map G [4, 3], corner stiffness k [4] and damping c [4], and
        the moment arms of the inertial forces h [3] (q = heave, pitch, roll)."""
        m = self.sprung_mass_kg
        M = np.diag([m, m * self.pitch_gyration_m**2, m * self.roll_gyration_m**2])
        corners = vehicle.wheel_positions() - np.array([self.cg_ahead_of_rear_axle_m, 0.0])  # [4, 2] from the CG
        # vertical displacement of a body point (x, y) from the CG: z - x * pitch + y * roll
        G = np.stack([np.ones(4), -corners[:, 0], corners[:, 1]], axis=1)
        k = np.array([self.stiffness_front_n_per_m] * 2 + [self.stiffness_rear_n_per_m] * 2)
        c = np.array([self.damping_front_ns_per_m] * 2 + [self.damping_rear_ns_per_m] * 2)
        return M, G, k, c, np.array([0.0, -m * self.cg_height_m, m * self.cg_height_m])

    def modes(self, vehicle: VehicleConfig) -> dict[str, tuple[float, float]]:
        """Undamped natural frequency (Hz) and damping ratio of heave, pitch and roll
        (each from its own diagonal term: the coupling is small)."""
        M, G, k, c, _ = self.matrices(vehicle)
        K = G.T @ (k[:, None] * G)
        C = G.T @ (c[:, None] * G)
        out = {}
        for i, name in enumerate(("heave", "pitch", "roll")):
            wn = math.sqrt(K[i, i] / M[i, i])
            out[name] = (wn / (2 * math.pi), C[i, i] / (2 * math.sqrt(K[i, i] * M[i, i])))
        return out


@dataclass(frozen=True)
class OdometryNoise:
    """How the vehicle's own odometry errs (planar dead reckoning).

    Attributes:
        rate_hz: ``/odom`` rate (a divisor of the IMU rate is used).
        speed_scale_error: relative wheel-speed scale error (tyre radius), fixed per drive.
        speed_noise_mps: white noise on the wheel speed, 1-sigma.
        yaw_rate_bias: gyro bias on the yaw rate (rad/s), fixed per drive.
        yaw_rate_noise: white noise on the yaw rate (rad/s), 1-sigma.
    """

    rate_hz: float = 50.0
    speed_scale_error: float = 0.005
    speed_noise_mps: float = 0.05
    yaw_rate_bias: float = 0.001
    yaw_rate_noise: float = 0.002

    def __post_init__(self) -> None:
        if not 1.0 <= self.rate_hz <= 1000.0:
            raise SynthError(f"odometry rate must be in [1, 1000] Hz, got {self.rate_hz}")
        if min(self.speed_noise_mps, self.yaw_rate_noise) < 0 or abs(self.speed_scale_error) > 0.2:
            raise SynthError("odometry noise must be >= 0 and |speed_scale_error| <= 0.2")
        if not math.isfinite(self.yaw_rate_bias):
            raise SynthError("yaw_rate_bias must be finite")


@dataclass(frozen=True)
class RidingConfig:
    """A drive of a car riding on its road.

    Attributes:
        drive: frames, speed, rates, seed, road, rig, grid, LiDAR and IMU noise (as
            :class:`DriveConfig`; its ``start_stamp_ns`` is the first IMU stamp).
        vehicle: base_link geometry and the camera's position on it.
        suspension: the ride model.
        odometry: the vehicle odometry's errors.
        curve_amplitude_m: half the lateral swing of the S-curves (0 = straight).
        max_lateral_accel: lateral acceleration of the curves (m/s^2).
        tail_s: the motion (IMU, poses) continues this long after the last frame, so that
            the wheels' arrival at what the last frames saw is known.
        road_map_resolution_m: cell size of the true road map.
    """

    drive: DriveConfig = field(default_factory=DriveConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    suspension: SuspensionSpec = field(default_factory=SuspensionSpec)
    odometry: OdometryNoise = field(default_factory=OdometryNoise)
    curve_amplitude_m: float = 0.6
    max_lateral_accel: float = 0.5
    tail_s: float = 1.0
    road_map_resolution_m: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 <= self.curve_amplitude_m <= 1.5:
            raise SynthError(f"curve_amplitude_m must be in [0, 1.5] (the road strip is 7.2 m wide), "
                             f"got {self.curve_amplitude_m}")
        if not 0.1 <= self.max_lateral_accel <= 4.0:
            raise SynthError(f"max_lateral_accel must be in [0.1, 4] m/s^2, got {self.max_lateral_accel}")
        if not 0.0 <= self.tail_s <= 10.0:
            raise SynthError(f"tail_s must be in [0, 10] s, got {self.tail_s}")
        if not 0.005 <= self.road_map_resolution_m <= 0.1:
            raise SynthError(f"road_map_resolution_m must be in [0.005, 0.1], got {self.road_map_resolution_m}")

    @property
    def grid(self) -> GridSpec:
        return self.drive.grid

    @property
    def camera(self) -> StereoCamera:
        return self.drive.camera


class PoseSeries(NamedTuple):
    """Poses of a frame over time.

    Attributes:
        stamp_ns: [K] int64.
        position: [K, 3] (m).
        orientation_xyzw: [K, 4] unit quaternions (sign-continuous).
        linear_velocity: [K, 3] in the moving frame's own axes (m/s).
        angular_velocity: [K, 3] in the moving frame's own axes (rad/s).
    """

    stamp_ns: np.ndarray
    position: np.ndarray
    orientation_xyzw: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray


# --- the ride model ----------------------------------------------------------------------------
def simulate_suspension(
    spec: SuspensionSpec,
    vehicle: VehicleConfig,
    road: np.ndarray,
    dt: float,
    accel_x: np.ndarray,
    accel_y: np.ndarray,
) -> np.ndarray:
    """Body motion on the suspension over road inputs, from static equilibrium.

    ``M q'' = -G^T k (G q - u) - G^T c (G q' - u') + h * (a_x, a_y)`` with q = (heave of the CG,
    pitch, roll), u the road under the four corners.

    Args:
        road: [n, 4] road height under the tyres (order ``vehicle.WHEEL_NAMES``) at steps of ``dt``.
        accel_x, accel_y: [n] longitudinal and lateral acceleration of the body (m/s^2).

    Returns:
        [n, 3] (heave of the CG (m), pitch (rad, nose down > 0), roll (rad, left up > 0)).
    """
    u = np.asarray(road, np.float64)
    n = u.shape[0]
    M, G, k, c, h = spec.matrices(vehicle)
    Minv = np.linalg.inv(M)
    K = G.T @ (k[:, None] * G)
    C = G.T @ (c[:, None] * G)
    F = np.zeros((6, 6))
    F[:3, 3:] = np.eye(3)
    F[3:, :3] = -Minv @ K
    F[3:, 3:] = -Minv @ C
    du = np.gradient(u, dt, axis=0) if n > 1 else np.zeros_like(u)
    force = u @ (k[:, None] * G) + du @ (c[:, None] * G)  # [n, 3] G^T k u + G^T c u'
    force[:, 1] += h[1] * np.asarray(accel_x)  # braking (a_x < 0) pitches the nose down
    force[:, 2] += h[2] * np.asarray(accel_y)  # turning left (a_y > 0) lifts the left side (roll > 0)
    drive = force @ Minv.T  # [n, 3] accelerations
    Phi, integral = expm_integral(F * dt)
    Gamma = (integral * dt)[:, 3:]  # [6, 3] zero-order hold on the accelerations
    x = np.zeros(6)
    x[:3] = np.linalg.solve(K, u[0] @ (k[:, None] * G))  # static equilibrium on the first input
    out = np.empty((n, 3))
    PhiT, GammaT = Phi.T, Gamma.T
    for i in range(n):
        out[i] = x[:3]
        x = x @ PhiT + drive[i] @ GammaT
    return out


# --- the drive ----------------------------------------------------------------------------------
class RidingDrive(SyntheticDrive):
    """A deterministic drive of a car riding on its road (see the module docstring).

    ``drive[i]`` renders frame i (a :class:`DriveSample` whose labels mark hidden cells NaN);
    ``imu_samples()``, ``ground_truth_poses()``, ``odometry()``, ``road_map()`` and
    ``base_to_camera`` give everything else a drive bag holds; ``features_in_odom()`` where the
    road's features are (for detectors).
    """

    def __init__(self, config: RidingConfig | None = None) -> None:
        self.riding = riding = config or RidingConfig()
        self.config = c = riding.drive
        vehicle = riding.vehicle
        seq = np.random.SeedSequence([int(c.seed) & 0xFFFFFFFF, 0x41D1E6])
        rng, rng_frames, rng_odom = (np.random.default_rng(s) for s in seq.spawn(3))
        self._frame_seeds = rng_frames.integers(0, 2**63 - 1, c.frames)
        frame_dt, imu_dt = 1.0 / c.frame_rate_hz, 1.0 / c.imu_rate_hz
        first = 2 * imu_dt + rng.uniform(0.1, 0.9) * imu_dt  # frames fall between IMU samples
        frame_t = first + np.arange(c.frames) * frame_dt
        n_imu = int(math.ceil((frame_t[-1] + riding.tail_s + 2 * imu_dt) / imu_dt)) + 1
        self._imu_t = imu_t = np.arange(n_imu) * imu_dt
        self._frame_t = frame_t
        self.frame_stamps_ns = [c.start_stamp_ns + int(round(t * 1e9)) for t in frame_t]
        self.imu_stamps_ns = [c.start_stamp_ns + int(round(t * 1e9)) for t in imu_t]

        # Fine time base: the car moves at most 1 cm per step.
        sub = max(10, int(math.ceil(1.1 * c.speed_mps * imu_dt / 0.01)))
        dt = imu_dt / sub
        n = (n_imu - 1) * sub + 1
        t = np.arange(n) * dt
        speed_imu = c.speed_mps * np.maximum(1.0 + _smooth_process(n_imu, imu_dt, 2.0, 0.05, rng), 0.0)
        speed = np.interp(t, imu_t, speed_imu)
        s = np.concatenate([[0.0], np.cumsum((speed[1:] + speed[:-1]) / 2 * dt)])  # [n] distance
        amp = riding.curve_amplitude_m
        wavelength = 2 * math.pi * math.sqrt(amp * max(c.speed_mps, 1.0) ** 2 / riding.max_lateral_accel)
        wavelength = max(wavelength, 20.0)
        side = float(rng.choice([-1.0, 1.0]))
        y0 = -side * amp + float(rng.uniform(-0.2, 0.2))
        # path y(x) with x along the strip; x(s) from ds^2 = dx^2 + dy^2 (fixed-point, converges fast)
        k_w = 2 * math.pi / wavelength
        x = s.copy()
        for _ in range(4):
            slope = side * amp * k_w * np.sin(k_w * x)
            dx = np.diff(s) / np.sqrt(1.0 + (0.5 * (slope[1:] + slope[:-1])) ** 2)
            x = np.concatenate([[0.0], np.cumsum(dx)])
        y = y0 + side * amp * (1.0 - np.cos(k_w * x))
        yaw = np.arctan(side * amp * k_w * np.sin(k_w * x))  # tangent; 0 at the start
        curvature = side * amp * k_w**2 * np.cos(k_w * x) * np.cos(yaw) ** 3
        accel_x = np.gradient(speed, dt) if n > 1 else np.zeros(n)
        accel_y = speed**2 * curvature
        x_end = float(x[-1]) + vehicle.camera_position_m[0] + LOOK_AHEAD_M + 2.0
        if x_end > 700.0 - 6.0:
            raise SynthError(f"a drive of {x[-1]:.0f} m is too long for one road strip; split it")
        self.scene = build_scene(c.road, c.seed, (-4.0, x_end))

        # The body on its suspension.
        road = corner_heights(self.scene, x, y, yaw, vehicle.wheel_positions()).T  # [n, 4]
        q = simulate_suspension(riding.suspension, vehicle, road, dt, accel_x, accel_y)  # [n, 3]
        b = riding.suspension.cg_ahead_of_rear_axle_m
        z_base = q[:, 0] + b * q[:, 1]  # base_link (rear axle, x = -b from the CG): z - (-b) * pitch
        keep = np.arange(0, n, sub)  # the IMU stamps
        self._path = {"x": x[keep], "y": y[keep], "yaw": yaw[keep], "speed": speed[keep]}
        mount_roll, mount_pitch = draw_mount_attitude(rng, in_drive=True)
        self.mount_rpy = (math.radians(mount_roll), math.radians(mount_pitch))
        cam_pos, R_base_optical = camera_extrinsic(vehicle, *self.mount_rpy)
        self.base_to_camera = (cam_pos, R_base_optical)  # base_link -> left optical frame (tf_static)
        R_base_cambody = rotation_from_rpy(*self.mount_rpy, 0.0)
        heading = rng.uniform(-math.pi, math.pi)  # the road's direction in ENU
        self._heading = heading

        # base_link in the strip's world frame at the IMU stamps, then in odom.
        R_base = np.array([rotation_from_rpy(float(r), float(p), float(w))
                           for r, p, w in zip(q[keep, 2], q[keep, 1], yaw[keep], strict=True)])  # [K, 3, 3]
        p_base = np.stack([x[keep], y[keep], z_base[keep]], axis=1)  # [K, 3]
        self._odom_origin = p_base[0].copy()  # odom: base_link's position and heading at t0
        self._odom_yaw = float(yaw[0])
        R_odom = rotation_from_rpy(0.0, 0.0, self._odom_yaw)
        self._base_pos = (p_base - self._odom_origin) @ R_odom  # [K, 3] in odom
        self._base_R = np.einsum("ji,kjl->kil", R_odom, R_base)  # [K, 3, 3] in odom
        self._base_q = _continuous(np.array([quaternion_from_rotation(R) for R in self._base_R]))

        # The camera (and the IMU on it) in ENU.
        R_enu = rotation_from_rpy(0.0, 0.0, heading)
        cam_world = p_base + np.einsum("kij,j->ki", R_base, cam_pos)  # [K, 3]
        self._R = [R_enu @ R @ R_base_cambody for R in R_base]
        self._q = _continuous(np.array([quaternion_from_rotation(R) for R in self._R]))
        acc = np.zeros((n_imu, 3))  # camera acceleration in the strip's axes, then ENU
        if n_imu > 2:
            for axis in range(3):
                acc[:, axis] = np.gradient(np.gradient(cam_world[:, axis], imu_dt), imu_dt)
        acc = acc @ R_enu.T
        acc[:, 2] += GRAVITY
        self._acc_body = np.einsum("kji,kj->ki", np.array(self._R), acc)
        self._acc_body += rng.normal(0.0, c.accel_noise, self._acc_body.shape)
        self._gyro_noise = rng.normal(0.0, c.gyro_noise, (n_imu, 3))
        self._x, self._y, self._z = cam_world[:, 0], cam_world[:, 1], cam_world[:, 2]
        self._yaw, self._speed = yaw[keep], speed[keep]
        self._velocity = np.stack([np.gradient(self._base_pos[:, i], imu_dt) for i in range(3)], 1) if n_imu > 1 \
            else np.zeros((n_imu, 3))
        self._odom = self._dead_reckon(rng_odom)

    # -- poses -------------------------------------------------------------------------------
    def _base_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """base_link (position [3], R [3, 3]) in odom at time t (s from the first IMU sample)."""
        imu_dt = 1.0 / self.config.imu_rate_hz
        k = min(int(math.floor(t / imu_dt)), len(self._imu_t) - 2)
        frac = (t - self._imu_t[k]) / imu_dt
        pos = self._base_pos[k] * (1 - frac) + self._base_pos[k + 1] * frac
        q = slerp(self._base_q[k], self._base_q[k + 1], frac)
        return pos, quaternion_to_rotation(*q)

    def pose(self, index: int) -> tuple[CameraPose, Attitude]:
        """The left camera's pose at frame ``index`` (world of the scene) and its attitude."""
        t = self._frame_t[index]
        pos, R = self._base_at(t)
        R_odom = rotation_from_rpy(0.0, 0.0, self._odom_yaw)
        cam_pos, _ = self.base_to_camera
        R_cam = R_odom @ R @ rotation_from_rpy(*self.mount_rpy, 0.0)  # camera body in the strip's axes
        world = self._odom_origin + R_odom @ (pos + R @ cam_pos)
        attitude = attitude_from_rotation(R_cam)
        yaw = math.atan2(R_cam[1, 0], R_cam[0, 0])
        return CameraPose(x=float(world[0]), y=float(world[1]), z=float(world[2]), attitude=attitude, yaw=yaw), attitude

    def __getitem__(self, index: int) -> DriveSample:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} of a {len(self)}-frame drive")
        index %= len(self)
        pose, attitude = self.pose(index)
        rng = np.random.default_rng(int(self._frame_seeds[index]))
        c = self.config
        return render_sample(self.scene, pose, c.camera, c.grid, c.lidar, rng, self.frame_stamps_ns[index],
                             attitude, hide_occluded=True, far_grid=c.far_grid)

    def ground_truth_poses(self) -> PoseSeries:
        """The exact pose and twist of ``base_link`` in ``odom`` at the IMU stamps."""
        imu_dt = 1.0 / self.config.imu_rate_hz
        n = len(self._imu_t)
        omega = np.zeros((n, 3))
        for k in range(n):
            a, b = max(k - 1, 0), min(k + 1, n - 1)
            if b > a:
                omega[k] = _rotvec(self._base_R[a].T @ self._base_R[b]) / ((b - a) * imu_dt)
        v_body = np.einsum("kji,kj->ki", self._base_R, self._velocity)
        return PoseSeries(np.array(self.imu_stamps_ns, np.int64), self._base_pos.copy(), self._base_q.copy(),
                          v_body, omega)

    def _dead_reckon(self, rng: np.random.Generator, noise: OdometryNoise | None = None) -> PoseSeries:
        noise = noise or self.riding.odometry
        imu_rate = self.config.imu_rate_hz
        step = max(1, int(round(imu_rate / noise.rate_hz)))
        idx = np.arange(0, len(self._imu_t), step)
        dt = step / imu_rate
        yaw_true = np.unwrap(np.arctan2(self._base_R[idx, 1, 0], self._base_R[idx, 0, 0]))
        v_true = np.hypot(self._velocity[idx, 0], self._velocity[idx, 1])
        yaw_rate_true = np.gradient(yaw_true, dt) if idx.size > 1 else np.zeros(idx.size)
        scale = 1.0 + noise.speed_scale_error * float(rng.choice([-1.0, 1.0]))
        bias = noise.yaw_rate_bias * float(rng.choice([-1.0, 1.0]))
        v = v_true * scale + rng.normal(0.0, noise.speed_noise_mps, idx.size)
        w = yaw_rate_true + bias + rng.normal(0.0, noise.yaw_rate_noise, idx.size)
        pos = np.zeros((idx.size, 3))
        yaw = np.zeros(idx.size)
        yaw[0] = yaw_true[0]
        for k in range(1, idx.size):  # midpoint dead reckoning
            yaw[k] = yaw[k - 1] + 0.5 * (w[k] + w[k - 1]) * dt
            mid = 0.5 * (yaw[k] + yaw[k - 1])
            step_len = 0.5 * (v[k] + v[k - 1]) * dt
            pos[k, :2] = pos[k - 1, :2] + step_len * np.array([math.cos(mid), math.sin(mid)])
        quat = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
        lin = np.stack([v, np.zeros_like(v), np.zeros_like(v)], axis=1)
        ang = np.stack([np.zeros_like(w), np.zeros_like(w), w], axis=1)
        stamps = np.array(self.imu_stamps_ns, np.int64)[idx]
        return PoseSeries(stamps, pos, _continuous(quat), lin, ang)

    def odometry(self, noise: OdometryNoise | None = None, seed: int = 0) -> PoseSeries:
        """The vehicle's own (planar, drifting) odometry of ``base_link`` in ``odom``: the
        drive's (``noise`` None), or dead reckoning with other errors drawn from ``seed``."""
        if noise is None:
            return self._odom
        return self._dead_reckon(np.random.default_rng(seed), noise)

    def trajectory(self) -> dict[str, np.ndarray]:
        """The left camera's path at the IMU stamps (world of the scene), as :class:`SyntheticDrive`."""
        return {
            "stamp_ns": np.array(self.imu_stamps_ns, dtype=np.int64),
            "x": self._x.copy(), "y": self._y.copy(), "z": self._z.copy(),
            "yaw": self._yaw.copy(), "speed": self._speed.copy(), "heading": np.array(self._heading),
        }

    def features_in_odom(self) -> list[tuple[str, float, float, float]]:
        """The road's placed features as (name, x, y, height) in ``odom`` (height: a bump's
        height, a pothole's depth as a negative number, 0 for other kinds)."""
        c, s = math.cos(self._odom_yaw), math.sin(self._odom_yaw)
        out = []
        for f in self.scene.features:
            dx, dy = f.x - self._odom_origin[0], f.y - self._odom_origin[1]
            depth = getattr(f, "depth", None) if f.name == "pothole" else None
            height = -float(depth) if depth is not None else float(getattr(f, "height", 0.0) or 0.0)
            out.append((f.name, c * dx + s * dy, -s * dx + c * dy, height))
        return out

    def road_map(self, margin_m: float = 1.5) -> RoadMap:
        """The true road height in ``odom`` over every wheel path and camera window of the drive."""
        res = self.riding.road_map_resolution_m
        grid = self.config.grid
        # Everything the wheels or the camera windows cover, in odom.
        pos = self._base_pos
        cam_x = self.riding.vehicle.camera_position_m[0]
        yaw = np.arctan2(self._base_R[:, 1, 0], self._base_R[:, 0, 0])
        reach = np.array([-1.0, cam_x + grid.x_max + 0.5])
        xs = pos[:, 0:1] + np.cos(yaw)[:, None] * reach
        half = max(abs(grid.y_min), abs(grid.y_max), 0.5 * self.riding.vehicle.track_width_m)
        x_lo, x_hi = float(xs.min()) - margin_m, float(xs.max()) + margin_m
        y_lo, y_hi = float(pos[:, 1].min()) - half - margin_m, float(pos[:, 1].max()) + half + margin_m
        n_rows = int(math.ceil((x_hi - x_lo) / res))
        n_cols = int(math.ceil((y_hi - y_lo) / res))
        centre = (x_lo + 0.5 * n_rows * res, y_lo + 0.5 * n_cols * res)
        cx = centre[0] + 0.5 * n_rows * res - (np.arange(n_rows) + 0.5) * res  # row 0 farthest (+x)
        cy = centre[1] + 0.5 * n_cols * res - (np.arange(n_cols) + 0.5) * res  # col 0 leftmost (+y)
        c, s = math.cos(self._odom_yaw), math.sin(self._odom_yaw)
        gx, gy = np.meshgrid(cx, cy, indexing="ij")
        wx = self._odom_origin[0] + c * gx - s * gy
        wy = self._odom_origin[1] + s * gx + c * gy
        z = self.scene.height(wx, wy) - self._odom_origin[2]
        return RoadMap(z.astype(np.float32), float(res), (float(centre[0]), float(centre[1])))


def planar_odometry(series: PoseSeries) -> list[PlanarPose]:
    """A pose series as the planar odometry samples the pipeline takes (x, y, yaw, forward
    speed, yaw rate), as ``msg_bridge.pipeline_io.odometry_sample`` reads ``/odom``."""
    R = np.array([quaternion_to_rotation(*q) for q in series.orientation_xyzw])  # [K, 3, 3]
    yaw = np.unwrap(planar_yaw(R))
    return [PlanarPose(int(t), float(p[0]), float(p[1]), float(y), float(v[0]), float(w[2]))
            for t, p, y, v, w in zip(series.stamp_ns, series.position, yaw, series.linear_velocity,
                                     series.angular_velocity, strict=True)]


def _continuous(q: np.ndarray) -> np.ndarray:
    """Quaternions [K, 4] with their sign flipped where needed to stay continuous."""
    q = np.array(q, np.float64)
    for k in range(1, q.shape[0]):
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q

