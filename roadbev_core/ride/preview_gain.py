"""How much of its preview a controller should apply: the preview's gain, measured as it drives.

A preview is only worth its feedforward when it is right; a noisy one (a backend that declines
half the road, a texture it cannot match) drives the actuator against the road and makes the
ride worse than the controller without preview. Whether a preview was right is known a horizon
later, once the wheel has ridden the road it previewed: the feedforward the true road velocity
would have given at step k (``Kw . w'[k .. k + n]``, the road under the wheel being what the
suspension measures as the wheel passes) can then be set against the feedforward the preview
gave. :class:`PreviewGain` keeps the exponentially weighted least-squares gain of the one on the
other (recursive least squares with a forgetting factor: Ljung and Söderström, *Theory and
Practice of Recursive Identification*, MIT Press 1983, ch. 2):

    g[k] = sum_j a^(k-j) f_p[j] f_r[j] / sum_j a^(k-j) f_p[j]^2,   j <= k - n,   a = exp(-dt / tau)

clipped to [0, 1], and the controller applies ``g`` times its feedforward (certainty equivalence
with the preview's measured reliability). A preview that follows the road keeps g near 1; one
that is mostly wrong drives it to 0, the controller without preview; until a horizon has been
ridden g is 1. Pure numpy.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from roadbev_core.ride.quarter_car import RideError

__all__ = ["DEFAULT_TIME_CONSTANT_S", "PreviewGain", "preview_gains"]

# Forgetting time constant: a few seconds of road (several features at city speed), short enough
# to follow a change of road or light.
DEFAULT_TIME_CONSTANT_S = 3.0
_MIN_ENERGY = 1e-6  # N^2: below this much previewed feedforward the gain stays where it is


def preview_gains(previewed: np.ndarray, realised: np.ndarray, lag_steps: int, dt: float,
                  time_constant_s: float = DEFAULT_TIME_CONSTANT_S) -> np.ndarray:
    """[J] the gain at every step of a ride (see the module docstring).

    Args:
        previewed: [J] the preview's feedforward at each step (N).
        realised: [J] the feedforward the true road velocity gives at each step (N).
        lag_steps: n, the steps until a step's realised feedforward is known (the horizon).
        dt: the step (s).
        time_constant_s: tau of the forgetting.
    """
    f_p = np.asarray(previewed, np.float64)
    f_r = np.asarray(realised, np.float64)
    if f_p.shape != f_r.shape or f_p.ndim != 1:
        raise RideError(f"previewed {f_p.shape} and realised {f_r.shape} feedforward must be equal 1-D arrays")
    gain = PreviewGain(lag_steps, dt, time_constant_s)
    out = np.empty(f_p.size)
    a = gain.forgetting
    num = den = 0.0
    for k in range(f_p.size):
        out[k] = gain.value_of(num, den)
        j = k - lag_steps
        if j >= 0:
            num = a * num + f_p[j] * f_r[j]
            den = a * den + f_p[j] * f_p[j]
    return out


@dataclass
class PreviewGain:
    """The gain online, one step at a time (see the module docstring).

    Attributes:
        lag_steps: n, the preview horizon in steps.
        dt: the control step (s).
        time_constant_s: tau of the forgetting.
    """

    lag_steps: int
    dt: float
    time_constant_s: float = DEFAULT_TIME_CONSTANT_S
    _previewed: deque[float] = field(init=False, repr=False)
    _num: float = field(default=0.0, init=False, repr=False)
    _den: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.lag_steps < 0 or not (math.isfinite(self.dt) and self.dt > 0):
            raise RideError(f"lag must be >= 0 steps and dt > 0, got {self.lag_steps}, {self.dt}")
        if not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise RideError(f"the time constant must be > 0 s, got {self.time_constant_s}")
        self._previewed = deque(maxlen=self.lag_steps + 1)

    @property
    def forgetting(self) -> float:
        """a = exp(-dt / tau)."""
        return math.exp(-self.dt / self.time_constant_s)

    @staticmethod
    def value_of(num: float, den: float) -> float:
        """The clipped gain of the weighted sums (1 until the preview has given any feedforward)."""
        if den < _MIN_ENERGY:
            return 1.0
        return min(1.0, max(0.0, num / den))

    @property
    def value(self) -> float:
        """The gain to apply now."""
        return self.value_of(self._num, self._den)

    def update(self, previewed_n: float, realised_lagged_n: float | None) -> None:
        """Record this step's previewed feedforward; ``realised_lagged_n`` is the feedforward the
        road the wheel has now ridden gives for the step ``lag_steps`` ago (None while unknown)."""
        self._previewed.append(float(previewed_n))
        if realised_lagged_n is None or len(self._previewed) <= self.lag_steps:
            return
        f_p = self._previewed[0]
        a = self.forgetting
        self._num = a * self._num + f_p * float(realised_lagged_n)
        self._den = a * self._den + f_p * f_p

    def reset(self) -> None:
        self._previewed.clear()
        self._num = self._den = 0.0
