"""Tests of the online evaluation's pure parts (the node runs in tests/roadbev_ros/test_e2e.py)."""

from __future__ import annotations

import pytest

from roadbev_lab.evaluation.online import latencies_on_arrival, node_command


def test_a_node_that_keeps_up_has_its_end_to_end_latencies_on_arrival() -> None:
    sent = {k: 0.1 * k for k in range(5)}
    received = {k: 0.1 * k + 0.06 for k in range(5)}
    assert latencies_on_arrival(sent, received) == pytest.approx([60.0] * 5)


def test_the_wait_for_the_previous_answer_is_left_out_and_dropped_frames_are_skipped() -> None:
    # 10 Hz camera, 130 ms a frame: frame 1 waits from 100 to 130 ms; frame 2 was replaced (no
    # answer); frame 3 arrives at 300 ms while the node is free since 260 ms
    sent = {0: 0.0, 1: 0.1, 2: 0.2, 3: 0.3}
    received = {0: 0.13, 1: 0.26, 3: 0.43}
    end_to_end = [1e3 * (received[s] - sent[s]) for s in sorted(received)]
    assert end_to_end == pytest.approx([130.0, 160.0, 130.0])
    assert latencies_on_arrival(sent, received) == pytest.approx([130.0, 130.0, 130.0])


def test_an_answer_lost_on_the_way_leaves_the_next_frame_its_whole_latency() -> None:
    """Frame 1's answer is lost, and frame 2 waited for the node to finish it: that wait is not
    known, so the latency is not made smaller (overstated, never understated)."""
    sent = {0: 0.0, 1: 0.1, 2: 0.2}
    received = {0: 0.15, 2: 0.45}
    assert latencies_on_arrival(sent, received) == pytest.approx([150.0, 250.0])
    assert latencies_on_arrival({}, {}) == []


def test_the_node_command_passes_an_empty_string_as_one_and_a_bool_as_yaml() -> None:
    command = node_command("bm", {"x_max": 7.08}, None,
                           {"pace_backend": "", "far_field.enabled": True, "imu_wait_s": 1.0})
    args = command[command.index("--ros-args") + 1:]
    assert args == ["-p", "x_max:=7.08", "-p", "pace_backend:=''", "-p", "far_field.enabled:=true",
                    "-p", "imu_wait_s:=1.0", "-p", "backend:=bm"]
