"""Recorder: topics appear late, QoS follows the publishers, the file is complete after close."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from msg_bridge import bag
from roadbev_ros.record import Recorder, RecordError

from ._ros_harness import wait_for


def test_records_best_effort_and_reliable_publishers_that_appear_later(ros: Any, tmp_path: Path) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from std_msgs.msg import String

    node = ros.create_node("record_test")
    pub_node = ros.create_node("record_test_pub")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    running = True

    def spin() -> None:
        while running:
            executor.spin_once(timeout_sec=0.02)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    seen: list[str] = []
    out = tmp_path / "out.mcap"
    try:
        recorder = Recorder(node, out, ["/fast", "reliable", "/never"], listener=lambda t, d: seen.append(t))
        fast = pub_node.create_publisher(String, "/fast", qos_profile_sensor_data)  # best effort
        reliable = pub_node.create_publisher(String, "/reliable", QoSProfile(depth=10))
        assert wait_for(lambda: recorder.subscribed == ["/fast", "/reliable"], 10.0)
        assert wait_for(lambda: fast.get_subscription_count() and reliable.get_subscription_count(), 10.0)
        for k in range(5):
            fast.publish(String(data=f"f{k}"))
            reliable.publish(String(data=f"r{k}"))
        assert wait_for(lambda: recorder.total() == 10, 10.0)
        counts = recorder.close()
        assert recorder.close() == counts  # closing twice is harmless
    finally:
        running = False
        thread.join(2)
        executor.shutdown()
        node.destroy_node()
        pub_node.destroy_node()
    assert counts == {"/fast": 5, "/reliable": 5}
    assert sorted(seen) == ["/fast"] * 5 + ["/reliable"] * 5
    messages = list(bag.read_messages(out, ["/reliable"]))
    assert [m.msg.data for m in messages] == [f"r{k}" for k in range(5)]
    assert bag.bag_topics(out)["/fast"].count == 5


def test_refuses_no_topics_and_an_existing_file(ros: Any, tmp_path: Path) -> None:
    node = ros.create_node("record_refuse")
    try:
        with pytest.raises(RecordError, match="no topics"):
            Recorder(node, tmp_path / "a.mcap", [])
        (tmp_path / "b.mcap").write_bytes(b"")
        with pytest.raises(ValueError, match="exists"):
            Recorder(node, tmp_path / "b.mcap", ["/x"])
    finally:
        node.destroy_node()
