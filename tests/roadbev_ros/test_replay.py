"""Replay in-process: timing and rate, raw bytes, restamping, looping, topic selection."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from msg_bridge import TypestoreFactory
from msg_bridge.bag import BagWriter, typestore
from msg_bridge.imu import imu_message
from roadbev_ros.replay import ReplayError, header_stamp_ns, history_depth, replay_bag, restamp_cdr

from ._ros_harness import wait_for

START = 1_700_000_000_000_000_000
PERIOD_NS = 20_000_000  # 50 Hz
N = 25


@pytest.fixture(scope="module")
def imu_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """IMU at 50 Hz for half a second, and one latched-looking String."""
    path = tmp_path_factory.mktemp("replay") / "imu.mcap"
    factory = TypestoreFactory(typestore())
    with BagWriter(path) as writer:
        writer.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        writer.add_topic("/note", "std_msgs/msg/String", latched=True)
        writer.write("/note", factory.new("std_msgs/msg/String", data="hello"), START)
        for k in range(N):
            stamp = START + k * PERIOD_NS
            writer.write("/imu/data", imu_message(factory, stamp_ns=stamp, orientation_xyzw=(0, 0, 0, 1)), stamp)
    return path


class Listener:
    """Receive times and stamps of /imu/data, and /note."""

    def __init__(self, rclpy: Any) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu
        from std_msgs.msg import String

        self.node = rclpy.create_node("replay_listener")
        self.pub_node = rclpy.create_node("replay_publisher")
        self.imu: list[tuple[float, int]] = []
        self.notes: list[str] = []
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(
            Imu, "/imu/data",
            lambda m: self.imu.append((time.monotonic(), m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)),
            qos)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(String, "/note", lambda m: self.notes.append(m.data), latched)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self) -> None:
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.running = False
        self.thread.join(2)
        self.executor.shutdown()
        self.node.destroy_node()
        self.pub_node.destroy_node()


@pytest.fixture
def listener(ros: Any) -> Any:
    lis = Listener(ros)
    yield lis
    lis.close()


def test_restamp_cdr_round_trip() -> None:
    from msg_bridge.bag import serialize

    factory = TypestoreFactory(typestore())
    data = serialize(imu_message(factory, stamp_ns=START + 5, orientation_xyzw=(0, 0, 0, 1)), "sensor_msgs/msg/Imu")
    assert header_stamp_ns(data) == START + 5
    moved = restamp_cdr(data, 42 * 10**9 + 7)
    assert header_stamp_ns(moved) == 42 * 10**9 + 7
    assert moved[12:] == data[12:] and len(moved) == len(data)


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_replay_keeps_the_timing_at_the_rate(listener: Listener, imu_bag: Path, rate: float) -> None:
    stats = replay_bag(listener.pub_node, imu_bag, rate=rate, wait_for_subscribers=10.0)
    assert wait_for(lambda: len(listener.imu) == N, 5.0), len(listener.imu)
    assert stats.per_topic == {"/imu/data": N, "/note": 1}
    received = np.array([t for t, _ in listener.imu])
    expected = np.arange(N) * PERIOD_NS * 1e-9 / rate
    error = np.abs((received - received[0]) - expected)
    assert np.median(error) < 0.01 and np.percentile(error, 90) < 0.05, error
    assert stats.duration_s == pytest.approx(expected[-1], abs=0.05)
    assert stats.late_p50_ms < 5.0
    assert [s for _, s in listener.imu] == [START + k * PERIOD_NS for k in range(N)]  # untouched
    assert wait_for(lambda: listener.notes == ["hello"], 3.0)


def test_restamp_loop_and_stop(listener: Listener, imu_bag: Path) -> None:
    stop = threading.Event()

    def stop_in_the_third_pass() -> None:
        if wait_for(lambda: len(listener.imu) >= 2 * N + 3, 20.0):
            stop.set()

    watcher = threading.Thread(target=stop_in_the_third_pass)
    watcher.start()  # stops the replay early in its third pass
    before = time.time_ns()
    stats = replay_bag(listener.pub_node, imu_bag, rate=1.0, loop=True, restamp=True, topics=["/imu/data"],
                       wait_for_subscribers=10.0, stop=stop)
    watcher.join()
    assert stats.loops == 3 and 2 * N + 3 <= stats.per_topic["/imu/data"] < 3 * N
    assert wait_for(lambda: len(listener.imu) == stats.messages, 5.0)
    stamps = np.array([s for _, s in listener.imu], dtype=np.int64)
    assert np.all(np.diff(stamps) > 0)  # restamped: time goes on across the loop
    assert stamps[0] >= before and stamps[-1] <= time.time_ns()  # wall-clock stamps
    # each stamp is the wall time of its publication: it matches the receive time up to the
    # delivery delay (robust statistics: a loaded machine delays a few deliveries)
    received = np.array([t for t, _ in listener.imu])
    offset = np.abs((stamps - stamps[0]) * 1e-9 - (received - received[0]))
    assert np.median(offset) < 0.01 and np.percentile(offset, 90) < 0.05, offset


def test_unknown_topics_only_give_an_error(listener: Listener, imu_bag: Path) -> None:
    with pytest.raises(ReplayError, match="nothing to replay"):
        replay_bag(listener.pub_node, imu_bag, topics=["/nope"])


@pytest.mark.parametrize("fraction", [0.35, 0.85])
def test_a_truncated_bag_is_replayed_as_far_as_it_is_readable(listener: Listener, imu_bag: Path, tmp_path: Path,
                                                              fraction: float) -> None:
    from msg_bridge.bag import ReadStats, read_messages

    from ._damaged_bags import rewrite, truncate

    small = tmp_path / "small_chunks.mcap"
    rewrite(imu_bag, small, chunk_size=1024)
    cut = truncate(small, tmp_path / "cut.mcap", fraction)
    readable = list(read_messages(cut, ["/imu/data"], raw=True, on_damage="skip", stats=ReadStats()))
    assert 0 < len(readable) <= N  # a cut in the summary still leaves every message
    stats = replay_bag(listener.pub_node, cut, rate=0.0, wait_for_subscribers=10.0)
    assert stats.per_topic["/imu/data"] == len(readable)
    assert not stats.bag_complete and stats.read_problems
    if len(readable) < N:
        assert any("breaks off" in p for p in stats.read_problems)
    assert wait_for(lambda: len(listener.imu) == len(readable), 5.0), len(listener.imu)
    assert [s for _, s in listener.imu] == [START + k * PERIOD_NS for k in range(len(readable))]


SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_drive.mcap"


@pytest.mark.skipif(not SAMPLE.exists(), reason="bags/sample_drive.mcap is not in this checkout")
def test_the_replay_command_waits_then_says_who_is_missing_and_replays_anyway(ros: Any) -> None:
    """Nobody on the bag's (compressed) image topic, a node on the raw one: after the wait the
    command names the topic and the setting, then replays (exit 0)."""
    import subprocess
    import sys

    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    from roadbev_ros.dds import child_env

    listener = ros.create_node("raw_image_listener")
    listener.create_subscription(Image, "/stereo/left/image_rect", lambda _m: None, qos_profile_sensor_data)
    try:
        topic = "/stereo/left/image_rect/compressed"
        before = time.monotonic()
        # (4 s: the replay process must discover the listener first, slow on a loaded machine)
        proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "replay", str(SAMPLE), "--topics", topic,
                               "--wait-for-subscribers", "4", "--rate", "0"],
                              capture_output=True, text=True, timeout=120, env=child_env())
        took = time.monotonic() - before
    finally:
        listener.destroy_node()
    assert proc.returncode == 0, proc.stderr
    warning = next(line for line in proc.stderr.splitlines() if "no subscriber" in line)
    assert warning.startswith(f"roadbev replay: warning: no subscriber on {topic} after 4 s"), warning
    assert "start the node with -p image_transport:=compressed" in warning and warning.endswith("replaying anyway")
    assert "published 20 messages" in proc.stdout and took >= 4.0


def test_replay_waits_only_for_the_topics_it_is_told(listener: Listener, imu_bag: Path) -> None:
    """Only the named topics are waited for; once they have a subscriber the replay starts, with
    nothing reported (the timeout case: the command test above)."""
    missed: list[list[str]] = []
    stats = replay_bag(listener.pub_node, imu_bag, rate=0.0, wait_for_subscribers=10.0, wait_topics=["/imu/data"],
                       on_wait_timeout=missed.append)
    assert stats.unmatched == [] and missed == [] and stats.waited_s < 10.0
    assert stats.per_topic["/imu/data"] == N


def test_an_interrupted_replay_says_how_much_it_published_of_what(imu_bag: Path) -> None:
    from roadbev_cli.commands.replay import published_of_bag

    assert published_of_bag(imu_bag, {"/imu/data": 7}) == f"/imu/data 7 of {N}, /note 0 of 1"


def test_the_replay_command_reports_an_interruption(imu_bag: Path) -> None:
    import signal
    import subprocess
    import sys

    from roadbev_ros.dds import child_env

    proc = subprocess.Popen([sys.executable, "-m", "roadbev_cli.cli", "replay", str(imu_bag), "--rate", "0.02",
                             "--no-wait", "--loop"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    try:
        time.sleep(4.0)  # up and publishing: at 1/50 of the bag's rate it is far from its end
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "roadbev replay: warning: interrupted after " in err, err
    assert f" of {N}" in err and "/note " in err


def test_history_depth_keeps_a_second_of_a_fast_topic_and_never_less_than_the_minimum() -> None:
    assert history_depth(1000, 10.0, 10, 1.0) == 100  # a 100 Hz IMU keeps a second
    assert history_depth(1001, 10.0, 10, 1.0) == 101  # rounded up
    assert history_depth(100, 10.0, 10, 1.0) == 10  # a 10 Hz camera: the minimum
    assert history_depth(1000, 10.0, 10, 0.5) == 50
    assert history_depth(1, 0.0, 10, 1.0) == 10  # one message, or no span: the minimum
    assert history_depth(500, 0.0, 10, 1.0) == 10
