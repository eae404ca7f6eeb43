"""The committed sample bag: exact message counts with two independent readers, and its content."""

from __future__ import annotations

import hashlib
import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from msg_bridge import bag_topics, read_messages
from msg_bridge.grid_map import grid_map_to_arrays
from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.evalbag import read_eval_bag

BAGS = Path(__file__).resolve().parents[2] / "bags"
SAMPLE = BAGS / "sample_drive.mcap"
COUNTS = {
    "/ground_truth/elevation": 20,
    "/imu/data": 386,
    "/roadbev/grid_config": 1,
    "/stereo/left/camera_info": 20,
    "/stereo/left/image_rect/compressed": 20,
    "/stereo/right/camera_info": 20,
    "/stereo/right/image_rect/compressed": 20,
}

pytestmark = pytest.mark.skipif(not SAMPLE.is_file(), reason="bags/sample_drive.mcap is missing")


def test_counts_with_our_reader() -> None:
    assert {topic: info.count for topic, info in bag_topics(SAMPLE).items()} == COUNTS
    assert Counter(m.topic for m in read_messages(SAMPLE, raw=True)) == COUNTS


def test_counts_and_decoding_with_the_independent_reader() -> None:
    counts: Counter[str] = Counter()
    with SAMPLE.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == "/roadbev/grid_config":
                assert decoded.data.startswith("{")
                continue
            stamp = decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec
            assert stamp == message.log_time  # log time = header stamp
            if channel.topic == "/ground_truth/elevation" and counts[channel.topic] == 1:
                assert grid_map_to_arrays(decoded).grid == GridSpec()
    assert counts == COUNTS


def test_it_is_an_evaluation_bag_with_a_pothole_and_a_speed_bump() -> None:
    bag = read_eval_bag(SAMPLE)
    assert len(bag) == 20 and bag.compressed and bag.stereo and bag.skipped == {}
    assert bag.grid == GridSpec() and bag.camera.size == (960, 528)
    lowest, highest = 0.0, 0.0
    for sample in bag:
        assert sample.inputs.left.shape == (528, 960, 3) and sample.truth is not None
        lowest, highest = min(lowest, np.nanmin(sample.truth)), max(highest, np.nanmax(sample.truth))
    assert lowest < -0.05  # a pothole (the 2 % cross slope alone stays within +-2 cm)
    assert highest > 0.08  # a speed bump


def test_the_readme_states_the_committed_digest() -> None:
    readme = (BAGS / "README.md").read_text()
    digest = re.search(r"sha256 of the committed bag: `([0-9a-f]{64})`", readme)
    assert digest is not None
    assert digest.group(1) == hashlib.sha256(SAMPLE.read_bytes()).hexdigest()
