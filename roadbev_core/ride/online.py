"""The preview controller online: preview messages in, actuator forces out, step by step.

What ``roadbev_ros.preview_controller`` runs, ROS-free. It holds the last few preview messages;
at every control step (``controller.dt``) it places each front wheel in every held message's
frame by dead reckoning along x at the message's own ``vehicle_speed`` from its stamp (``x =
wheel_x + v (now - stamp)``; ``wheel_x`` is the front axle's x in the message's frame at its
stamp: ``vehicle.wheelbase_m`` for ``base_link`` messages, ``wheelbase_m - camera x`` for
``roadbev_road`` ones), reads the road over the horizon ahead from the newest message that has a
value at each point (:func:`roadbev_core.preview.read_profile`, as the preview-at-arrival metric),
turns it into road velocity within that one message (so each message's own reference height
drops out) and applies :class:`PreviewLqr`, its feedforward scaled by the preview's gain measured
on the road the wheel has ridden (:class:`roadbev_core.ride.preview_gain.PreviewGain`: a preview
that turns out wrong is applied less, down to none). A reference implementation has no
suspension sensors: its quarter car is a model riding the previewed road itself (the road under
the wheel = the newest held value there). On a vehicle, replace
:attr:`OnlinePreviewController.state` with the measured state (suspension deflection, body and
wheel velocities, tyre deflection estimate) and pass the road velocity measured under each wheel
to :meth:`OnlinePreviewController.step`. Pure numpy.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from roadbev_core.preview import PreviewProfiles, read_profile
from roadbev_core.ride.preview_gain import DEFAULT_TIME_CONSTANT_S, PreviewGain
from roadbev_core.ride.preview_lqr import PreviewLqr
from roadbev_core.ride.quarter_car import FRONT_WHEELS, RideError

__all__ = ["HeldPreview", "OnlinePreviewController", "WheelCommand"]

_TRACKS = {"front_left": ("front_left", "left"), "front_right": ("front_right", "right")}


class HeldPreview(NamedTuple):
    """A preview message as the controller holds it.

    Attributes:
        stamp_ns: the message's stamp.
        profiles: its profiles (with ``vehicle_speed``).
        wheel_x: x of the front axle in the message's frame at its stamp (m).
        slope_x: dz/dx of the message's reference plane against gravity along its x (0 for
            ``roadbev_road``, which is level; the contact plane's for fused-map messages).
    """

    stamp_ns: int
    profiles: PreviewProfiles
    wheel_x: float
    slope_x: float = 0.0


class WheelCommand(NamedTuple):
    """One wheel's output of a step.

    Attributes:
        force_n: actuator force (N, positive pushes the body up and the wheel down).
        feedforward_n: its preview part (N), after the preview's gain.
        preview_gain: the share of the preview's feedforward applied (0..1).
        covered: a held message had a value at the wheel's own point.
        preview_m: how far ahead of the wheel the held messages reach without a gap (m).
        body_acceleration: the model body's vertical acceleration (m/s^2).
    """

    force_n: float
    feedforward_n: float
    preview_gain: float
    covered: bool
    preview_m: float
    body_acceleration: float


@dataclass
class OnlinePreviewController:
    """Preview LQR over a stream of preview messages (see the module docstring).

    Attributes:
        controller: the control law (its ``dt`` is the step).
        hold: messages held (the newest first wins where it has a value).
        max_age_s: a message older than this is dropped.
        wheels: the wheels controlled.
        gain_time_constant_s: forgetting of the preview's measured gain (0: always apply all of it).
    """

    controller: PreviewLqr = field(default_factory=PreviewLqr)
    hold: int = 4
    max_age_s: float = 2.0
    wheels: tuple[str, ...] = FRONT_WHEELS
    gain_time_constant_s: float = DEFAULT_TIME_CONSTANT_S
    state: dict[str, np.ndarray] = field(init=False)
    held: deque[HeldPreview] = field(init=False)
    gains: dict[str, PreviewGain] = field(init=False)
    ridden: dict[str, deque[float]] = field(init=False)

    def __post_init__(self) -> None:
        if self.hold < 1 or not (math.isfinite(self.max_age_s) and self.max_age_s > 0):
            raise RideError(f"hold must be >= 1 and max_age_s > 0, got {self.hold}, {self.max_age_s}")
        unknown = [w for w in self.wheels if w not in _TRACKS]
        if unknown:
            raise RideError(f"only front wheels can be previewed, got {unknown}")
        if not (math.isfinite(self.gain_time_constant_s) and self.gain_time_constant_s >= 0):
            raise RideError(f"gain_time_constant_s must be >= 0, got {self.gain_time_constant_s}")
        self.state = {w: np.zeros(4) for w in self.wheels}
        self.held = deque(maxlen=self.hold)
        n = self.controller.steps
        tau = self.gain_time_constant_s or 1.0
        self.gains = {w: PreviewGain(n, self.controller.dt, tau) for w in self.wheels}
        self.ridden = {w: deque(maxlen=n + 1) for w in self.wheels}  # road velocity under the wheel, oldest first

    def receive(self, stamp_ns: int, profiles: PreviewProfiles, wheel_x: float, slope_x: float = 0.0) -> None:
        """Hold a message (``slope_x``: see :class:`HeldPreview`; the profile is put back on gravity
        with it, so a tilted reference plane does not read as road).

        Raises:
            RideError: no positive ``vehicle_speed`` (the wheel cannot be placed), no track for
                a controlled wheel, or a stamp older than the newest held one.
        """
        speed = profiles.vehicle_speed
        if speed is None or not (math.isfinite(speed) and speed > 0):
            raise RideError("a preview without a positive vehicle_speed cannot be placed under the wheels")
        names = {t.name for t in profiles.tracks}
        for wheel in self.wheels:
            if not any(n in names for n in _TRACKS[wheel]):
                raise RideError(f"the preview has no track for {wheel} (tracks {sorted(names)})")
        if self.held and stamp_ns < self.held[-1].stamp_ns:
            raise RideError("preview stamps went back in time")
        if not (math.isfinite(wheel_x) and math.isfinite(slope_x)):
            raise RideError("wheel_x and slope_x must be finite")
        self.held.append(HeldPreview(int(stamp_ns), profiles, float(wheel_x), float(slope_x)))

    def reset(self) -> None:
        """Forget the messages and return the model to rest (e.g. after a time jump)."""
        self.held.clear()
        for w in self.wheels:
            self.state[w] = np.zeros(4)
            self.gains[w].reset()
            self.ridden[w].clear()

    def road_velocity_ahead(self, wheel: str, now_ns: int) -> np.ndarray:
        """[n + 1] the road velocity w' at the wheel now and every step ahead (NaN = unknown)."""
        ctl = self.controller
        n, dt = ctl.steps, ctl.dt
        out = np.full(n + 1, np.nan)
        for msg in reversed(self.held):  # newest first: fill only what newer ones left open
            if (now_ns - msg.stamp_ns) * 1e-9 > self.max_age_s or now_ns < msg.stamp_ns:
                continue
            v = float(msg.profiles.vehicle_speed or 0.0)
            track = next(t for t in _TRACKS[wheel] if t in {p.name for p in msg.profiles.tracks})
            x0 = msg.wheel_x + v * (now_ns - msg.stamp_ns) * 1e-9
            xs = x0 + v * dt * np.arange(n + 2)  # [n + 2]
            h = read_profile(msg.profiles, track, xs) + msg.slope_x * xs
            w = np.diff(h) / dt
            gap = np.isnan(out)
            out[gap] = w[gap]
        return out

    def step(self, now_ns: int, measured_road_velocity: Mapping[str, float] | None = None) -> dict[str, WheelCommand]:
        """One control step at ``now_ns``: the force per wheel, and the model advanced by ``dt``.

        Args:
            measured_road_velocity: the road velocity under each wheel now (m/s), as a vehicle's
                suspension sensors give it; None: the model's own (the newest previewed value).
        """
        ctl = self.controller
        Phi, Gu, Gw = ctl.matrices
        C, D = ctl.car.body_acceleration()
        out = {}
        for wheel in self.wheels:
            ahead = self.road_velocity_ahead(wheel, now_ns)
            known = np.isfinite(ahead)
            ff_preview = float(ctl.preview_gains @ np.where(known, ahead, 0.0))
            w_now = float(ahead[0]) if known[0] else 0.0
            if measured_road_velocity is not None and wheel in measured_road_velocity:
                w_now = float(measured_road_velocity[wheel])
            gain = self._gain(wheel, ff_preview, w_now)
            ff = gain * ff_preview
            x = self.state[wheel]
            u = -float(ctl.feedback @ x) - ff
            reach = int(np.argmin(known)) if not known.all() else known.size
            out[wheel] = WheelCommand(u, ff, gain, bool(known[0]), reach * ctl.dt * self._speed(),
                                      float(C @ x + D[0] * u))
            self.state[wheel] = Phi @ x + Gu[:, 0] * u + Gw[:, 0] * w_now
        return out

    def _gain(self, wheel: str, ff_preview: float, w_now: float) -> float:
        """The preview's gain for this step, after recording this step's feedforward and the road
        the wheel rides now (which completes the realised feedforward of the step a horizon ago)."""
        if not self.gain_time_constant_s:
            return 1.0
        gain, ridden = self.gains[wheel], self.ridden[wheel]
        value = gain.value
        ridden.append(w_now)
        realised = float(self.controller.preview_gains @ np.asarray(ridden)) if len(ridden) == ridden.maxlen else None
        gain.update(ff_preview, realised)
        return value

    def _speed(self) -> float:
        return float(self.held[-1].profiles.vehicle_speed or 0.0) if self.held else 0.0
