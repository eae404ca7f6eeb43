"""The node's camera inputs without ROS: checks, synchronised sets, drop reports, time jumps."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from msg_bridge import bag_factory, stamp_from_header
from msg_bridge.camera_info import camera_info_from_stereo
from msg_bridge.image import array_to_image
from roadbev_core.config import StereoCamera, SyncConfig
from roadbev_ros.camera_inputs import (
    LEFT_IMAGE,
    LEFT_INFO,
    RIGHT_IMAGE,
    RIGHT_INFO,
    STEREO_INPUTS,
    CameraInputs,
    sync_slot,
)
from roadbev_ros.diagnostics import Health
from roadbev_ros.mailbox import Mailbox

MS = 1_000_000
START_NS = 1_700_000_000 * 1_000_000_000
FACTORY = bag_factory()
CAMERA = StereoCamera(50.0, 50.0, 31.5, 23.5, 0.12, 64, 48)
TOPICS = {LEFT_IMAGE: "/cam/left/image_rect", RIGHT_IMAGE: "/cam/right/image_rect",
          LEFT_INFO: "/cam/left/camera_info", RIGHT_INFO: "/cam/right/camera_info"}


def message(which: str, stamp_ns: int, pixels: np.ndarray | None = None) -> Any:
    if which in (LEFT_IMAGE, RIGHT_IMAGE):
        image = np.zeros((CAMERA.height, CAMERA.width), np.uint8) if pixels is None else pixels
        return array_to_image(image, FACTORY, stamp_ns=stamp_ns, frame_id="left")
    return camera_info_from_stereo(CAMERA, FACTORY, right=which == RIGHT_INFO, stamp_ns=stamp_ns)


class Inputs:
    """CameraInputs with everything it reports kept."""

    def __init__(self, stereo: bool = True, config: SyncConfig | None = None) -> None:
        self.health = Health()
        self.mailbox: Mailbox[tuple[Any, ...]] = Mailbox()
        self.problems: list[tuple[str, str]] = []
        self.warnings: list[str] = []
        self.jumps: list[tuple[int, int] | None] = []
        self.now_ns = START_NS
        self.camera = CameraInputs(TOPICS, config or SyncConfig(), stereo, health=self.health,
                                   report=lambda kind, reason: self.problems.append((kind, reason)),
                                   warn=self.warnings.append, now_ns=lambda: self.now_ns, mailbox=self.mailbox,
                                   on_time_jump=self.jumps.append)

    def feed(self, stamp_ns: int, inputs: tuple[str, ...] = STEREO_INPUTS) -> None:
        for which in inputs:
            self.camera.add(which, message(which, stamp_ns))

    def kinds(self) -> list[str]:
        return [kind for kind, _ in self.problems]


def test_each_input_has_its_slot_and_a_mono_backend_needs_the_left_two_only() -> None:
    assert [sync_slot(which, 4) for which in STEREO_INPUTS] == [0, 1, 2, 3]
    assert [sync_slot(which, 2) for which in STEREO_INPUTS] == [0, None, 1, None]


def test_a_complete_set_reaches_the_mailbox_in_input_order() -> None:
    inputs = Inputs()
    inputs.now_ns = START_NS + 30 * MS
    inputs.feed(START_NS)
    taken = inputs.mailbox.take()
    assert taken is not None
    msgs, _ = taken
    assert [m.__class__.__name__ for m in msgs] == ["sensor_msgs__msg__Image", "sensor_msgs__msg__Image",
                                                    "sensor_msgs__msg__CameraInfo", "sensor_msgs__msg__CameraInfo"]
    assert inputs.health.frames_in == 1 and inputs.health.sets == 1
    assert inputs.health.arrival_age_ms.percentile(50) == pytest.approx(30.0)  # by the node's clock
    assert inputs.camera.received == dict.fromkeys(TOPICS, 1)
    assert inputs.problems == []


def test_a_newer_set_replaces_the_waiting_one_and_is_counted_busy() -> None:
    inputs = Inputs()
    inputs.feed(START_NS)
    inputs.feed(START_NS + 100 * MS)
    assert inputs.health.dropped_busy == 1 and inputs.health.sets == 2


def test_a_mono_backend_pairs_the_left_image_with_its_info_and_ignores_the_right() -> None:
    inputs = Inputs(stereo=False)
    inputs.feed(START_NS)
    taken = inputs.mailbox.take()
    assert taken is not None and len(taken[0]) == 2
    assert inputs.camera.received[RIGHT_IMAGE] == 1 and inputs.camera.sync.queued() == [0, 0]


def test_a_message_without_a_stamp_is_refused_and_a_left_image_counted_invalid() -> None:
    inputs = Inputs()
    inputs.camera.add(LEFT_IMAGE, message(LEFT_IMAGE, 0))
    inputs.camera.add(LEFT_INFO, message(LEFT_INFO, 0))
    assert inputs.problems == [("bad stamp", "left image: header has no stamp (0)"),
                               ("bad stamp", "left info: header has no stamp (0)")]
    assert inputs.health.frames_in == 1 and inputs.health.dropped_invalid == 1
    assert inputs.camera.sync.queued() == [0, 0, 0, 0]


def test_an_image_over_max_image_mb_is_refused_before_it_is_queued() -> None:
    inputs = Inputs(config=SyncConfig(max_image_mb=0.001, queue_mb=1.0))
    big = np.zeros((48, 64 * 3), np.uint8)  # 9216 bytes > 1048 bytes
    inputs.camera.add(LEFT_IMAGE, message(LEFT_IMAGE, START_NS, big))
    inputs.camera.add(RIGHT_IMAGE, message(RIGHT_IMAGE, START_NS, big))
    assert inputs.kinds() == ["image too large", "image too large"]
    assert "MiB is larger than the limit" in inputs.problems[0][1]
    assert inputs.health.frames_in == 1 and inputs.health.dropped_invalid == 1  # the left image only
    assert inputs.camera.sync.queued() == [0, 0, 0, 0]


def test_an_unpaired_left_image_names_the_inputs_that_never_arrived() -> None:
    inputs = Inputs(config=SyncConfig(queue_size=1))
    inputs.feed(START_NS, (LEFT_IMAGE, LEFT_INFO))
    inputs.feed(START_NS + 100 * MS, (LEFT_IMAGE, LEFT_INFO))  # the first left image overflows its queue
    assert inputs.kinds() == ["unpaired"]
    reason = inputs.problems[0][1]
    assert "nothing received on /cam/right/image_rect (right image), /cam/right/camera_info (right info)" in reason
    assert inputs.health.dropped_sync == 1
    inputs.feed(START_NS + 100 * MS, (RIGHT_INFO, RIGHT_IMAGE))  # the newest set completes
    inputs.feed(START_NS + 200 * MS, (LEFT_IMAGE,))
    inputs.feed(START_NS + 300 * MS, (LEFT_IMAGE,))
    assert inputs.kinds()[-1] == "unpaired" and "no matching right image / camera infos" in inputs.problems[-1][1]


def test_out_of_order_stamps_are_reported() -> None:
    inputs = Inputs()
    inputs.feed(START_NS + 100 * MS)
    inputs.feed(START_NS + 50 * MS, (LEFT_IMAGE,))
    assert inputs.problems == [("stamp order", f"left image at {(START_NS + 50 * MS) * 1e-9:.6f} s: out of order")]
    assert inputs.health.dropped_sync == 1


def test_a_jump_back_resets_the_caller_drops_the_waiting_set_and_is_logged_once() -> None:
    inputs = Inputs()
    for k in range(3):
        inputs.feed(START_NS + k * 100 * MS)
    assert inputs.mailbox.waiting
    inputs.feed(START_NS - 5_000 * MS)  # held: one message never resets
    assert inputs.jumps == [] and inputs.camera.passes == 0
    inputs.feed(START_NS - 4_900 * MS)  # the new timeline goes on: the clock did jump back
    assert inputs.camera.passes == 1 and inputs.health.time_jumps == 1
    assert inputs.jumps == [(START_NS - 5_000 * MS, START_NS - 4_900 * MS)]  # the restart span
    assert len(inputs.warnings) == 1 and inputs.warnings[0].startswith("stamps went back 5.10 s and stayed back")
    assert inputs.problems == []
    assert inputs.health.dropped_sync == 1  # the old pass's waiting set
    taken = inputs.mailbox.take()  # the new timeline goes on, from its held first messages
    assert taken is not None and stamp_from_header(taken[0][0]) == START_NS - 4_900 * MS
    assert inputs.health.sets == 5


def test_configure_rebuilds_the_synchroniser_only_for_other_inputs() -> None:
    inputs = Inputs()
    sync = inputs.camera.sync
    inputs.camera.configure(SyncConfig(slop_s=0.03), stereo=True)
    assert inputs.camera.sync is sync and sync.slop_ns == 30 * MS
    inputs.camera.configure(SyncConfig(), stereo=False)
    assert inputs.camera.sync is not sync and inputs.camera.sync.n_topics == 2


def test_a_set_stamped_far_ahead_is_reported_and_resets_nothing() -> None:
    inputs = Inputs()
    for stamp in (START_NS, START_NS + 100 * MS, START_NS + 5_000 * MS, START_NS + 200 * MS):
        inputs.feed(stamp)
    assert inputs.problems == [("stamp order", "a left image stamped 4.80 s ahead of the stream (a stamp glitch): "
                                               "nothing was reset")]
    assert inputs.jumps == [] and inputs.health.time_jumps == 0 and inputs.health.sets == 4
