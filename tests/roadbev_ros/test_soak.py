"""Soak: 1,000 frames through the node over DDS with flat memory (RSS growth under 5 %)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from roadbev_ros.diagnostics import DROP_KINDS

from ._ros_harness import MS, START_NS, Harness, wait_for

FRAMES = 1000
WARM_UP = 200


def rss_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


@pytest.mark.soak
def test_thousand_frames_with_flat_memory(ros: Any) -> None:
    h = Harness(ros, keep=5)
    try:
        frame_ns = 50 * MS
        baseline = 0
        start = time.monotonic()
        for k in range(FRAMES):
            stamp = START_NS + k * frame_ns
            for dt in (-20, 0, 20):
                h.publish_imu(stamp + dt * MS, 0.02)
            h.publish_frame(stamp)
            # lockstep: wait for the answer (a lost frame is allowed, it is counted)
            def answered(s: int = stamp) -> bool:
                return s in h.stamps_seen

            wait_for(answered, timeout=1.0, step=0.0005)
            if k == WARM_UP:
                baseline = rss_bytes()
        elapsed = time.monotonic() - start
        assert wait_for(lambda: h.node.counts()["frames_in"] == h.node.counts()["outputs"]
                        + sum(h.node.counts()[k] for k in DROP_KINDS), 5.0)
        final = rss_bytes()
        counts = h.node.counts()
        growth = (final - baseline) / baseline
        print(f"soak: {FRAMES} frames in {elapsed:.1f} s, RSS {baseline / 2**20:.1f} -> {final / 2**20:.1f} MiB "
              f"({100 * growth:+.2f} %), counts {counts}")
        assert counts["outputs"] >= 0.98 * FRAMES, counts
        assert growth < 0.05
    finally:
        h.close()
