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

from roadbev_core.attitude import ImuStale
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import FrameError, ImplausibleFrame
from roadbev_core.preview import PreviewError

__all__ = [
    "COMPRESSED_SUFFIX",
    "DROP_KINDS",
    "Check",
    "ClockWatch",
    "Health",
    "HealthSnapshot",
    "LatencyWindow",
    "NodeDiagnostics",
    "OutputTally",
    "ProblemLog",
    "RateMeter",
    "ThrottledLog",
    "far_field_state",
    "frequency_check",
    "late_output",
    "node_values",
    "other_transport",
    "stamp_check",
    "to_diagnostic_array",
    "transport_hint",
]

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels
# The counters of left images that became no output: with ``outputs`` they account for every one.
DROP_KINDS: tuple[str, ...] = ("dropped_busy", "dropped_sync", "dropped_invalid", "dropped_stale")
_LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}


class RateMeter:
    """Events per second over a sliding window (monotonic clock).

    Args:
        window_s: length of the window.
        clock: seconds, monotonic (injectable for tests).
    """

    def __init__(self, window_s: float = 2.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.window_s = window_s
        self._clock = clock
        self._times: deque[float] = deque()
        self._first: float | None = None
        self._last: float | None = None
        self.total = 0

    def tick(self) -> None:
        now = self._clock()
        self._times.append(now)
        self._last = now
        self._first = now if self._first is None else self._first
        self.total += 1
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self._times and self._times[0] < now - self.window_s:
            self._times.popleft()

    def in_window(self) -> int:
        """Events in the last window."""
        self._trim(self._clock())
        return len(self._times)

    def full(self) -> bool:
        """Whether the first event is at least a window ago (before, a rate says little)."""
        return self._first is not None and self._clock() - self._first >= self.window_s

    def last(self) -> float | None:
        """Monotonic time of the last event (None before the first)."""
        return self._last


    def rate(self) -> float:
        """Events per second in the last window (0 when fewer than two events)."""
        now = self._clock()
        self._trim(now)
        if len(self._times) < 2:
            return 0.0
        span = max(now - self._times[0], self._times[-1] - self._times[0])
        return (len(self._times) - 1) / span if span > 0 else 0.0


class LatencyWindow:
    """The samples of a duration from the last ``window_s`` seconds (at most ``size``), with
    percentiles (milliseconds): after ``window_s`` without a sample it is empty again, so figures
    of a stream that stopped do not stay on show."""

    def __init__(self, size: int = 200, window_s: float = math.inf,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._values: deque[tuple[float, float]] = deque(maxlen=size)  # (monotonic time, value)
        self.window_s = window_s
        self._clock = clock

    def add(self, value_ms: float) -> None:
        if math.isfinite(value_ms):
            self._values.append((self._clock(), float(value_ms)))

    def _recent(self) -> list[float]:
        cut = self._clock() - self.window_s
        while self._values and self._values[0][0] < cut:
            self._values.popleft()
        return [v for _, v in self._values]

    def __len__(self) -> int:
        return len(self._recent())

    def percentile(self, q: float) -> float:
        """The q-th percentile (0..100) by linear interpolation; NaN when empty."""
        values = sorted(self._recent())
        if not values:
            return math.nan
        pos = (len(values) - 1) * q / 100.0
        lo = int(math.floor(pos))
        hi = min(lo + 1, len(values) - 1)
        return values[lo] + (values[hi] - values[lo]) * (pos - lo)

    def mean(self) -> float:
        values = self._recent()
        return sum(values) / len(values) if values else math.nan

    def extremes(self) -> tuple[float, float]:
        """(smallest, largest) sample in the window; NaNs when empty."""
        values = self._recent()
        return (min(values), max(values)) if values else (math.nan, math.nan)


@dataclass(frozen=True)
class Check:
    """One status of ``/diagnostics`` (a diagnostic_updater task): level, message, values."""

    name: str
    level: int
    message: str
    values: dict[str, str]


def frequency_check(rate: RateMeter, min_hz: float, max_hz: float, tolerance: float, *, what: str,
                    never: str = "waiting for input", silent_s: float | None = None) -> Check:
    """diagnostic_updater's ``FrequencyStatus`` over ``rate``'s window: ERROR without events in
    the window (WARN before the first event ever), WARN outside ``[min (1 - tol), max (1 + tol)]``
    (a bound of 0 is no bound; the lower one only once the first event is a window old), else OK.

    Args:
        silent_s: seconds since the last event (for the message).
    """
    hz = rate.rate()
    events = rate.in_window()
    values = {
        "Events in window": str(events),
        "Events since startup": str(rate.total),
        "Duration of window (s)": f"{rate.window_s:.1f}",
        "Actual frequency (Hz)": f"{hz:.2f}",
        "Minimum acceptable frequency (Hz)": f"{min_hz * (1 - tolerance):.2f}" if min_hz else "none",
        "Maximum acceptable frequency (Hz)": f"{max_hz * (1 + tolerance):.2f}" if max_hz else "none",
    }
    name = f"{what} rate"
    if rate.total == 0:
        return Check(name, WARN, never, values)
    if events == 0:
        since = f" for {silent_s:.1f} s" if silent_s is not None else ""
        return Check(name, ERROR, f"stale: no {what}{since} (window {rate.window_s:g} s)", values)
    if min_hz and hz < min_hz * (1 - tolerance) and rate.full():
        return Check(name, WARN, f"{what} rate too low: {hz:.2f} Hz (expected at least {min_hz:g} Hz)", values)
    if max_hz and hz > max_hz * (1 + tolerance):
        return Check(name, WARN, f"{what} rate too high: {hz:.2f} Hz (expected at most {max_hz:g} Hz)", values)
    return Check(name, OK, "desired frequency", values)


def stamp_check(delays_ms: LatencyWindow, min_s: float, max_s: float, *, what: str) -> Check:
    """diagnostic_updater's ``TimeStampStatus`` over the window: the age of each stamp on arrival
    (the node's clock minus the header stamp) must lie in ``[min_s, max_s]`` (``max_s`` 0: no
    check). WARN, not ERROR, when out of bounds: everything is matched by stamp, so an offset clock
    costs nothing but says that a clock is wrong (or a bag is replayed without ``use_sim_time``)."""
    earliest, latest = (v * 1e-3 for v in delays_ms.extremes())
    values = {
        "Earliest timestamp delay (s)": f"{earliest:.3f}",
        "Latest timestamp delay (s)": f"{latest:.3f}",
        "Earliest acceptable timestamp delay (s)": f"{min_s:.3f}",
        "Latest acceptable timestamp delay (s)": f"{max_s:.3f}" if max_s else "none",
    }
    name = f"{what} stamps"
    if math.isnan(earliest):  # no input: the rate check says so
        return Check(name, OK, "no data in the window", values)
    if earliest < min_s:
        return Check(name, WARN, f"{what} stamps up to {-earliest:.3g} s ahead of the node's clock", values)
    if max_s and latest > max_s:
        return Check(name, WARN, f"{what} stamps up to {latest:.3g} s old on arrival (the node's clock; replaying "
                     "a bag? replay --clock with use_sim_time:=true, or --restamp)", values)
    return Check(name, OK, "timestamps are reasonable", values)


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
        level: 0 OK, 1 WARN, 2 ERROR: the worst of the node's own state and of ``checks``.
        message: one-line summary.
        values: key -> value (strings), in a stable order.
        checks: the input's rate and stamp checks (one status each in the DiagnosticArray).
    """

    level: int
    message: str
    values: dict[str, str]
    checks: tuple[Check, ...] = ()


@dataclass
class Health:
    """Thread-safe counters of the node, read by the diagnostics timer.

    Counters are totals since start; ``problems`` counts input problems by kind (for example
    ``"bad image"``, ``"imu stale"``) and ``last_error`` keeps the latest reason in words. Rates,
    percentiles and stamp ages cover the last ``window_s`` only (:meth:`configure`), so when the
    input stops the status goes stale (ERROR, as diagnostic_updater's FrequencyStatus) instead of
    showing the last figures forever.
    """

    backend: str = ""
    # "on", "off", or "off: <why>" when the far field is asked for and the backend has none
    far_field: str = "off"
    window_s: float = 5.0
    problem_window_s: float = 5.0
    clock: Callable[[], float] = time.monotonic
    min_rate_hz: float = 0.0
    max_rate_hz: float = 0.0
    rate_tolerance: float = 0.1
    min_stamp_age_s: float = -1.0
    max_stamp_age_s: float = 0.0
    max_latency_ms: float = 0.0  # 0 = no bound
    input_rate: RateMeter = field(init=False)
    stale_rate: RateMeter = field(init=False)  # outputs dropped for their latency
    busy_rate: RateMeter = field(init=False)  # sets replaced in the mailbox while the worker was busy
    set_rate: RateMeter = field(init=False)
    output_rate: RateMeter = field(init=False)
    latency_ms: LatencyWindow = field(init=False)
    stamp_age_ms: LatencyWindow = field(init=False)
    arrival_age_ms: LatencyWindow = field(init=False)  # node clock minus stamp when a left image arrives
    inference_ms: LatencyWindow = field(init=False)
    overhead_ms: LatencyWindow = field(init=False)
    imu_wait_ms: LatencyWindow = field(init=False)
    frames_in: int = 0
    sets: int = 0
    outputs: int = 0
    dropped_busy: int = 0
    dropped_sync: int = 0
    dropped_invalid: int = 0
    dropped_stale: int = 0
    problems: Counter[str] = field(default_factory=Counter)
    time_jumps: int = 0
    last_error: str = ""
    last_error_time: float = -math.inf
    imu_age_s: float | None = None
    coverage_pct: float | None = None  # the latest frame's (roadbev_core.selfcheck)
    coverage_ok: bool = True
    coverage_hint: str = ""
    input_hint: str = ""  # why nothing may arrive (the node looks at the graph: another transport)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self.input_rate = RateMeter(self.window_s, self.clock)
        self.set_rate = RateMeter(self.window_s, self.clock)
        self.output_rate = RateMeter(self.window_s, self.clock)
        self.stale_rate = RateMeter(self.window_s, self.clock)
        self.busy_rate = RateMeter(self.window_s, self.clock)
        windows = ("latency_ms", "stamp_age_ms", "arrival_age_ms", "inference_ms", "overhead_ms", "imu_wait_ms")
        for name in windows:
            setattr(self, name, LatencyWindow(window_s=self.window_s, clock=self.clock))

    def configure(self, config: Any) -> None:
        """Take the window and the bounds from a :class:`roadbev_core.config.tree.DiagnosticsConfig`."""
        with self._lock:
            self.window_s = config.window_s
            for meter in (self.input_rate, self.set_rate, self.output_rate, self.stale_rate, self.busy_rate):
                meter.window_s = config.window_s
            for window in (self.latency_ms, self.stamp_age_ms, self.arrival_age_ms, self.inference_ms,
                           self.overhead_ms, self.imu_wait_ms):
                window.window_s = config.window_s
            self.min_rate_hz, self.max_rate_hz = config.min_rate_hz, config.max_rate_hz
            self.rate_tolerance = config.rate_tolerance
            self.min_stamp_age_s, self.max_stamp_age_s = config.min_stamp_age_s, config.max_stamp_age_s
            self.max_latency_ms = config.max_latency_s * 1e3

    def frame_in(self, stamp_age_s: float | None = None) -> None:
        """A left image arrived; ``stamp_age_s``: the node's clock minus its stamp."""
        with self._lock:
            self.frames_in += 1
            self.input_rate.tick()
            if stamp_age_s is not None:
                self.arrival_age_ms.add(stamp_age_s * 1e3)

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
            stamp_age_ms: outputs published minus the image stamp, by the node's clock.
            inference_ms: the backend's ``estimate``.
            overhead_ms: the node's own work (conversions, preview, publishing).
            imu_wait_ms: time spent waiting for the IMU sample at or after the image stamp (before
                the estimate) and the odometry one (before the map stage).
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
        ``stale`` (outputs later than the latency bound, not published), ``invalid`` (refused input)."""
        with self._lock:
            if kind == "busy":
                self.dropped_busy += count
                for _ in range(count):
                    self.busy_rate.tick()
            elif kind == "stale":
                self.dropped_stale += count
                self.stale_rate.tick()
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
        """The figures now, with a level: the worst of the input checks (rate: ERROR when stale,
        WARN outside the expected window or before any input; stamps: WARN outside their bounds)
        and the node's own state (WARN while a problem was reported in the last
        ``problem_window_s``, while input arrives but nothing is published, or on low coverage)."""
        with self._lock:
            now = self.clock()
            recent_problem = now - self.last_error_time < self.problem_window_s
            out_rate = self.output_rate.rate()
            in_rate = self.input_rate.rate()
            last_in = self.input_rate.last()
            hint = f" ({self.input_hint})" if self.input_hint else ""
            rate = frequency_check(self.input_rate, self.min_rate_hz, self.max_rate_hz, self.rate_tolerance,
                                   what="left image", never="waiting for input" + hint,
                                   silent_s=None if last_in is None else now - last_in)
            if rate.level == ERROR:
                rate = Check(rate.name, rate.level, rate.message + hint, rate.values)
            stamps = stamp_check(self.arrival_age_ms, self.min_stamp_age_s, self.max_stamp_age_s, what="left image")
            # a stale stream shows no figures: its last outputs were recorded a processing time
            # after its last input, so their windows would still hold them for that long
            stale = rate.level == ERROR

            def pct(window: LatencyWindow, q: float) -> float:
                return math.nan if stale else window.percentile(q)

            def mean(window: LatencyWindow) -> float:
                return math.nan if stale else window.mean()

            values = {
                "backend": self.backend,
                "far_field": self.far_field,
                "input_rate_hz": f"{in_rate:.2f}",
                "set_rate_hz": f"{self.set_rate.rate():.2f}",
                "output_rate_hz": f"{out_rate:.2f}",
                "latency_p50_ms": f"{pct(self.latency_ms, 50):.1f}",
                "latency_p95_ms": f"{pct(self.latency_ms, 95):.1f}",
                "stamp_age_p50_ms": f"{pct(self.stamp_age_ms, 50):.1f}",
                "inference_mean_ms": f"{mean(self.inference_ms):.1f}",
                "inference_p50_ms": f"{pct(self.inference_ms, 50):.1f}",
                "overhead_mean_ms": f"{mean(self.overhead_ms):.2f}",
                "overhead_p95_ms": f"{pct(self.overhead_ms, 95):.2f}",
                "imu_wait_mean_ms": f"{mean(self.imu_wait_ms):.2f}",
                "window_s": f"{self.window_s:g}",
                "last_input_age_s": "never" if last_in is None else f"{now - last_in:.1f}",
                "frames_in": str(self.frames_in),
                "sets": str(self.sets),
                "outputs": str(self.outputs),
                "dropped_busy": str(self.dropped_busy),
                "dropped_sync": str(self.dropped_sync),
                "dropped_invalid": str(self.dropped_invalid),
                "dropped_stale": str(self.dropped_stale),
                "max_latency_ms": f"{self.max_latency_ms:g}",
                "imu_age_s": "none" if self.imu_age_s is None else f"{self.imu_age_s:.3f}",
                "time_jumps": str(self.time_jumps),
                "last_error": self.last_error,
                "coverage_pct": "none" if self.coverage_pct is None else f"{self.coverage_pct:.1f}",
                "self_check": self.coverage_hint,
            }
            low_coverage = not self.coverage_ok
            for kind, count in sorted(self.problems.items()):
                values[f"problem.{kind}"] = str(count)
            stale_now = self.stale_rate.in_window()
            busy_now, answered_now = self.busy_rate.in_window(), self.output_rate.in_window()
            latency_p95 = pct(self.latency_ms, 95)
        # the node's own state, most telling first; the worst level wins, its first message is shown
        states: list[tuple[int, str]] = [(rate.level, rate.message)] if rate.level == ERROR else []
        if stale_now:
            states.append((ERROR, f"{stale_now} output(s) in the last {self.window_s:g} s later than max_latency_s "
                                  f"({self.max_latency_ms:g} ms): not published"))
        elif self.max_latency_ms and latency_p95 > self.max_latency_ms:
            states.append((WARN, f"latency p95 {latency_p95:.0f} ms over max_latency_s ({self.max_latency_ms:g} ms)"))
        if busy_now > answered_now:
            # more sets replaced unprocessed than answered: the input outruns the backend (a
            # flood, or a camera faster than the backend); outputs stay fresh, most frames go
            states.append((WARN, f"{busy_now} of {busy_now + answered_now} image sets in the last "
                                 f"{self.window_s:g} s dropped while the backend was busy "
                                 f"(input {in_rate:.1f} Hz, output {out_rate:.1f} Hz)"))
        if recent_problem:
            states.append((WARN, self.last_error))
        if in_rate > 0 and self.output_rate.in_window() == 0:
            states.append((WARN, "input arrives but nothing is published"))
        if low_coverage:
            states.append((WARN, self.coverage_hint or "low coverage"))
        states += [(c.level, c.message) for c in (rate, stamps) if c.level not in (OK, ERROR)]
        level = max((lv for lv, _ in states), default=OK)
        message = next((m for lv, m in states if lv == level), "ok")
        return HealthSnapshot(level, message, values, (rate, stamps))


class ProblemLog:
    """Reports an input or processing problem: counted by kind in ``health`` and logged through
    ``warn``, at most once per ``period_s`` per kind (the next report says how many were held back).

    Args:
        health: the figures the problem is counted in.
        warn: writes one warning line (the node's logger).
        period_s: the log throttle per kind (``diagnostics.log_throttle_s``).
        clock: seconds, monotonic (injectable for tests).
    """

    def __init__(self, health: Health, warn: Callable[[str], object], period_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._health = health
        self._warn = warn
        self.throttle = ThrottledLog(period_s, clock)

    def __call__(self, kind: str, reason: str) -> None:
        self._health.problem(kind, reason)
        if self.throttle.allow(kind):
            suppressed = self.throttle.suppressed.pop(kind, 0)
            more = f" ({suppressed} more since the last report)" if suppressed else ""
            self._warn(f"{kind}: {reason}{more}")


def late_output(stamp_ns: int, late_s: float, bound_s: float) -> str | None:
    """Why the output of the frame at ``stamp_ns``, ready ``late_s`` after its input arrived, is
    not published (a preview this late points at road already driven over); None when it is in
    time or there is no bound (``bound_s``: ``diagnostics.max_latency_s``, 0 = none)."""
    if not (bound_s and late_s > bound_s):
        return None
    return (f"the frame at {stamp_ns * 1e-9:.3f} s was ready {late_s * 1e3:.0f} ms after its input arrived "
            f"(max_latency_s {bound_s:g}): not published")


class ClockWatch:
    """Whether the node's clock moves (a replay's ``/clock`` stops when the bag ends: the
    diagnostics after it carry the same stamp, and say so).

    Args:
        steady: seconds, monotonic (injectable for tests).
    """

    def __init__(self, steady: Callable[[], float] = time.monotonic) -> None:
        self._steady = steady
        self._seen: tuple[int, float] | None = None  # the clock's value (ns) and when it last changed

    def state(self, now_ns: int) -> str:
        """``running``, or for how long the clock, now at ``now_ns``, has stood still."""
        steady = self._steady()
        if self._seen is None or now_ns != self._seen[0]:
            self._seen = (now_ns, steady)
            return "running"
        return f"stopped for {steady - self._seen[1]:.0f} s (use_sim_time and no /clock)"


@dataclass
class OutputTally:
    """What the diagnostics report of the fused map and the preview of the frames published."""

    fused: int = 0  # frames fused into the map
    preview_reference: str = ""  # reference (and contact-plane source) of the newest preview
    paced: int = 0  # frames the pace backend answered (roadbev_core.pacing)

    def note(self, output: Any) -> None:
        """Take one :class:`roadbev_core.pipeline.PipelineOutput`."""
        if output.fusion is not None:
            self.fused += 1
        if output.paced:
            self.paced += 1
        if output.preview is not None:
            plane = output.preview.contact_plane
            self.preview_reference = output.preview.reference + (f" ({plane.source})" if plane is not None else "")


def node_values(*, queued_set: bool, queued_left_images: int, map_state: str, tally: OutputTally,
                motion_age_s: float | None, clock: str, camera_mount: str, pace: str = "off") -> dict[str, str]:
    """The node's own figures, appended to :meth:`Health.snapshot`'s values (in this order).

    Args:
        queued_set: a synchronised set waits for the worker.
        queued_left_images: left images waiting in the synchroniser.
        map_state: the fused map in a few words (fusing, or why not).
        tally: the outputs so far.
        motion_age_s: seconds since the newest odometry or speed sample (None: never).
        clock: :meth:`ClockWatch.state`.
        camera_mount: where the camera's mount comes from (:meth:`roadbev_ros.camera_mount.CameraMount.state`).
        pace: who answers the frames and why (:meth:`roadbev_core.pacing.PaceState.describe`, or
            "off" where there is no pace backend).
    """
    return {
        "queued_sets": "1" if queued_set else "0",
        "queued_left_images": str(queued_left_images),
        "map": map_state,
        "map_frames_fused": str(tally.fused),
        "motion_age_s": "never" if motion_age_s is None else f"{motion_age_s:.2f}",
        "preview_reference": tally.preview_reference or "none yet",
        "clock": clock,
        "camera_mount": camera_mount,
        "pace": pace,
        "paced_frames": str(tally.paced),
    }


def far_field_state(estimated: bool, why_not: str) -> str:
    """The ``far_field`` diagnostic value: "on" where the far field is estimated, "off: <why>"
    where it is asked for and not estimated (``why_not``: the pipeline's ``far_field_off``), else
    "off"."""
    if estimated:
        return "on"
    return f"off: {why_not}" if why_not else "off"


class NodeDiagnostics:
    """What the RoadBEV node reports on ``/diagnostics``: its :class:`Health` figures, the problems
    (:class:`ProblemLog`), the outputs' :class:`OutputTally` and whether its clock moves.

    Args:
        backend: the backend's name.
        config: a :class:`roadbev_core.config.tree.DiagnosticsConfig` (as :meth:`Health.configure`).
        warn: writes one warning line (the node's logger).
        steady: seconds, monotonic (injectable for tests).
        far_field: whether the far field is estimated: "on", "off", or "off: <why>" when it is
            asked for and the backend has none (:func:`far_field_state`).
    """

    def __init__(self, backend: str, config: Any, warn: Callable[[str], object],
                 steady: Callable[[], float] = time.monotonic, *, far_field: str = "off") -> None:
        self.health = Health(backend=backend, far_field=far_field)
        self.health.configure(config)
        self.report = ProblemLog(self.health, warn, config.log_throttle_s, steady)
        self.tally = OutputTally()
        self._clock = ClockWatch(steady)

    def configure(self, backend: str, config: Any, *, far_field: str = "off") -> None:
        """A new backend or new settings (a parameter change)."""
        self.health.backend = backend
        self.health.far_field = far_field
        self.report.throttle.period_s = config.log_throttle_s
        self.health.configure(config)

    def late(self, stamp_ns: int, late_s: float, bound_s: float) -> bool:
        """Whether the output of the frame at ``stamp_ns`` is too late to publish
        (:func:`late_output`); such a frame is counted (``dropped_stale``) and reported."""
        reason = late_output(stamp_ns, late_s, bound_s)
        if reason is not None:
            self.health.drop("stale")
            self.report("stale output", reason)
        return reason is not None

    def frame_failed(self, exc: Exception, *, earlier_pass: bool) -> None:
        """A frame the worker could not finish: refused input (counted invalid, reported under
        :func:`problem_kind`), quietly dropped (``sync``) when the clock jumped back meanwhile (the
        IMU history was reset under it), or a backend failure (counted invalid, reported)."""
        if isinstance(exc, RoadbevError) and earlier_pass:
            self.health.drop("sync")
            return
        self.health.drop("invalid")
        if isinstance(exc, RoadbevError):
            self.report(problem_kind(exc), str(exc))
        else:
            self.report("backend error", f"{type(exc).__name__}: {exc}")

    def snapshot(self, *, input_hint: str, queued_set: bool, queued_left_images: int, map_state: str,
                 motion_age_s: float | None, camera_mount: str, now_ns: int, pace: str = "off") -> HealthSnapshot:
        """The figures now, the node's own (:func:`node_values`) after the health's; ``input_hint``:
        why no input may arrive (:func:`transport_hint`), ``now_ns``: the node's clock."""
        self.health.input_hint = input_hint
        snapshot = self.health.snapshot()
        snapshot.values.update(node_values(queued_set=queued_set, queued_left_images=queued_left_images,
                                           map_state=map_state, tally=self.tally, motion_age_s=motion_age_s,
                                           clock=self._clock.state(now_ns), camera_mount=camera_mount,
                                           pace=pace))
        return snapshot


def to_diagnostic_array(snapshot: HealthSnapshot, stamp: Any, name: str = "roadbev: pipeline",
                        hardware_id: str = "roadbev") -> Any:
    """A ``diagnostic_msgs/DiagnosticArray`` built from ``snapshot``: the pipeline's status, then
    one per input check.

    Args:
        snapshot: the figures.
        stamp: a ``builtin_interfaces/Time`` for the header.
    """
    # lazy: the figures and rules here run without ROS (the lab, the tests); only the message needs it
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    def status(name: str, level: int, message: str, values: dict[str, str]) -> Any:
        out = DiagnosticStatus()
        out.level = bytes([level])
        out.name = name
        out.message = message[:500]
        out.hardware_id = hardware_id
        out.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        return out

    array = DiagnosticArray()
    array.header.stamp = stamp
    # the pipeline first (the overall level, every figure), then one status per input check, as
    # diagnostic_updater's tasks: "roadbev: left image rate", "roadbev: left image stamps"
    array.status = [status(name, snapshot.level, snapshot.message, snapshot.values)] + [
        status(f"{name.split(':')[0]}: {c.name}", c.level, c.message, c.values) for c in snapshot.checks
    ]
    return array


def level_name(level: int) -> str:
    """``OK``, ``WARN`` or ``ERROR``."""
    return _LEVEL_NAMES.get(level, str(level))


def problem_kind(exc: Exception) -> str:
    """The diagnostics kind under which a refused frame is counted and logged."""

    kinds = ((ImuStale, "imu stale"), (ImplausibleFrame, "implausible input"), (FrameError, "bad frame"),
             (PreviewError, "preview"))
    return next((kind for cls, kind in kinds if isinstance(exc, cls)), "bad input")


COMPRESSED_SUFFIX = "/compressed"  # image_transport's topic of the compressed stream


def other_transport(topic: str) -> str:
    """The same image stream's topic on the other transport: ``T`` <-> ``T/compressed``."""
    return topic[: -len(COMPRESSED_SUFFIX)] if topic.endswith(COMPRESSED_SUFFIX) else topic + COMPRESSED_SUFFIX


def transport_hint(node: Any, topic: str) -> str:
    """Why nothing may arrive on ``topic``: nobody publishes it but its other transport has a
    publisher (the graph of ``node``); "" otherwise."""
    if node.count_publishers(topic) > 0:
        return ""
    other = other_transport(topic)
    if node.count_publishers(other) == 0:
        return f"nothing publishes {topic}"
    transport = "raw" if topic.endswith(COMPRESSED_SUFFIX) else "compressed"
    return f"nothing publishes {topic}, but {other} has a publisher: set image_transport:={transport}"
