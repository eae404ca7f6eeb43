"""Test doubles for the msg_bridge tests: a tiny deterministic drive shaped like SyntheticDrive."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_core.labels import ElevationLabel


class FakeImuSample(NamedTuple):
    stamp_ns: int
    orientation_xyzw: tuple[float, float, float, float]
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]


class FakeSample(NamedTuple):
    frame: Frame
    truth: ElevationLabel
    points_road: np.ndarray


@dataclass(frozen=True)
class FakeConfig:
    frames: int = 4
    seed: int = 0
    frame_rate_hz: float = 5.0
    imu_rate_hz: float = 100.0
    start_stamp_ns: int = 1_700_000_000_000_000_000
    camera: StereoCamera = field(default_factory=lambda: StereoCamera(50.0, 50.0, 31.5, 23.5, 0.12, 64, 48))
    grid: GridSpec = field(default_factory=GridSpec)


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (x, y, z, w)."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def quaternion_xyzw(roll: float, pitch: float, yaw: float = 0.0) -> tuple[float, float, float, float]:
    """Unit quaternion of ``rotation_from_rpy``: Rz(yaw) Ry(pitch) Rx(roll) as a product of axis turns."""
    about_x = np.array([math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2)])
    about_y = np.array([0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2)])
    about_z = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])
    x, y, z, w = _multiply(_multiply(about_z, about_y), about_x)
    return (float(x), float(y), float(z), float(w))


class FakeDrive:
    """Deterministic frames with random pixels, a smooth attitude and a pothole-like truth."""

    def __init__(self, config: FakeConfig | None = None) -> None:
        self.config = config or FakeConfig()
        self._period_ns = int(1e9 / self.config.frame_rate_hz)

    def attitude_at(self, stamp_ns: int) -> Attitude:
        t = (stamp_ns - self.config.start_stamp_ns) * 1e-9
        return Attitude(roll=0.01 * math.sin(3 * t), pitch=0.02 + 0.01 * math.cos(2 * t))

    def stamps(self) -> list[int]:
        return [self.config.start_stamp_ns + i * self._period_ns for i in range(self.config.frames)]

    def __len__(self) -> int:
        return self.config.frames

    def __iter__(self) -> Iterator[FakeSample]:
        rng = np.random.default_rng(self.config.seed)
        grid, camera = self.config.grid, self.config.camera
        for stamp in self.stamps():
            left = rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
            right = rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
            truth = rng.normal(0.0, 0.01, grid.shape).astype(np.float32)
            truth[:20] = np.nan  # far rows without labels
            frame = Frame(left, right, camera, self.attitude_at(stamp), stamp)
            label = ElevationLabel(truth, np.isfinite(truth), np.isfinite(truth).astype(np.int32))
            yield FakeSample(frame, label, np.zeros((0, 3)))

    def imu_samples(self) -> list[FakeImuSample]:
        start = self.config.start_stamp_ns - 50_000_000
        end = self.stamps()[-1] + 50_000_000
        step = int(1e9 / self.config.imu_rate_hz)
        samples = []
        for stamp in range(start, end + 1, step):
            a = self.attitude_at(stamp)
            q = quaternion_xyzw(a.roll, a.pitch, 0.3)
            samples.append(FakeImuSample(stamp, q, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81)))
        return samples
