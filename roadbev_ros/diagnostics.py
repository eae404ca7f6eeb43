"""The node's health figures: rates, latencies, drops and input problems, for ``/diagnostics``.

``diagnostic_updater`` has no wheel on PyPI, so this module keeps the figures itself and
:func:`to_diagnostic_array` turns a :class:`HealthSnapshot` into a
``diagnostic_msgs/DiagnosticArray`` (imported lazily: the rest of the module is plain Python and
thread-safe, since callbacks and the inference worker both report here).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "Health",
    "HealthSnapshot",
    "LatencyWindow",
    "RateMeter",
    "ThrottledLog",
    "to_diagnostic_array",
]

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels
_LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}


class RateMeter:
    """Events per second over a sliding window (monotonic clock).

    Args:
        window_s: length of the window.
        clock: seconds, monotonic (injectable for tests).
    """

    def __init__(self, window_s: float = 2.0, clock: Callable[[], float] = time.monotonic) -> None:
        self._window = window_s
        self._clock = clock
        self._times: deque[float] = deque()
        self.total = 0

    def tick(self) -> None:
        now = self._clock()
        self._times.append(now)
        self.total += 1
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self._times and self._times[0] < now - self._window:
            self._times.popleft()

    def rate(self) -> float:
        """Events per second in the last window (0 when fewer than two events)."""
        now = self._clock()
        self._trim(now)
        if len(self._times) < 2:
            return 0.0
        span = max(now - self._times[0], self._times[-1] - self._times[0])
        return (len(self._times) - 1) / span if span > 0 else 0.0


class LatencyWindow:
    """The last ``size`` samples of a duration, with percentiles (milliseconds)."""

    def __init__(self, size: int = 200) -> None:
        self._values: deque[float] = deque(maxlen=size)

    def add(self, value_ms: float) -> None:
        if math.isfinite(value_ms):
            self._values.append(float(value_ms))

    def __len__(self) -> int:
        return len(self._values)

    def percentile(self, q: float) -> float:
        """The q-th percentile (0..100) by linear interpolation; NaN when empty."""
        if not self._values:
            return math.nan
        values = sorted(self._values)
        pos = (len(values) - 1) * q / 100.0
        lo = int(math.floor(pos))
        hi = min(lo + 1, len(values) - 1)
        return values[lo] + (values[hi] - values[lo]) * (pos - lo)

    def mean(self) -> float:
        return sum(self._values) / len(self._values) if self._values else math.nan


class ThrottledLog:
    """Lets a message with a given key through at most once per ``period_s`` (and counts the rest)."""

    def __init__(self, period_s: float = 5.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.period_s = period_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self.suppressed: Counter[str] = Counter()

    def allow(self, key: str) -> bool:
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self.period_s:
            self.suppressed[key] += 1
            return False
        self._last[key] = now
        return True


@dataclass(frozen=True)
class HealthSnapshot:
    """What ``/diagnostics`` reports once a period.

    Attributes:
        level: 0 OK, 1 WARN, 2 ERROR.
        message: one-line summary.
        values: key -> value (strings), in a stable order.
    """

    level: int
    message: str
    values: dict[str, str]


@dataclass
class Health:
    """Thread-safe counters of the node, read by the diagnostics timer.

    Counters are totals since start; ``problems`` counts input problems by kind (for example
    ``"bad image"``, ``"imu stale"``) and ``last_error`` keeps the latest reason in words.
    """

    backend: str = ""
    window_s: float = 2.0
    problem_window_s: float = 5.0
    clock: Callable[[], float] = time.monotonic
    input_rate: RateMeter = field(init=False)
    set_rate: RateMeter = field(init=False)
    output_rate: RateMeter = field(init=False)
    latency_ms: LatencyWindow = field(default_factory=LatencyWindow)
    stamp_age_ms: LatencyWindow = field(default_factory=LatencyWindow)
    inference_ms: LatencyWindow = field(default_factory=LatencyWindow)
    overhead_ms: LatencyWindow = field(default_factory=LatencyWindow)
    imu_wait_ms: LatencyWindow = field(default_factory=LatencyWindow)
    frames_in: int = 0
    sets: int = 0
    outputs: int = 0
    dropped_busy: int = 0
    dropped_sync: int = 0
    dropped_invalid: int = 0
    problems: Counter[str] = field(default_factory=Counter)
    time_jumps: int = 0
    last_error: str = ""
    last_error_time: float = -math.inf
    imu_age_s: float | None = None
    coverage_pct: float | None = None  # the latest frame's (roadbev_core.selfcheck)
    coverage_ok: bool = True
    coverage_hint: str = ""

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self.input_rate = RateMeter(self.window_s, self.clock)
        self.set_rate = RateMeter(self.window_s, self.clock)
        self.output_rate = RateMeter(self.window_s, self.clock)

    def frame_in(self) -> None:
        """A left image arrived."""
        with self._lock:
            self.frames_in += 1
            self.input_rate.tick()

    def set_in(self) -> None:
        """A synchronised set reached the worker's mailbox."""
        with self._lock:
            self.sets += 1
            self.set_rate.tick()

    def output(self, latency_ms: float, stamp_age_ms: float, inference_ms: float, overhead_ms: float,
               imu_wait_ms: float = 0.0) -> None:
        """An elevation map was published.

        Args:
            latency_ms: set complete (last message received) to outputs published.
            stamp_age_ms: outputs published minus the image stamp (end to end on a live clock).
            inference_ms: the backend's ``estimate``.
            overhead_ms: the node's own work (conversions, preview, publishing).
            imu_wait_ms: time spent waiting for an IMU sample at or after the image stamp.
        """
        with self._lock:
            self.outputs += 1
            self.output_rate.tick()
            self.latency_ms.add(latency_ms)
            self.stamp_age_ms.add(stamp_age_ms)
            self.inference_ms.add(inference_ms)
            self.overhead_ms.add(overhead_ms)
            self.imu_wait_ms.add(imu_wait_ms)

    def drop(self, kind: str, count: int = 1) -> None:
        """Frames lost: ``busy`` (worker still busy: newest kept), ``sync`` (never paired),
        ``invalid`` (refused input)."""
        with self._lock:
            if kind == "busy":
                self.dropped_busy += count
            elif kind == "sync":
                self.dropped_sync += count
            else:
                self.dropped_invalid += count

    def coverage(self, coverage_pct: float, ok: bool, hint: str) -> None:
        """The latest frame's self-check (:func:`roadbev_core.selfcheck.self_check`: its
        ``coverage_pct``, ``ok`` and ``message``); WARN with the hint while coverage is low."""
        with self._lock:
            self.coverage_pct = float(coverage_pct)
            self.coverage_ok = bool(ok)
            self.coverage_hint = hint

    def time_jump(self) -> None:
        """The stamps jumped back (a looped bag): counted, not a problem."""
        with self._lock:
            self.time_jumps += 1

    def problem(self, kind: str, reason: str) -> None:
        """An input or processing problem (counted by kind; the reason is kept as last error)."""
        with self._lock:
            self.problems[kind] += 1
            self.last_error = f"{kind}: {reason}"
            self.last_error_time = self.clock()

    def snapshot(self) -> HealthSnapshot:
        """The figures now, with a level: WARN while a problem was reported in the last
        ``problem_window_s`` or nothing is produced although sets arrive."""
        with self._lock:
            recent_problem = self.clock() - self.last_error_time < self.problem_window_s
            out_rate = self.output_rate.rate()
            in_rate = self.input_rate.rate()
            values = {
                "backend": self.backend,
                "input_rate_hz": f"{in_rate:.2f}",
                "set_rate_hz": f"{self.set_rate.rate():.2f}",
                "output_rate_hz": f"{out_rate:.2f}",
                "latency_p50_ms": f"{self.latency_ms.percentile(50):.1f}",
                "latency_p95_ms": f"{self.latency_ms.percentile(95):.1f}",
                "stamp_age_p50_ms": f"{self.stamp_age_ms.percentile(50):.1f}",
                "inference_mean_ms": f"{self.inference_ms.mean():.1f}",
                "inference_p50_ms": f"{self.inference_ms.percentile(50):.1f}",
                "overhead_mean_ms": f"{self.overhead_ms.mean():.2f}",
                "overhead_p95_ms": f"{self.overhead_ms.percentile(95):.2f}",
                "imu_wait_mean_ms": f"{self.imu_wait_ms.mean():.2f}",
                "frames_in": str(self.frames_in),
                "sets": str(self.sets),
                "outputs": str(self.outputs),
                "dropped_busy": str(self.dropped_busy),
                "dropped_sync": str(self.dropped_sync),
                "dropped_invalid": str(self.dropped_invalid),
                "imu_age_s": "none" if self.imu_age_s is None else f"{self.imu_age_s:.3f}",
                "time_jumps": str(self.time_jumps),
                "last_error": self.last_error,
                "coverage_pct": "none" if self.coverage_pct is None else f"{self.coverage_pct:.1f}",
                "self_check": self.coverage_hint,
            }
            low_coverage = not self.coverage_ok
            for kind, count in sorted(self.problems.items()):
                values[f"problem.{kind}"] = str(count)
        if recent_problem:
            level, message = WARN, self.last_error
        elif in_rate > 0 and out_rate == 0:
            level, message = WARN, "input arrives but nothing is published"
        elif low_coverage:
            level, message = WARN, self.coverage_hint or "low coverage"
        else:
            level, message = OK, "ok" if self.outputs else "waiting for input"
        return HealthSnapshot(level, message, values)


