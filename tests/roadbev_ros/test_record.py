"""Recorder: topics appear late, QoS follows the publishers, the file is complete after close."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from msg_bridge import bag
from roadbev_ros.record import Recorder, RecordError

from ._ros_harness import Spinning, wait_for


def test_records_best_effort_and_reliable_publishers_that_appear_later(ros: Any, tmp_path: Path) -> None:
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from std_msgs.msg import String

    node = ros.create_node("record_test")
    seen: list[str] = []
    out = tmp_path / "out.mcap"
    with Spinning(ros, node) as spun:
        recorder = Recorder(node, out, ["/fast", "reliable", "/never"], listener=lambda t, d: seen.append(t))
        fast = spun.feeder.create_publisher(String, "/fast", qos_profile_sensor_data)  # best effort
        reliable = spun.feeder.create_publisher(String, "/reliable", QoSProfile(depth=10))
        assert wait_for(lambda: recorder.subscribed == ["/fast", "/reliable"], 10.0)
        assert wait_for(lambda: fast.get_subscription_count() and reliable.get_subscription_count(), 10.0)
        for k in range(5):
            fast.publish(String(data=f"f{k}"))
            reliable.publish(String(data=f"r{k}"))
        assert wait_for(lambda: recorder.total() == 10, 10.0)
        counts = recorder.close()
        assert recorder.close() == counts  # closing twice is harmless
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


def _replay_bag(path: Path, seconds: float = 3.0) -> None:
    """A small, fast replay: IMU at 200 Hz and a 57 KB image at 20 Hz."""
    import numpy as np

    from msg_bridge import bag_factory
    from msg_bridge.image import array_to_image
    from msg_bridge.imu import imu_message

    factory = bag_factory()
    start = 1_700_000_000 * 10**9
    pixels = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    with bag.BagWriter(path) as writer:
        writer.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        writer.add_topic("/cam/image", "sensor_msgs/msg/Image")
        for k in range(int(seconds * 200)):
            stamp = start + k * 5_000_000
            writer.write("/imu/data", imu_message(factory, stamp_ns=stamp, orientation_xyzw=(0, 0, 0, 1)), stamp)
            if k % 10 == 0:
                writer.write("/cam/image", array_to_image(pixels, factory, stamp_ns=stamp), stamp)


def _record_and_kill(ros: Any, source: Path, outs: list[Path], kill_after: list[float],
                     tmp_path: Path) -> tuple[list[tuple[float, str, bytes]], list[float]]:
    """Replay ``source`` at rate 1 into one ``roadbev record OUT`` process per ``outs`` and SIGKILL
    recorder i ``kill_after[i]`` seconds after the first publication. Returns (what was published,
    with its monotonic time; the time of each kill)."""
    import signal
    import subprocess
    import sys
    import time

    from roadbev_ros.dds import child_env
    from roadbev_ros.replay import replay_bag

    from ._ros_harness import wait_for

    published: list[tuple[float, str, bytes]] = []
    killed_at = [0.0] * len(outs)
    stop = threading.Event()
    procs = []
    for i, out in enumerate(outs):
        with (tmp_path / f"record{i}.log").open("wb") as log:
            procs.append(subprocess.Popen([sys.executable, "-m", "roadbev_cli.cli", "record", str(out),
                                           "--topics", "/imu/data", "/cam/image"],
                                          stdout=log, stderr=subprocess.STDOUT, env=child_env()))

    def hook(topic: str, _log_time: int, data: bytes) -> None:
        published.append((time.monotonic(), topic, bytes(data)))

    def killer() -> None:
        while not published and not stop.is_set():
            time.sleep(0.005)
        for i in sorted(range(len(procs)), key=lambda i: kill_after[i]):
            if published:
                time.sleep(max(0.0, published[0][0] + kill_after[i] - time.monotonic()))
            procs[i].send_signal(signal.SIGKILL)
            killed_at[i] = time.monotonic()
        stop.set()

    node = ros.create_node("kill_replay")
    thread = threading.Thread(target=killer, daemon=True)
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image, Imu

    # Publishers as the replay's (reliable), so that the recorders discover the topics and
    # subscribe before the replay starts (it only waits for one subscriber per topic).
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    announce = [node.create_publisher(Imu, "/imu/data", qos), node.create_publisher(Image, "/cam/image", qos)]
    try:
        counts = lambda: min(node.count_subscribers(t) for t in ("/imu/data", "/cam/image"))  # noqa: E731
        assert wait_for(lambda: counts() >= len(outs) or any(p.poll() is not None for p in procs), 60.0)
        thread.start()
        for publisher in announce:
            node.destroy_publisher(publisher)
        replay_bag(node, source, rate=1.0, wait_for_subscribers=10.0, stop=stop, before_publish=hook, linger_s=0.0)
    finally:
        stop.set()
        if thread.is_alive():
            thread.join(5)
        node.destroy_node()
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)
    for i, proc in enumerate(procs):
        assert proc.returncode == -signal.SIGKILL and killed_at[i], (tmp_path / f"record{i}.log").read_text()
    return published, killed_at


def test_sigkill_at_random_moments_loses_nothing_older_than_a_second(ros: Any, tmp_path: Path) -> None:
    """``roadbev record`` killed with SIGKILL at random moments of a replay (three recorders, one
    kill time each): the recovered bag holds every message published more than 1 s before its
    kill, byte for byte, and nothing that was not published."""
    import random

    source = tmp_path / "source.mcap"
    _replay_bag(source)
    rng = random.Random(18)
    outs = [tmp_path / f"killed{i}.mcap" for i in range(3)]
    kill_after = [rng.uniform(1.1, 2.7) for _ in outs]
    published, killed_at = _record_and_kill(ros, source, outs, kill_after, tmp_path)
    published_set = Counter((t, d) for _w, t, d in published)
    for run, out in enumerate(outs):
        assert bag.marker_path(out).is_file() and not bag.bag_info(out).closed
        fixed = tmp_path / f"recovered{run}.mcap"
        stats = bag.recover_bag(out, fixed)
        recorded = Counter((m.topic, bytes(m.msg)) for m in bag.read_messages(fixed, raw=True))
        old_enough = [(t, d) for when, t, d in published if when < killed_at[run] - 1.0]
        assert old_enough, f"run {run}: nothing was published a second before the kill"
        missing = [t for t, d in old_enough if recorded[(t, d)] == 0]
        assert not missing, f"run {run}: {len(missing)} of {len(old_enough)} old messages lost ({stats.summary()})"
        assert all(published_set[key] >= n for key, n in recorded.items())  # nothing invented
        before_kill = sum(1 for when, _t, _d in published if when < killed_at[run])
        print(f"run {run}: killed {killed_at[run] - published[0][0]:.2f} s in; published before the kill "
              f"{before_kill}, of them older than 1 s {len(old_enough)}; recovered {sum(recorded.values())}")


def test_a_topic_nothing_published_is_warned_of(tmp_path: Path) -> None:
    import subprocess
    import sys

    from roadbev_ros.dds import child_env

    out = tmp_path / "silent.mcap"
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "record", str(out), "--topics",
                           "/nobody/publishes/this", "--duration", "1"], capture_output=True, text=True, timeout=60,
                          env=child_env())
    assert proc.returncode == 0, proc.stderr
    assert ("roadbev record: warning: /nobody/publishes/this: 0 messages recorded: nothing published it "
            "(never discovered)") in proc.stderr
