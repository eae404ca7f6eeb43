"""Health figures: rates, percentiles, throttling, levels, and the DiagnosticArray."""

from __future__ import annotations

import math

import pytest

from roadbev_ros.diagnostics import OK, WARN, Health, LatencyWindow, RateMeter, ThrottledLog, to_diagnostic_array


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_rate_meter_counts_events_per_second_in_the_window() -> None:
    clock = FakeClock()
    meter = RateMeter(window_s=2.0, clock=clock)
    assert meter.rate() == 0.0
    for _ in range(11):  # 10 Hz for one second
        meter.tick()
        clock.t += 0.1
    assert meter.rate() == pytest.approx(10.0, rel=0.1)
    clock.t += 5.0  # silence: the window empties
    assert meter.rate() == 0.0
    assert meter.total == 11


def test_latency_window_percentiles_and_bound() -> None:
    window = LatencyWindow(size=100)
    assert math.isnan(window.percentile(50))
    for v in range(1, 201):  # only the last 100 (101..200) are kept
        window.add(float(v))
    window.add(float("nan"))  # ignored
    assert len(window) == 100
    assert window.percentile(0) == 101 and window.percentile(100) == 200
    assert window.percentile(50) == pytest.approx(150.5)
    assert window.mean() == pytest.approx(150.5)


def test_throttled_log_lets_one_through_per_period_and_counts_the_rest() -> None:
    clock = FakeClock()
    gate = ThrottledLog(period_s=5.0, clock=clock)
    assert gate.allow("imu")
    assert not gate.allow("imu") and not gate.allow("imu")
    assert gate.allow("image")  # another kind is independent
    assert gate.suppressed["imu"] == 2
    clock.t += 5.0
    assert gate.allow("imu")


def test_health_levels_and_values() -> None:
    clock = FakeClock()
    health = Health(backend="bm", clock=clock)
    snap = health.snapshot()
    assert snap.level == OK and snap.message == "waiting for input"
    health.frame_in()
    health.set_in()
    health.output(30.0, 40.0, 20.0, 2.0, 1.0)
    health.drop("busy")
    health.drop("sync", 2)
    health.drop("invalid")
    snap = health.snapshot()
    assert snap.level == OK and snap.message == "ok"
    assert snap.values["dropped_busy"] == "1" and snap.values["dropped_sync"] == "2"
    assert snap.values["dropped_invalid"] == "1" and snap.values["backend"] == "bm"
    assert float(snap.values["latency_p95_ms"]) == pytest.approx(30.0)
    health.problem("imu stale", "IMU gap of 0.3 s")
    snap = health.snapshot()
    assert snap.level == WARN and "IMU gap" in snap.message
    assert snap.values["problem.imu stale"] == "1" and "IMU gap" in snap.values["last_error"]
    clock.t += 10.0  # the problem is old: back to OK, the count and last error stay
    snap = health.snapshot()
    assert snap.level == OK and snap.values["problem.imu stale"] == "1"


def test_input_without_output_warns() -> None:
    clock = FakeClock()
    health = Health(clock=clock)
    for _ in range(5):
        health.frame_in()
        clock.t += 0.1
    assert health.snapshot().level == WARN


def test_zero_coverage_warns_with_the_self_check_hint() -> None:
    import numpy as np

    from roadbev_core.config import GridSpec, StereoCamera
    from roadbev_core.frame import Estimate, Frame
    from roadbev_core.geometry import Attitude
    from roadbev_core.selfcheck import self_check

    grid = GridSpec()
    camera = StereoCamera.rsrd_half().scaled(0.25)
    flat = np.full((camera.height, camera.width), 120, np.uint8)
    empty = np.full(grid.shape, np.nan, np.float32)
    check = self_check(Estimate(empty, empty.copy()), Frame(flat, flat.copy(), camera, Attitude(0.0, 0.3)), grid)
    health = Health(backend="bev_sweep", clock=FakeClock())
    health.output(30.0, 40.0, 20.0, 2.0)
    health.coverage(check.coverage_pct, check.ok, check.message)
    snap = health.snapshot()
    assert snap.level == WARN and "no texture" in snap.message
    assert snap.values["coverage_pct"] == "0.0" and "coverage 0.0 % (low)" in snap.values["self_check"]
    health.coverage(85.0, True, "coverage 85.0 %")
    assert health.snapshot().level == OK


def test_diagnostic_array_message() -> None:
    from builtin_interfaces.msg import Time

    health = Health(backend="bev_sweep")
    array = to_diagnostic_array(health.snapshot(), Time(sec=5))
    status = array.status[0]
    assert array.header.stamp.sec == 5
    assert status.name == "roadbev: pipeline" and status.level == bytes([OK])
    assert {kv.key: kv.value for kv in status.values}["backend"] == "bev_sweep"
