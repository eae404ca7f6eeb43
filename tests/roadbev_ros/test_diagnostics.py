"""Health figures: rates, percentiles, throttling, levels, and the DiagnosticArray."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from roadbev_core.attitude import ImuStale
from roadbev_core.config import DiagnosticsConfig
from roadbev_ros.diagnostics import (
    ERROR,
    OK,
    WARN,
    ClockWatch,
    Health,
    LatencyWindow,
    NodeDiagnostics,
    OutputTally,
    ProblemLog,
    RateMeter,
    ThrottledLog,
    late_output,
    node_values,
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


def _camera(health: Health, clock: FakeClock, sets: int, period_s: float, answered_every: int) -> None:
    """``sets`` image sets ``period_s`` apart, one in ``answered_every`` answered, the rest dropped busy."""
    for k in range(sets):
        health.frame_in()
        health.set_in()
        if k % answered_every == 0:
            health.output(50.0, 60.0, 40.0, 2.0, 1.0)
        else:
            health.drop("busy")
        clock.t += period_s


def test_an_input_flood_warns_while_most_sets_are_dropped_unprocessed() -> None:
    clock = FakeClock()
    health = Health(backend="bm", clock=clock, window_s=2.0)
    _camera(health, clock, 100, 0.02, 10)  # 50 Hz of image sets for 2 s; the backend answers one in ten
    snap = health.snapshot()
    assert snap.level == WARN
    assert snap.message.startswith("90 of 100 image sets in the last 2 s dropped while the backend was busy")
    clock.t += 2.5  # the flood is over: the figures stay, the warning goes
    health.frame_in()
    health.set_in()
    health.output(50.0, 60.0, 40.0, 2.0, 1.0)
    snap = health.snapshot()
    assert "dropped while the backend was busy" not in snap.message and snap.values["dropped_busy"] == "90"


def test_a_camera_the_backend_keeps_up_with_does_not_warn() -> None:
    clock = FakeClock()
    health = Health(backend="bm", clock=clock, window_s=2.0)
    _camera(health, clock, 20, 0.1, 2)  # 10 Hz, every second set replaced: half answered is not a flood
    assert health.snapshot().level == OK


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


def test_problems_are_counted_and_logged_once_per_period_with_the_count_held_back() -> None:
    clock = FakeClock()
    health = Health(clock=clock)
    lines: list[str] = []
    report = ProblemLog(health, lines.append, period_s=5.0, clock=clock)
    for _ in range(3):
        report("bad imu", "non-unit quaternion")
    report("bad tf", "no frame")
    clock.t += 5.0
    report("bad imu", "stale")
    assert lines == ["bad imu: non-unit quaternion", "bad tf: no frame",
                     "bad imu: stale (2 more since the last report)"]
    assert health.problems == {"bad imu": 4, "bad tf": 1} and health.last_error == "bad imu: stale"


def test_an_output_later_than_max_latency_is_named_and_without_a_bound_never() -> None:
    stamp_ns = 1_700_000_000_250_000_000
    assert late_output(stamp_ns, 0.1234, 0.1) == ("the frame at 1700000000.250 s was ready 123 ms after its input "
                                                  "arrived (max_latency_s 0.1): not published")
    assert late_output(stamp_ns, 0.1, 0.1) is None  # at the bound: in time
    assert late_output(stamp_ns, 9.0, 0.0) is None  # 0: no bound


def test_the_clock_watch_says_how_long_the_node_clock_stood_still() -> None:
    steady = FakeClock()
    watch = ClockWatch(steady)
    assert watch.state(10) == "running"
    steady.t += 3.0
    assert watch.state(20) == "running"
    steady.t += 7.4
    assert watch.state(20) == "stopped for 7 s (use_sim_time and no /clock)"
    assert watch.state(30) == "running"


def output(fused: bool, reference: str | None, plane_source: str | None = None, *, paced: bool = False
           ) -> SimpleNamespace:
    plane = None if plane_source is None else SimpleNamespace(source=plane_source)
    preview = None if reference is None else SimpleNamespace(reference=reference, contact_plane=plane)
    return SimpleNamespace(fusion=object() if fused else None, preview=preview, paced=paced)


def test_the_tally_and_the_node_values_in_their_order() -> None:
    tally = OutputTally()
    values = node_values(queued_set=False, queued_left_images=0, map_state="off (map.enabled false)", tally=tally,
                         motion_age_s=None, clock="running", camera_mount="vehicle.camera_position_m [1.6, 0.0, 1.1]")
    assert values == {"queued_sets": "0", "queued_left_images": "0", "map": "off (map.enabled false)",
                      "map_frames_fused": "0", "motion_age_s": "never", "preview_reference": "none yet",
                      "clock": "running", "camera_mount": "vehicle.camera_position_m [1.6, 0.0, 1.1]",
                      "pace": "off", "paced_frames": "0"}
    tally.note(output(True, "contact plane", "map"))
    tally.note(output(False, "camera"))
    tally.note(output(True, None))
    assert (tally.fused, tally.preview_reference) == (2, "camera")
    tally.note(output(True, "contact plane", "map", paced=True))
    values = node_values(queued_set=True, queued_left_images=3, map_state="fusing", tally=tally, motion_age_s=0.256,
                         clock="running", camera_mount="/tf base_link -> left at [1.6, 0.0, 1.1] m",
                         pace="bm answers")
    assert list(values.values()) == ["1", "3", "fusing", "3", "0.26", "contact plane (map)", "running",
                                     "/tf base_link -> left at [1.6, 0.0, 1.1] m", "bm answers", "1"]


def test_node_diagnostics_count_late_and_failed_frames_and_append_the_node_values() -> None:
    lines: list[str] = []
    status = NodeDiagnostics("bm", DiagnosticsConfig(), lines.append)
    assert not status.late(1_000_000_000, 0.05, 0.1)
    assert status.late(1_000_000_000, 0.25, 0.1)
    assert status.health.dropped_stale == 1 and status.health.problems["stale output"] == 1
    status.frame_failed(ImuStale("no IMU within 0.1 s"), earlier_pass=False)
    status.frame_failed(ImuStale("no IMU within 0.1 s"), earlier_pass=True)  # the clock jumped back meanwhile
    status.frame_failed(RuntimeError("the accelerator went away"), earlier_pass=True)
    h = status.health
    assert (h.dropped_invalid, h.dropped_sync) == (2, 1)
    assert h.problems["imu stale"] == 1 and h.last_error == "backend error: RuntimeError: the accelerator went away"
    assert len(lines) == 3  # one line per kind
    snapshot = status.snapshot(input_hint="nothing publishes /left", queued_set=False, queued_left_images=2,
                               map_state="fusing", motion_age_s=None, camera_mount="", now_ns=5)
    assert list(snapshot.values)[-10:] == ["queued_sets", "queued_left_images", "map", "map_frames_fused",
                                           "motion_age_s", "preview_reference", "clock", "camera_mount", "pace",
                                           "paced_frames"]
    assert snapshot.values["queued_left_images"] == "2" and snapshot.values["clock"] == "running"
    assert "nothing publishes /left" in snapshot.checks[0].message
    status.configure("sgbm", DiagnosticsConfig(log_throttle_s=0.0, window_s=2.0))
    assert status.health.backend == "sgbm" and status.health.window_s == 2.0
    status.frame_failed(RuntimeError("again"), earlier_pass=False)
    assert len(lines) == 4  # no throttle now
