"""Health figures: rates, percentiles, throttling, levels, and the DiagnosticArray."""

from __future__ import annotations

import math

import pytest

from roadbev_ros.diagnostics import (
    ERROR,
    OK,
    WARN,
    Health,
    LatencyWindow,
    RateMeter,
    ThrottledLog,
    other_transport,
    to_diagnostic_array,
    transport_hint,
)


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
    assert snap.level == WARN and snap.message == "waiting for input"
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
    clock.t += 5.5  # the problem is old: back to OK, the count and last error stay
    health.frame_in()
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
    health.frame_in()
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
    assert status.name == "roadbev: pipeline" and status.level == bytes([WARN])
    assert status.message == "waiting for input"
    assert {kv.key: kv.value for kv in status.values}["backend"] == "bev_sweep"
    # one status per input check after the pipeline's, named as diagnostic_updater tasks
    assert [s.name for s in array.status[1:]] == ["roadbev: left image rate", "roadbev: left image stamps"]
    rate = {kv.key: kv.value for kv in array.status[1].values}
    assert rate["Events since startup"] == "0" and array.status[1].level == bytes([WARN])


def test_latency_window_forgets_old_samples() -> None:
    clock = FakeClock()
    window = LatencyWindow(size=100, window_s=5.0, clock=clock)
    window.add(10.0)
    clock.t += 3.0
    window.add(20.0)
    assert window.percentile(50) == pytest.approx(15.0) and window.extremes() == (10.0, 20.0)
    clock.t += 3.0  # the first sample is 6 s old
    assert window.percentile(50) == pytest.approx(20.0) and len(window) == 1
    clock.t += 3.0
    assert math.isnan(window.percentile(95)) and math.isnan(window.mean()) and len(window) == 0


def diag_config(**changes: float) -> object:
    from roadbev_core.config import RoadbevConfig

    return RoadbevConfig.from_params(changes).diagnostics


def feed(health: Health, clock: FakeClock, seconds: float, hz: float, age_s: float = 0.05) -> None:
    for _ in range(round(seconds * hz)):
        health.frame_in(age_s)
        health.set_in()
        health.output(30.0, 60.0, 20.0, 2.0)
        clock.t += 1.0 / hz


def test_the_status_goes_stale_when_input_stops_and_recovers_when_it_resumes() -> None:
    clock = FakeClock()
    health = Health(backend="bm", clock=clock)
    health.configure(diag_config())  # the node's defaults: 5 s window, 1..100 Hz, stamps -1..5 s
    feed(health, clock, 3.0, 10.0)
    snap = health.snapshot()
    assert snap.level == OK, snap.message
    assert float(snap.values["input_rate_hz"]) == pytest.approx(10.0, rel=0.1)
    assert float(snap.values["latency_p95_ms"]) == pytest.approx(30.0)
    clock.t += 6.0  # the camera stops: after the window nothing recent is left
    snap = health.snapshot()
    assert snap.level == ERROR and snap.message.startswith("stale: no left image for 6.1 s"), snap.message
    assert snap.values["input_rate_hz"] == "0.00" and snap.values["latency_p50_ms"] == "nan"
    assert snap.values["last_input_age_s"] == "6.1" and snap.values["frames_in"] == "30"
    assert snap.checks[0].level == ERROR and snap.checks[0].values["Events in window"] == "0"
    feed(health, clock, 1.0, 10.0)  # it comes back
    snap = health.snapshot()
    assert snap.level == OK and snap.message == "ok", snap.message
    assert float(snap.values["latency_p50_ms"]) == pytest.approx(30.0)


def test_rate_outside_the_expected_window_warns() -> None:
    clock = FakeClock()
    health = Health(clock=clock)
    health.configure(diag_config(**{"diagnostics.min_rate_hz": 5.0, "diagnostics.max_rate_hz": 20.0}))
    feed(health, clock, 3.0, 2.0)
    assert health.snapshot().level == OK  # the window is not full yet: no verdict on a low rate
    feed(health, clock, 3.0, 2.0)
    snap = health.snapshot()
    assert snap.level == WARN and "rate too low" in snap.message and "at least 5 Hz" in snap.message
    assert snap.checks[0].values["Minimum acceptable frequency (Hz)"] == "4.50"
    feed(health, clock, 5.0, 40.0)
    snap = health.snapshot()
    assert snap.level == WARN and "rate too high" in snap.message
    feed(health, clock, 5.0, 21.0)  # inside the tolerance (10 %)
    assert health.snapshot().level == OK


@pytest.mark.parametrize(("age_s", "words"), [(30.0, "s old on arrival"), (-3.0, "ahead of the node's clock")])
def test_stamp_ages_outside_their_bounds_warn(age_s: float, words: str) -> None:
    clock = FakeClock()
    health = Health(clock=clock)
    health.configure(diag_config())
    feed(health, clock, 2.0, 10.0, age_s=age_s)
    snap = health.snapshot()
    assert snap.level == WARN and words in snap.message, snap.message
    assert snap.checks[1].level == WARN
    assert float(snap.checks[1].values["Latest timestamp delay (s)"]) == pytest.approx(age_s)
    health.configure(diag_config(**{"diagnostics.max_stamp_age_s": 0.0, "diagnostics.min_stamp_age_s": -3600.0}))
    assert health.snapshot().level == OK  # both checks off


class Graph:
    """count_publishers of a fake ROS graph."""

    def __init__(self, *topics: str) -> None:
        self.topics = topics

    def count_publishers(self, topic: str) -> int:
        return self.topics.count(topic)


def test_the_other_transport_on_the_graph_is_named() -> None:
    assert other_transport("/cam/image_rect") == "/cam/image_rect/compressed"
    assert other_transport("/cam/image_rect/compressed") == "/cam/image_rect"
    raw, compressed = "/cam/image_rect", "/cam/image_rect/compressed"
    assert transport_hint(Graph(raw), raw) == ""
    assert "set image_transport:=compressed" in transport_hint(Graph(compressed), raw)
    assert "set image_transport:=raw" in transport_hint(Graph(raw), compressed)
    assert transport_hint(Graph(), raw) == f"nothing publishes {raw}"
    clock = FakeClock()
    health = Health(clock=clock)
    health.input_hint = transport_hint(Graph(compressed), raw)
    assert "image_transport:=compressed" in health.snapshot().message  # before any input
    feed(health, clock, 1.0, 10.0)
    clock.t += 10.0
    snap = health.snapshot()
    assert snap.level == ERROR and "image_transport:=compressed" in snap.message  # and once it stopped


def test_a_stale_stream_shows_no_figures_even_while_its_last_outputs_are_inside_the_window() -> None:
    clock = FakeClock()
    health = Health(backend="bm", clock=clock)
    health.configure(diag_config(**{"diagnostics.window_s": 1.0, "diagnostics.min_rate_hz": 0.0}))
    for _ in range(5):
        health.frame_in(0.05)
        health.set_in()
        clock.t += 0.05  # each output is recorded a processing time after its input
        health.output(30.0, 60.0, 20.0, 2.0)
        clock.t += 0.05
    clock.t += 1.0 - 0.06  # the last input is a window old, the last output not yet
    snap = health.snapshot()
    assert snap.level == ERROR and snap.message.startswith("stale"), snap.message
    for key in ("latency_p50_ms", "latency_p95_ms", "inference_mean_ms", "overhead_p95_ms"):
        assert snap.values[key] == "nan", (key, snap.values[key])
