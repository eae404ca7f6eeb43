"""Keeping pace with the camera: a cheaper backend answers the frames the chosen one cannot.

A node slower than its camera answers each frame late (it waits for the node) and skips frames
(a newer set replaces the waiting one). At highway speed both cost the preview most of its worth:
the error of the road between the features, carried by the car's motion over a longer latency,
outweighs what a better estimate gains (docs/results/preview.md, "On a slower CPU"). So when the
chosen backend takes more of the camera's period per frame than ``pace_load`` allows, the pace
backend (``pace_backend``; for the default ensemble its cheapest member, ``bm``) answers instead,
and every few seconds (:data:`PROBE_EVERY` frames) the chosen backend answers one frame again,
so that its cost is measured afresh and it takes over again once it fits (the load on the machine
went away, the camera slowed down).

At speed the pace backend may answer even where the chosen one keeps up: a preview received later
reads the road ahead from a map that last saw it from farther away, and at 20-30 m/s the tens of
milliseconds between two backends carry the car further than a better estimate is worth
(docs/results/preview.md, "What the pace backend's estimate needs"). With ``lead_m`` set, the
pace backend answers while the car's speed times the chosen backend's extra busy time per frame
exceeds it; until the pace backend has answered a frame its time counts as none, so it answers
one to be measured once that rule could hold at all.

The camera's period is the median of the intervals between the arrivals of the last synchronised
sets (every set, those that a newer one replaced too), on the clock the node's busy time is
measured on (a bag replayed at twice its speed brings frames twice as fast as its stamps say). A
frame's cost is the node's busy time on it (estimate, map, outputs; waits for the IMU or odometry
left out), smoothed per backend (a probe's measurement replaces the chosen backend's). The
:class:`Pacer` is told the times; it reads no clock.
"""

from __future__ import annotations

import math
import statistics
import threading
from collections import deque
from dataclasses import dataclass

from roadbev_core.config import split_backend_spec

__all__ = ["MAX_INTERVAL_S", "PROBE_EVERY", "PaceState", "Pacer", "stand_in"]

# Every this many frames answered by the pace backend, the chosen one answers one (at a 10 Hz
# camera every 5 s): long enough that its extra time is a small share, short enough to notice
# that the load went away.
PROBE_EVERY = 50
# Intervals between sets longer than this are gaps in the stream (a paused bag, a camera that
# restarted), not its period.
MAX_INTERVAL_S = 1.0
_INTERVALS = 9  # sets whose intervals make the period (a median: one late set does not move it)
_SMOOTHING = 0.3  # weight of a frame's cost in its backend's running cost


def stand_in(pace_backend: str, backend: str) -> str:
    """The backend that answers for ``backend`` when it cannot keep pace: ``pace_backend`` (a name,
    or ``NAME:OPTION=VALUE,...``: :func:`roadbev_core.config.split_backend_spec`), or "" where that
    is empty or names ``backend`` itself (nothing cheaper to hand over to)."""
    if not pace_backend or split_backend_spec(pace_backend, "pace_backend")[0] == backend:
        return ""
    return pace_backend


@dataclass(frozen=True)
class PaceState:
    """What the pacer knows now (the node's ``pace`` diagnostic).

    Attributes:
        period_s: the camera's period (None: fewer than two sets yet).
        cost_s: the chosen backend's busy time per frame (None: not measured yet).
        pace_cost_s: the pace backend's (None: it has not answered yet).
        paced: whether the pace backend answers the next frame (a probe aside).
        probe_every: frames the pace backend answers between two the chosen one answers.
        speed_mps: the car's speed at the last choice (None: unknown).
        lead_m: the travel the chosen backend's extra time may cost (0: no such rule).
        by_speed: the pace backend answers for the speed rule, the chosen backend keeping up.
    """

    period_s: float | None
    cost_s: float | None
    pace_cost_s: float | None
    paced: bool
    probe_every: int = PROBE_EVERY
    speed_mps: float | None = None
    lead_m: float = 0.0
    by_speed: bool = False

    def describe(self, backend: str, pace_backend: str, load: float) -> str:
        """One line: who answers and why."""
        if self.period_s is None or self.cost_s is None:
            return f"{backend} answers (measuring its cost and the camera's period)"
        fit = (f"{backend} takes {1e3 * self.cost_s:.0f} ms a frame, the camera's period is "
               f"{1e3 * self.period_s:.0f} ms (pace_load {load:g})")
        if not self.paced:
            return f"{backend} answers: {fit}"
        pace = "" if self.pace_cost_s is None else f", {1e3 * self.pace_cost_s:.0f} ms a frame"
        if self.by_speed and self.speed_mps is not None:
            extra = _extra_s(self.cost_s, self.pace_cost_s)
            fit = (f"at {abs(self.speed_mps):.1f} m/s the {1e3 * extra:.0f} ms more a frame that {backend} takes "
                   f"are {abs(self.speed_mps) * extra:.2f} m of travel (pace_lead_m {self.lead_m:g})")
        return f"{pace_backend} answers{pace}: {fit}; {backend} answers one frame in {self.probe_every + 1}"


