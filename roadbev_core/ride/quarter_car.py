"""The quarter-car ride model: one corner's sprung and unsprung mass with an actuator.

Two masses on two springs (Gillespie, "Fundamentals of Vehicle Dynamics", SAE 1992, ch. 5;
the quarter car of preview-control studies: Bender 1968, Thompson 1976, Hac 1992): the body
share ``m_s`` on the suspension spring ``k_s`` and damper ``c_s``, the wheel ``m_u`` on the tyre
spring ``k_t`` (point contact on the road height ``w`` under the tyre), and an actuator force
``u`` between body and wheel (positive pushes the body up and the wheel down). States, all
deviations from static equilibrium::

    x = [x1, x2, x3, x4] = [z_s - z_u (suspension deflection, m), z_s' (body velocity, m/s),
                            z_u - w (tyre deflection, m), z_u' (wheel velocity, m/s)]

    x1' = x2 - x4
    x2' = (-k_s x1 - c_s (x2 - x4) + u) / m_s
    x3' = x4 - w'
    x4' = ( k_s x1 + c_s (x2 - x4) - k_t x3 - u) / m_u

The road enters as its velocity ``w'`` (the slope along the path times the speed), so a road
profile given in any reference that differs from the truth by a constant offset drives the model
identically. Default parameters: one corner of the synthetic drives' car
(:class:`roadbev_lab.synth.SuspensionSpec`: 1500 kg body on four 21 kN/m, 1.68 kNs/m corners ->
375 kg, body mode 1.19 Hz, damping ratio 0.30), with a 40 kg wheel and a 200 kN/m tyre (wheel
hop about 11.8 Hz): the ranges of Gillespie's Table 5.1 (body 1-1.5 Hz, wheel hop 10-12 Hz,
m_u / m_s ~ 0.1, k_t / k_s ~ 10). Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np

from roadbev_core.errors import RoadbevError
from roadbev_core.ride.lti import discretise

__all__ = ["FRONT_WHEELS", "GRAVITY", "QuarterCar", "RideError"]

GRAVITY = 9.81
# The wheels a preview reaches before the car does (the rear ones ride what the front ones rode).
FRONT_WHEELS: tuple[str, ...] = ("front_left", "front_right")


class RideError(RoadbevError, ValueError):
    """Ride-model, controller or simulation inputs that cannot be used."""


@dataclass(frozen=True)
class QuarterCar:
    """Quarter-car parameters (SI units; see the module docstring).

    Attributes:
        sprung_mass_kg: body mass carried by this corner (m_s).
        unsprung_mass_kg: wheel, brake, hub and part of the links (m_u).
        spring_n_per_m: suspension stiffness at the wheel (k_s).
        damper_ns_per_m: passive damper rate at the wheel (c_s).
        tyre_n_per_m: tyre vertical stiffness (k_t).
    """

    sprung_mass_kg: float = 375.0
    unsprung_mass_kg: float = 40.0
    spring_n_per_m: float = 21_000.0
    damper_ns_per_m: float = 1_684.0
    tyre_n_per_m: float = 200_000.0

    def __post_init__(self) -> None:
        values = [getattr(self, f) for f in self.__dataclass_fields__]
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise RideError(f"quarter-car parameters must be positive and finite, got {self}")

    @property
    def static_tyre_load_n(self) -> float:
        """The tyre's static load (m_s + m_u) g (N)."""
        return (self.sprung_mass_kg + self.unsprung_mass_kg) * GRAVITY

    def body_frequency_hz(self) -> float:
        """Undamped body mode on the series stiffness of spring and tyre (Hz)."""
        k = self.spring_n_per_m * self.tyre_n_per_m / (self.spring_n_per_m + self.tyre_n_per_m)
        return math.sqrt(k / self.sprung_mass_kg) / (2 * math.pi)

    def wheel_hop_hz(self) -> float:
        """Undamped wheel-hop mode, body held still (Hz)."""
        return math.sqrt((self.spring_n_per_m + self.tyre_n_per_m) / self.unsprung_mass_kg) / (2 * math.pi)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A [4, 4], B [4, 1] (actuator force u), E [4, 1] (road velocity w') of x' = A x + B u + E w'."""
        ms, mu = self.sprung_mass_kg, self.unsprung_mass_kg
        ks, cs, kt = self.spring_n_per_m, self.damper_ns_per_m, self.tyre_n_per_m
        A = np.array([
            [0.0, 1.0, 0.0, -1.0],
            [-ks / ms, -cs / ms, 0.0, cs / ms],
            [0.0, 0.0, 0.0, 1.0],
            [ks / mu, cs / mu, -kt / mu, -cs / mu],
        ])
        B = np.array([[0.0], [1.0 / ms], [0.0], [-1.0 / mu]])
        E = np.array([[0.0], [0.0], [-1.0], [0.0]])
        return A, B, E

    def body_acceleration(self) -> tuple[np.ndarray, np.ndarray]:
        """C [4], D (scalar as [1]) of the body's acceleration z_s'' = C x + D u."""
        ms = self.sprung_mass_kg
        C = np.array([-self.spring_n_per_m / ms, -self.damper_ns_per_m / ms, 0.0, self.damper_ns_per_m / ms])
        return C, np.array([1.0 / ms])

    def discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Phi [4, 4], Gamma_u [4, 1], Gamma_w [4, 1]: zero-order hold on u and w' at step ``dt``
        (exact for a road that is linear between samples)."""
        A, B, E = self.continuous()
        Phi, G = discretise(A, np.hstack([B, E]), dt)
        return Phi, G[:, :1], G[:, 1:]

    def transmissibility(self, frequency_hz: np.ndarray | float) -> np.ndarray:
        """|z_s / w| of the passive car (u = 0) at ``frequency_hz`` [...]: the analytic body
        displacement transmissibility of the two-mass model."""
        s = 2j * math.pi * np.asarray(frequency_hz, np.float64)
        ms, mu = self.sprung_mass_kg, self.unsprung_mass_kg
        ks, cs, kt = self.spring_n_per_m, self.damper_ns_per_m, self.tyre_n_per_m
        susp = cs * s + ks
        den = (ms * s * s + susp) * (mu * s * s + susp + kt) - susp * susp
        return cast("np.ndarray", np.abs(susp * kt / den))
