"""The node's camera inputs, without ROS: images and camera infos into synchronised sets for the
inference worker.

Each message is checked before it is queued (a stamp, an image within ``max_image_mb``); the
synchroniser (:class:`roadbev_ros.sync.ApproximateTimeSync`: the four inputs for a stereo
backend, the left two for a mono one) pairs them, and each set goes to the worker's mailbox,
replacing a waiting one (counted ``busy``). The left image is the frame: every left image is
counted in (:meth:`Health.frame_in`) and ends as an output or a counted drop; the other inputs
are reported when refused, not counted. When the stamps jump back and stay back (a bag looped,
a ``/clock`` reset) the synchroniser has reset itself: the caller resets what it holds, the
waiting set of the old pass is dropped, and the jump is counted and logged once.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

from msg_bridge import MessageError, stamp_from_header
from msg_bridge.image import check_image_message
from roadbev_core.config import SyncConfig
from roadbev_ros.diagnostics import Health
from roadbev_ros.mailbox import Mailbox
from roadbev_ros.sync import ApproximateTimeSync, DropReason

__all__ = [
    "LEFT_IMAGE", "LEFT_INFO", "MONO_INPUTS", "RIGHT_IMAGE", "RIGHT_INFO", "STEREO_INPUTS", "TIME_JUMP_BACK_S",
    "CameraInputs", "sync_slot",
]

LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO = "left image", "right image", "left info", "right info"
STEREO_INPUTS = (LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO)  # in their synchroniser slots' order
MONO_INPUTS = (LEFT_IMAGE, LEFT_INFO)  # what a mono backend needs, in the same order
# A camera message this much older than the last paired one means the clock jumped back (a bag
# looped or started again): the synchroniser, the IMU history and the pipeline start afresh.
# (Half a second: a looped bag of one second jumps back by one second less one frame.)
TIME_JUMP_BACK_S = 0.5

Report = Callable[[str, str], None]


def sync_slot(which: str, n_topics: int) -> int | None:
    """The synchroniser slot of the input ``which`` (``n_topics`` 2: a mono backend's
    synchroniser, else stereo); None for an input a mono backend does not need."""
    inputs = MONO_INPUTS if n_topics == 2 else STEREO_INPUTS
    return inputs.index(which) if which in inputs else None


class CameraInputs:
    """Camera messages in, synchronised sets into ``mailbox`` (module docstring).

    Args:
        topics: each input's topic as the graph names it (remapped, fully qualified), by input
            name: an input that never arrived is named when its partners are dropped unpaired.
        config: the synchroniser's settings.
        stereo: the backend needs all four inputs (else the left image and its info).
        health: the node's figures.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
        warn: writes a warning line to the log.
        now_ns: the node's clock (sim time under use_sim_time), nanoseconds.
        mailbox: where each set goes: its messages, in :data:`STEREO_INPUTS` (or
            :data:`MONO_INPUTS`) order.
        on_time_jump: resets what the caller holds after a jump back; given the stamps of the
            new timeline seen so far (:attr:`ApproximateTimeSync.restart_span`).
        on_set: told when every set arrives (``time.monotonic()``), before it goes to the
            mailbox (the node's pacer measures the camera's period from them).
    """

    def __init__(self, topics: Mapping[str, str], config: SyncConfig, stereo: bool, *, health: Health,
                 report: Report, warn: Callable[[str], object], now_ns: Callable[[], int],
                 mailbox: Mailbox[tuple[Any, ...]], on_time_jump: Callable[[tuple[int, int] | None], None],
                 on_set: Callable[[float], object] = lambda _arrival_s: None) -> None:
        self.topics = topics
        self.received: dict[str, int] = dict.fromkeys(topics, 0)  # messages per input so far
        self.passes = 0  # time jumps back so far: a frame of an earlier pass fails quietly
        self._health = health
        self._report = report
        self._warn = warn
        self._now_ns = now_ns
        self._mailbox = mailbox
        self._on_time_jump = on_time_jump
        self._on_set_arrival = on_set
        self._config = config
        self.sync = self._new_sync(config, stereo)

    def _new_sync(self, config: SyncConfig, stereo: bool) -> ApproximateTimeSync:
        return ApproximateTimeSync(4 if stereo else 2, config.queue_size, config.slop_s, self._on_set,
                                   self._on_drop, jump_back_s=TIME_JUMP_BACK_S, on_reset=self._on_reset,
                                   max_bytes=int(config.queue_mb * 2**20), on_outlier=self._on_outlier)

    def configure(self, config: SyncConfig, stereo: bool) -> None:
        """New settings, or a backend that needs other inputs (then a new, empty synchroniser)."""
        if (self.sync.n_topics == 4) != stereo:
            self.sync = self._new_sync(config, stereo)
        else:
            self.sync.configure(config.queue_size, config.slop_s, int(config.queue_mb * 2**20))
        self._config = config

    def add(self, which: str, msg: Any) -> None:
        """A message of the input ``which`` (a subscription's callback)."""
        admitted = self.admit(which, msg)
        if admitted is not None:
            slot, stamp, nbytes = admitted
            self.sync.add(slot, stamp, (which, msg), nbytes)

    def admit(self, which: str, msg: Any) -> tuple[int, int, int] | None:
        """Check a message of the input ``which`` before it is queued.

        Returns:
            ``(slot, stamp_ns, nbytes)`` to queue it, or None: an input the backend does not need,
            or a message without a stamp or with an image over ``max_image_mb`` (reported; a left
            image counted as dropped).
        """
        self.received[which] += 1
        slot = sync_slot(which, self.sync.n_topics)
        if slot is None:
            return None
        left = which == LEFT_IMAGE
        try:
            stamp = stamp_from_header(msg)
            if stamp <= 0:
                raise MessageError("header has no stamp (0)")
        except MessageError as exc:
            if left:
                self._health.frame_in()
                self._health.drop("invalid")
            self._report("bad stamp", f"{which}: {exc}")
            return None
        if left:  # the stamp's age by the node's clock
            self._health.frame_in((self._now_ns() - stamp) * 1e-9)
        nbytes = 0
        if which in (LEFT_IMAGE, RIGHT_IMAGE):  # refused before it is held (issue 19: 46 MB images)
            try:
                nbytes = check_image_message(msg, int(self._config.max_image_mb * 2**20), which)
            except MessageError as exc:
                if left:
                    self._health.drop("invalid")
                self._report("image too large", str(exc))
                return None
        return slot, stamp, nbytes

    def _on_set(self, *items: tuple[str, Any]) -> None:
        self._health.set_in()
        self._on_set_arrival(time.monotonic())
        if self._mailbox.put(tuple(msg for _, msg in items)):
            self._health.drop("busy")  # the waiting set was replaced by a newer one

    def _on_drop(self, topic: int, stamp: int, item: tuple[str, Any], reason: str) -> None:
        """A message left the synchroniser unpaired: a left image is counted as dropped, a drop
        that says something about the inputs is reported."""
        which = item[0]
        if reason == DropReason.RESET:
            pass  # counted below; the jump itself is logged once by _on_reset
        elif reason in (DropReason.OUT_OF_ORDER, DropReason.DUPLICATE, DropReason.GLITCH):
            self._report("stamp order", f"{which} at {stamp * 1e-9:.6f} s: {reason}")
        elif which == LEFT_IMAGE:
            needed = STEREO_INPUTS if self.sync.n_topics == 4 else MONO_INPUTS
            silent = [f"{self.topics[name]} ({name})" for name in needed if self.received[name] == 0]
            if silent:
                self._report("unpaired", f"left image at {stamp * 1e-9:.6f} s dropped: nothing received on "
                             f"{', '.join(silent)}; is it published, and remapped to?")
            else:
                self._report("unpaired", f"left image at {stamp * 1e-9:.6f} s dropped: {reason} "
                             "(no matching right image / camera infos within the slop)")
        elif reason == DropReason.OVERFLOW_BYTES:
            self._report("unpaired", f"{which} at {stamp * 1e-9:.6f} s dropped: {reason} (sync_queue_mb)")
        if which == LEFT_IMAGE:
            self._health.drop("sync")

    def _on_outlier(self, topic: int, ahead_ns: int) -> None:
        """One set stamped far ahead of the stream (a stamp glitch): it was dropped downstream or
        published; the stream goes on from the stamps before it and nothing is reset."""
        if topic == 0:
            self._report("stamp order", f"a left image stamped {ahead_ns * 1e-9:.2f} s ahead of the stream "
                         "(a stamp glitch): nothing was reset")

    def _on_reset(self, topic: int, jump_ns: int) -> None:
        """A looped or restarted bag, or a /clock reset (the synchroniser saw the stamps jump back
        and stay back, and has reset itself): a reset of everything fused, a WARN and a count."""
        self.passes += 1
        self._on_time_jump(self.sync.restart_span)
        if self._mailbox.clear():  # a set of the old pass must not meet the new pass's IMU
            self._health.drop("sync")
        self._health.time_jump()
        self._warn(f"stamps went back {jump_ns * 1e-9:.2f} s and stayed back (a bag started again, a /clock "
                   "reset): the synchroniser, the IMU history, the odometry and the fused map start afresh")