class Pacer:
    """Chooses, frame by frame, whether the pace backend answers (module docstring).

    Args:
        load: the largest share of the camera's period the chosen backend may take per frame.
        probe_every: frames answered by the pace backend between two answered by the chosen one.
        lead_m: the pace backend answers while the car's speed times the chosen backend's extra
            busy time per frame exceeds this (m); 0 = by ``load`` alone.
    """

    def __init__(self, load: float, probe_every: int = PROBE_EVERY, lead_m: float = 0.0) -> None:
        if not load > 0.0:
            raise ValueError(f"pace load must be positive, got {load}")
        if not lead_m >= 0.0:
            raise ValueError(f"pace lead must be a non-negative distance, got {lead_m}")
        self.load = load
        self.probe_every = probe_every
        self.lead_m = lead_m
        self._speed: float | None = None
        # the camera's sets come on the node's executor thread, the costs on its worker
        self._lock = threading.Lock()
        self._last_arrival_s: float | None = None
        self._intervals: deque[float] = deque(maxlen=_INTERVALS)
        self._cost: float | None = None
        self._pace_cost: float | None = None
        self._paced_in_a_row = 0

    def reset(self) -> None:
        """Forget the stream (a new pass of a looped bag); the costs are kept."""
        with self._lock:
            self._last_arrival_s = None
            self._intervals.clear()

    def note_set(self, arrival_s: float) -> None:
        """A synchronised set of the camera arrived at ``arrival_s`` (seconds, a monotonic clock)."""
        with self._lock:
            last, self._last_arrival_s = self._last_arrival_s, arrival_s
            if last is None:
                return
            interval = arrival_s - last
            if 0.0 < interval <= MAX_INTERVAL_S:
                self._intervals.append(interval)

    @property
    def period_s(self) -> float | None:
        """The camera's period: the median interval between the last sets (None: none yet)."""
        with self._lock:
            return self._period()

    def _period(self) -> float | None:
        return statistics.median(self._intervals) if self._intervals else None

    def _fits(self) -> bool:
        """Whether the chosen backend's cost fits the camera's period (or either is unknown)."""
        period = self._period()
        return period is None or self._cost is None or self._cost <= self.load * period

    def _lags(self) -> bool:
        """Whether at the last speed the chosen backend's extra busy time per frame over the pace
        backend's (taken as none until it is measured) carries the car more than ``lead_m``."""
        if not self.lead_m or self._speed is None or self._cost is None:
            return False
        return abs(self._speed) * _extra_s(self._cost, self._pace_cost) > self.lead_m

    def choose(self, speed_mps: float | None = None) -> bool:
        """Whether the pace backend answers the next frame, the car going at ``speed_mps`` (None:
        unknown, and the speed rule is off)."""
        with self._lock:
            self._speed = speed_mps if speed_mps is not None and math.isfinite(speed_mps) else None
            return (not self._fits() or self._lags()) and self._paced_in_a_row < self.probe_every

    def note_cost(self, paced: bool, busy_s: float) -> None:
        """The busy time of a frame just answered, by the pace backend (``paced``) or the chosen one."""
        with self._lock:
            if paced:
                self._pace_cost = _smoothed(self._pace_cost, busy_s)
                self._paced_in_a_row += 1
            else:
                # a probe's cost replaces the running one: the load may have changed since the last
                probe = self._paced_in_a_row > 0
                self._cost = busy_s if probe else _smoothed(self._cost, busy_s)
                self._paced_in_a_row = 0

    def state(self) -> PaceState:
        """What it knows now."""
        with self._lock:
            fits, lags = self._fits(), self._lags()
            return PaceState(self._period(), self._cost, self._pace_cost, not fits or lags, self.probe_every,
                             self._speed, self.lead_m, fits and lags)


def _extra_s(cost_s: float, pace_cost_s: float | None) -> float:
    """The chosen backend's busy time per frame beyond the pace backend's (none until measured)."""
    return cost_s - (pace_cost_s or 0.0)


def _smoothed(running: float | None, value: float) -> float:
    return value if running is None else (1.0 - _SMOOTHING) * running + _SMOOTHING * value