def to_diagnostic_array(snapshot: HealthSnapshot, stamp: Any, name: str = "roadbev: pipeline",
                        hardware_id: str = "roadbev") -> Any:
    """A ``diagnostic_msgs/DiagnosticArray`` holding one status built from ``snapshot``.

    Args:
        snapshot: the figures.
        stamp: a ``builtin_interfaces/Time`` for the header.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    status = DiagnosticStatus()
    status.level = bytes([snapshot.level])
    status.name = name
    status.message = snapshot.message[:500]
    status.hardware_id = hardware_id
    status.values = [KeyValue(key=k, value=v) for k, v in snapshot.values.items()]
    array = DiagnosticArray()
    array.header.stamp = stamp
    array.status = [status]
    return array


def level_name(level: int) -> str:
    """``OK``, ``WARN`` or ``ERROR``."""
    return _LEVEL_NAMES.get(level, str(level))


def problem_kind(exc: Exception) -> str:
    """The diagnostics kind under which a refused frame is counted and logged."""
    from roadbev_core.attitude import ImuStale
    from roadbev_core.frame import FrameError
    from roadbev_core.preview import PreviewError

    kinds = ((ImuStale, "imu stale"), (FrameError, "bad frame"), (PreviewError, "preview"))
    return next((kind for cls, kind in kinds if isinstance(exc, cls)), "bad input")
