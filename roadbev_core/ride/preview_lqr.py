"""Optimal linear preview control of an active quarter-car suspension (discrete-time LQR).

The control law of Bender (E. K. Bender, "Optimum linear preview control with application to
vehicle suspension", ASME J. Basic Engineering 90(2), 213-221, 1968) and Tomizuka (M. Tomizuka,
"Optimum linear preview control with application to vehicle suspension - revisited", ASME J.
Dynamic Systems, Measurement and Control 98(3), 309-315, 1976), in the discrete-time form of
Tomizuka and Whitney ("Optimal discrete finite preview problems", ASME JDSMC 97(4), 1975) and
Hac ("Optimal linear preview control of active vehicle suspension", Vehicle System Dynamics
21(1), 167-195, 1992). With the quarter car ``x[k+1] = Phi x[k] + Gu u[k] + Gw w'[k]``
(:meth:`QuarterCar.discrete`) and the cost

    J = sum_k  rho_a a[k]^2 + rho_t x1[k]^2 + rho_d x3[k]^2 + rho_u u[k]^2   (times dt)

(body acceleration a = C x + D u, suspension travel x1, tyre deflection x3 = dynamic tyre load
/ k_t, actuator force u), the optimal force given the road velocity w'[k .. k + n] over a
preview of n steps (w' = 0 assumed beyond) is

    u[k] = -K x[k] - sum_{j=0..n} Kw[j] w'[k + j],
    K = S^-1 (Gu' P Phi + N'),  Kw[j] = S^-1 Gu' (Ac')^j P Gw,  S = R + Gu' P Gu,  Ac = Phi - Gu K,

with P the stabilising solution of the discrete Riccati equation (:func:`solve_dare`; Q, N, R
the cost above). The feedback part alone (``Kw`` = 0) is the same controller without preview.
The gains Kw[j] decay with the closed loop's time constants: a preview longer than about 1 s
adds nothing for a car body. Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from roadbev_core.ride.lti import solve_dare
from roadbev_core.ride.quarter_car import QuarterCar, RideError

__all__ = ["LqrWeights", "PreviewLqr"]


@dataclass(frozen=True)
class LqrWeights:
    """Weights of the quadratic cost (each term's square, SI units).

    Defaults: chosen once on two truth-only drives (speed bumps at 10 m/s and an ISO 8608 class
    D road at 20 m/s, seed 7, not a benchmark seed) from a 3 x 3 grid (travel 1e3 / 5e3 / 2e4,
    tyre 1e4 / 5e4 / 2e5) for a controller without preview that is clearly better than the
    passive car at a small cost in peak travel and tyre-load variation; never tuned on any
    preview.

    Attributes:
        body_acceleration: on (m/s^2)^2.
        suspension_travel: on m^2.
        tyre_deflection: on m^2 (k_t x3 is the dynamic tyre load).
        force: on N^2 (actuator effort).
    """

    body_acceleration: float = 1.0
    suspension_travel: float = 5.0e3
    tyre_deflection: float = 5.0e4
    force: float = 1.0e-8

    def __post_init__(self) -> None:
        values = [getattr(self, f) for f in self.__dataclass_fields__]
        if not all(math.isfinite(v) and v >= 0 for v in values) or self.body_acceleration + self.force <= 0:
            raise RideError(f"LQR weights must be finite and >= 0, with a positive force or acceleration "
                            f"weight, got {self}")


@dataclass(frozen=True)
class PreviewLqr:
    """The preview LQR of a quarter car at step ``dt`` with ``horizon_s`` of preview.

    Attributes:
        car: the plant.
        dt: control step (s).
        horizon_s: preview length (s); ``n = round(horizon_s / dt)`` future steps.
        weights: the cost.
        matrices: (derived) Phi [4, 4], Gu [4, 1], Gw [4, 1] of the discretised car.
        feedback: (derived) K [4]: u = -K x (+ the preview term).
        preview_gains: (derived) Kw [n + 1]: the weight of the road velocity j steps ahead (N s/m).
    """

    car: QuarterCar = field(default_factory=QuarterCar)
    dt: float = 0.001
    horizon_s: float = 1.0
    weights: LqrWeights = field(default_factory=LqrWeights)
    # derived in __post_init__: Phi [4, 4], Gu [4, 1], Gw [4, 1]; K [4] (u = -K x + ...); Kw [n + 1]
    matrices: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)
    feedback: np.ndarray = field(init=False, repr=False, compare=False)
    preview_gains: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dt) and 1e-4 <= self.dt <= 0.02):
            raise RideError(f"the control step must be in [0.1, 20] ms, got {self.dt} s")
        if not (math.isfinite(self.horizon_s) and 0.0 <= self.horizon_s <= 5.0):
            raise RideError(f"the preview horizon must be in [0, 5] s, got {self.horizon_s}")
        Phi, Gu, Gw = self.car.discrete(self.dt)
        C, D = self.car.body_acceleration()
        w = self.weights
        Q = (w.body_acceleration * np.outer(C, C)
             + np.diag([w.suspension_travel, 0.0, w.tyre_deflection, 0.0])) * self.dt
        N = (w.body_acceleration * C[:, None] * D[0]) * self.dt  # [4, 1]
        R = np.array([[w.body_acceleration * D[0] ** 2 + w.force]]) * self.dt
        P = solve_dare(Phi, Gu, Q, R, N)
        S = R + Gu.T @ P @ Gu  # [1, 1]
        K = np.linalg.solve(S, Gu.T @ P @ Phi + N.T)  # [1, 4]
        Ac = Phi - Gu @ K
        n = int(round(self.horizon_s / self.dt))
        gains = np.empty(n + 1)
        v = P @ Gw  # [4, 1] (Ac')^j P Gw, j = 0
        AcT = Ac.T
        for j in range(n + 1):
            gains[j] = float(np.linalg.solve(S, Gu.T @ v)[0, 0])
            v = AcT @ v
        object.__setattr__(self, "matrices", (Phi, Gu, Gw))
        object.__setattr__(self, "feedback", K[0])
        object.__setattr__(self, "preview_gains", gains)

    @property
    def steps(self) -> int:
        """n, the number of future steps previewed."""
        return int(self.preview_gains.size - 1)

    def force(self, state: np.ndarray, road_velocity_ahead: np.ndarray | None) -> float:
        """The actuator force (N) for ``state`` [4] and the road velocity ahead [<= n + 1]
        (w'[k], w'[k + 1], ...; NaN or missing entries count as 0: a flat road); None: no preview."""
        u = -float(self.feedback @ np.asarray(state, np.float64))
        if road_velocity_ahead is not None:
            w = np.nan_to_num(np.asarray(road_velocity_ahead, np.float64)[: self.steps + 1], nan=0.0)
            u -= float(self.preview_gains[: w.size] @ w)
        return u

    def feedforward(self, road_velocity: np.ndarray) -> np.ndarray:
        """[J] the preview term sum_j Kw[j] w'[k + j] for every step k of a known road velocity
        [J] (NaN = 0; zero beyond the end): the controller with a perfect preview."""
        w = np.nan_to_num(np.asarray(road_velocity, np.float64), nan=0.0)
        padded = np.concatenate([w, np.zeros(self.steps)])
        return np.correlate(padded, self.preview_gains, mode="valid")
