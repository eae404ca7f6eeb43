"""Online evaluation: replay -> node (its own process) -> record -> compare with the ground truth.

The same metrics as ``roadbev eval`` (:class:`roadbev_lab.evaluation.metrics.MetricAccumulator` and
:class:`~roadbev_lab.evaluation.metrics.SigmaAccumulator` over the recorded ``uncertainty`` layer, the keys
of docs/interface/evaluation.md), but every estimate has travelled over DDS: the bag's input topics are replayed as raw
bytes, the node runs as a separate process (``roadbev node``), its outputs are recorded to an
MCAP bag, and the recorded elevation maps are matched to ``/ground_truth/elevation`` by stamp. With the far
field on (``far_field.enabled`` among the parameters) and a bag with its truth
(``/ground_truth/elevation_far``), the far-field grid is set from that truth as ``roadbev eval``
sets it, the node's ``/roadbev/elevation_far`` is recorded and scored the same way: the
``far_field`` key of :func:`roadbev_lab.evaluation.frames.far_field_metrics`.

Two pacings:

* ``rate=None`` (default, *lockstep*): messages go out as fast as the node answers: each left
  image is held back until the node has published (or counted as dropped) the previous one, so
  every frame is processed and the metrics equal the offline evaluation's;
* ``rate=R``: the bag's timing scaled by R; when the backend is slower than the camera the node
  drops frames (it keeps the newest), and a frame without an output counts as missing (all its
  labelled cells lower ``coverage_pct``).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.executors import SingleThreadedExecutor

from msg_bridge import bag
from msg_bridge.grid_map import grid_map_to_arrays, map_window_from_message
from msg_bridge.preview import preview_from_message
from roadbev_core.config import DEFAULT_BACKEND, GridSpec, RoadbevConfig, load_params_file
from roadbev_core.errors import RoadbevError
from roadbev_core.pipeline import check_config
from roadbev_lab.evaluation.arrival import TimedPreview, map_accuracy
from roadbev_lab.evaluation.drivebag import is_drive_bag, read_drive_truth, score_previews
from roadbev_lab.evaluation.evalbag import EvalBag, grid_fields, read_eval_bag
from roadbev_lab.evaluation.frames import far_field_metrics, json_safe
from roadbev_lab.evaluation.metrics import BandAccumulator, MetricAccumulator, Metrics, SigmaAccumulator
from roadbev_lab.evaluation.offline import far_field_params
from roadbev_ros.dds import child_env, init_ros
from roadbev_ros.diagnostics import DROP_KINDS
from roadbev_ros.record import Recorder
from roadbev_ros.replay import header_stamp_ns, replay_bag

__all__ = ["OnlineEvalError", "OnlineResult", "evaluate_online", "format_online", "latencies_on_arrival",
           "node_command", "stop_process"]

ELEVATION_TOPIC = "/roadbev/elevation"
PREVIEW_TOPIC = "/roadbev/preview"
MAP_TOPIC = "/roadbev/map"
# the node's outputs, and the TF viewers need to place them (the node's per-frame TF on /tf, the
# mount the replay publishes on /tf_static)
OUTPUT_TOPICS = (ELEVATION_TOPIC, PREVIEW_TOPIC, MAP_TOPIC, "/diagnostics", "/tf", "/tf_static")


class OnlineEvalError(RoadbevError, RuntimeError):
    """The online evaluation could not run (node did not start, no ground truth...)."""


@dataclass
class OnlineResult:
    """What :func:`evaluate_online` measured.

    Attributes:
        accuracy: the accuracy metrics, typed (as the offline :class:`roadbev_lab.evaluation.frames.EvalResult`'s).
        metrics: the interface's keys (as ``roadbev eval``) plus ``mode`` and ``online`` details:
            outputs, frames without output, ``latency_ms`` (left image published -> elevation
            map received, over DDS both ways), ``latency_on_arrival_ms`` (the same less each
            frame's wait for the node: :func:`latencies_on_arrival`) and the node's last diagnostics.
        recorded: path of the recorded outputs (MCAP).
        node_log: the node process's output.
    """

    metrics: dict[str, Any]
    accuracy: Metrics
    recorded: Path
    node_log: str = ""
    diagnostics: dict[str, str] = field(default_factory=dict)


def node_command(backend: str, grid_params: Mapping[str, float], params_file: Path | None = None,
                 extra_params: Mapping[str, Any] | None = None) -> list[str]:
    """The ``roadbev node`` command line running ``backend`` on the evaluation grid."""
    ros_args = []
    if params_file is not None:
        ros_args += ["--params-file", str(params_file)]
    for name, value in {**dict(grid_params), **dict(extra_params or {}), "backend": backend}.items():
        # an empty string in YAML's words: a bare "name:=" would be no value at all
        text = repr(float(value)) if isinstance(value, float) else str(value) if value != "" else "''"
        if isinstance(value, bool):
            text = "true" if value else "false"
        ros_args += ["-p", f"{name}:={text}"]
    return [sys.executable, "-m", "roadbev_cli.cli", "node", "--ros-args", *ros_args]


class _Watcher:
    """Stamps of the elevation maps received and the node's latest diagnostics."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.stamps: set[int] = set()
        self.received: dict[int, float] = {}  # stamp -> monotonic receive time
        self.diagnostics: dict[str, str] = {}

    def __call__(self, topic: str, data: bytes) -> None:
        if topic == ELEVATION_TOPIC:
            stamp = header_stamp_ns(data)
            now = time.monotonic()
            with self.cond:
                self.stamps.add(stamp)
                self.received.setdefault(stamp, now)
                self.cond.notify_all()
        elif topic == "/diagnostics":
            msg = bag.deserialize(data, "diagnostic_msgs/msg/DiagnosticArray")
            if msg.status:
                with self.cond:
                    self.diagnostics = {kv.key: kv.value for kv in msg.status[0].values}
                    self.cond.notify_all()

    def accounted(self) -> int:
        """Left images the node has answered or counted as dropped (from its diagnostics)."""
        d = self.diagnostics
        try:
            return sum(int(d[k]) for k in ("outputs", *DROP_KINDS))
        except (KeyError, ValueError):
            return 0

    def wait(self, stamp: int | None, answered: int, timeout: float) -> bool:
        """Until the map for ``stamp`` arrived or the node accounted for ``answered`` images."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while not ((stamp is not None and stamp in self.stamps) or self.accounted() >= answered):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.cond.wait(min(remaining, 0.1))
        return True


def _truths(path: Path, eval_bag: EvalBag) -> dict[int, np.ndarray]:
    """The ground truth by stamp (empty for a bag without it: then nothing is scored)."""
    truths = {}
    grid = eval_bag.grid
    # partial bags: what is readable
    for item in bag.read_messages(path, [eval_bag.topics.ground_truth], on_damage="skip"):
        decoded = grid_map_to_arrays(item.msg, base=grid)
        truths[decoded.stamp_ns] = np.asarray(decoded.layers["elevation"], dtype=np.float32)
    return truths


def _whole_frames(path: Path, eval_bag: EvalBag) -> set[int]:
    """Stamps of the frames the node can answer: every frame of a sound bag; in a damaged or
    cut one, only those with every synchronised input (images, CameraInfos) at their stamp."""
    stamps = set(eval_bag.stamps)
    if eval_bag.read_stats.complete:
        return stamps
    names = eval_bag.topics
    topics = [names.left_image, names.left_info] + ([names.right_image, names.right_info] if eval_bag.stereo else [])
    seen: dict[str, set[int]] = {t: set() for t in topics}
    for item in bag.read_messages(path, topics, raw=True, on_damage="skip"):
        seen[item.topic].add(header_stamp_ns(bytes(item.msg)))
    for found in seen.values():
        stamps &= found
    return stamps


def _estimates(recorded: Path, grid: GridSpec, topic: str = ELEVATION_TOPIC
               ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Stamp -> (elevation, 1-sigma) [R, C] of every recorded map on ``topic``; the sigma is NaN
    where the map has no ``uncertainty`` layer."""
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if not recorded.exists():
        return out
    for item in bag.read_messages(recorded, [topic], on_damage="skip"):
        decoded = grid_map_to_arrays(item.msg, base=grid)
        elevation = np.asarray(decoded.layers["elevation"], dtype=np.float32)
        sigma = decoded.layers.get("uncertainty")
        out[decoded.stamp_ns] = (
            elevation, np.full_like(elevation, np.nan) if sigma is None else np.asarray(sigma, dtype=np.float32)
        )
    return out


def _far_scores(recorded: Path, topic: str, far_grid: GridSpec, eval_bag: EvalBag, frames: Sequence[int]
                ) -> dict[str, Any]:
    """The ``far_field`` key over the recorded far-field maps of ``frames`` (a frame with truth and
    no map counts as all unanswered), as ``roadbev eval`` scores it."""
    estimates = _estimates(recorded, far_grid, topic)
    scored, sigma, bands = MetricAccumulator(far_grid), SigmaAccumulator(), BandAccumulator(far_grid)
    empty = np.full(far_grid.shape, np.nan, np.float32)
    for stamp in frames:
        truth = eval_bag.far_truth(stamp)
        if truth is None:
            continue
        elevation, uncertainty = estimates.get(stamp, (empty, empty))
        scored.add(elevation, truth)
        sigma.add(elevation, uncertainty, truth)
        bands.add(elevation, uncertainty, truth)
    return far_field_metrics(far_grid, scored, sigma, bands)


def stop_process(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
    """Stop a node or tool process as Ctrl-C does (SIGINT, so it closes cleanly); killed when it
    has not ended after ``timeout`` s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)


def evaluate_online(
    bag_path: str | Path,
    out_dir: str | Path,
    *,
    backend: str = DEFAULT_BACKEND,
    params: Mapping[str, Any] | None = None,
    params_file: str | Path | None = None,
    rate: float | None = None,
    startup_timeout_s: float = 120.0,
    frame_timeout_s: float = 60.0,
    node_params: Mapping[str, Any] | None = None,
    on_image_sent: Callable[[int, int], None] | None = None,
) -> OnlineResult:
    """Replay ``bag_path`` into a node process, record its outputs, and score them.

    Args:
        bag_path: an evaluation bag (with ``/ground_truth/elevation``).
        out_dir: where the recorded outputs (``online.mcap``) and the node log go.
        backend: the node's backend.
        params: parameters (as from a params YAML) for the evaluation grid (``base_height``,
            vertical range...); also passed to the node.
        params_file: a ROS 2 params YAML for the node (read for the grid too).
        rate: None = lockstep (every frame processed); else the replay rate factor.
        startup_timeout_s: how long the node may take to come up (imports, backend set-up).
        frame_timeout_s: how long one frame may take in lockstep before it counts as missing.
        node_params: further node parameters (``-p``).
        on_image_sent: called ``(stamp ns, wall time ns)`` just before each left image is
            published (the demo plots latency per frame from it).

    Raises:
        OnlineEvalError: the node did not start or exited, or the bag has no ground truth.
        ParamError: ``params`` (with ``params_file``) that the node would refuse.
    """
    bag_path = Path(bag_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    all_params = dict(load_params_file(params_file).values) if params_file else {}
    all_params.update(params or {})
    settings = check_config(RoadbevConfig.from_params(all_params))
    eval_bag = read_eval_bag(bag_path, settings.topics, grid_overrides=grid_fields(all_params))
    grid = eval_bag.grid
    truths = _truths(bag_path, eval_bag)
    left_topic = eval_bag.topics.left_image
    # what a vehicle delivers: no ground truth (a drive's /ground_truth/odom and road map have no
    # subscriber: the replay would wait for one) and no earlier outputs
    input_topics = [t for t in bag.bag_topics(bag_path)
                    if t != eval_bag.topics.ground_truth and not t.startswith(("/ground_truth/", "/roadbev/"))]
    recorded = out_dir / "online.mcap"
    if recorded.exists():
        recorded.unlink()
    extra = {k: v for k, v in all_params.items() if k not in grid.to_dict()}
    extra.update(node_params or {})
    far_grid = None
    # the node's far field as its config reads it (the params file, params and node_params together)
    if eval_bag.far_grid is not None and settings.with_params(dict(node_params or {})).far_field.enabled:
        extra.update(far_field_params(eval_bag))  # the far grid of the bag's truth, as roadbev eval sets it
        far_grid = eval_bag.far_grid
    far_topic = settings.far_field.topic
    if eval_bag.compressed:
        extra["image_transport"] = "compressed"
    if rate is None:
        # Lockstep: the IMU samples after a frame's stamp go out only after its images, and on a
        # loaded machine they can take longer than the default 50 ms to arrive. Waiting for them
        # keeps the node's attitude (slerp between two samples) equal to the offline one.
        extra.setdefault("imu_wait_s", 1.0)
        # and every frame is scored against the offline run: none may be left unpublished for
        # its latency on a busy machine (a real-time replay keeps the node's bound)
        extra.setdefault("max_latency_s", 0.0)
        # nor answered by the pace backend: the replay waits for the node, so its sets arrive as
        # fast as it answers, which its pacer would take for a camera it cannot keep up with
        extra.setdefault("pace_backend", "")
    command = node_command(backend, grid.to_dict(), Path(params_file) if params_file else None, extra)
    log_path = out_dir / "node.log"
    rclpy = init_ros()
    io_node = rclpy.create_node(f"roadbev_online_eval_{os.getpid()}")
    executor = SingleThreadedExecutor()
    executor.add_node(io_node)
    spinning = threading.Event()
    spinning.set()

    def spin() -> None:
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    watcher = _Watcher()
    recorder = Recorder(io_node, recorded, (*OUTPUT_TOPICS, far_topic) if far_grid else OUTPUT_TOPICS,
                        listener=watcher)
    with log_path.open("wb") as log:
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=child_env())
    try:
        deadline = time.monotonic() + startup_timeout_s
        # every scored output subscribed before the first frame goes out (discovery is per topic)
        scored = {ELEVATION_TOPIC, far_topic} if far_grid is not None else {ELEVATION_TOPIC}
        while not scored <= set(recorder.subscribed):
            if proc.poll() is not None:
                raise OnlineEvalError(f"the node exited (code {proc.returncode}): {_tail(log_path)}")
            if time.monotonic() > deadline:
                raise OnlineEvalError(f"the node did not come up in {startup_timeout_s:.0f} s: {_tail(log_path)}")
            time.sleep(0.05)
        images_sent = 0
        last_stamp: int | None = None
        usable = _whole_frames(bag_path, eval_bag)
        sent: dict[int, float] = {}  # stamp -> monotonic time the left image went out
        stop = threading.Event()

        def gate(topic: str, _log_time: int, data: bytes) -> None:
            nonlocal images_sent, last_stamp
            if topic != left_topic:
                return
            # A frame that cannot complete (its other image lost in a damaged or cut bag) gets no
            # answer: lockstep waits only for the frames the bag holds whole.
            if rate is None and images_sent and last_stamp in usable:
                watcher.wait(last_stamp, images_sent, frame_timeout_s)
            if proc.poll() is not None:
                stop.set()
            images_sent += 1
            last_stamp = header_stamp_ns(data)
            sent[last_stamp] = time.monotonic()  # published right after this returns
            if on_image_sent is not None:
                on_image_sent(last_stamp, time.time_ns())

        start = time.monotonic()
        replay_bag(io_node, bag_path, rate=0.0 if rate is None else rate, topics=input_topics,
                   wait_for_subscribers=30.0, stop=stop, before_publish=gate)
        final = max((s for s in sent if s in usable), default=None)
        watcher.wait(final, images_sent, frame_timeout_s if final is not None else 1.0)
        elapsed = time.monotonic() - start
        # one more diagnostics period so the final counts are in
        time.sleep(1.2)
    finally:
        stop_process(proc)
        recorder.close()
        spinning.clear()
        spinner.join(2.0)
        executor.shutdown()
        io_node.destroy_node()
    if proc.returncode not in (0, -signal.SIGINT):
        raise OnlineEvalError(f"the node failed (code {proc.returncode}): {_tail(log_path)}")
    estimates = _estimates(recorded, grid)
    acc = MetricAccumulator(grid)
    calibration = SigmaAccumulator()
    missing = 0
    # The whole frames sent (a frame lost in a damaged bag never reached the node, or only half of
    # it did): with ground truth those that have one, without it all of them.
    frames = sorted(s for s in (truths or sent) if s in sent and s in usable)
    for stamp in frames:
        recorded_map = estimates.get(stamp)
        if recorded_map is None:
            missing += 1
            recorded_map = (np.full(grid.shape, np.nan, np.float32), np.full(grid.shape, np.nan, np.float32))
        if truths:
            elevation, sigma = recorded_map
            acc.add(elevation, truths[stamp])
            calibration.add(elevation, sigma, truths[stamp])
    accuracy = acc.result()
    metrics: dict[str, Any] = {"backend": backend, **accuracy.to_dict(), **calibration.result()}
    if far_grid is not None:
        metrics["far_field"] = _far_scores(recorded, far_topic, far_grid, eval_bag, frames)
    if not truths:
        metrics.update(frames=len(frames), coverage_pct=math.nan)
    answered = len(frames) - missing
    metrics["fps"] = answered / elapsed if elapsed > 0 else math.nan
    metrics["mode"] = "lockstep" if rate is None else f"rate {rate}"
    latencies = [1e3 * (watcher.received[s] - sent[s]) for s in sorted(sent) if s in watcher.received]
    metrics["online"] = {
        "latency_ms": _summary(latencies),
        # without the first answer, which carries the backend's one-time warm-up
        "latency_after_first_ms": _summary(latencies[1:]),
        "latency_on_arrival_ms": _summary(latencies_on_arrival(sent, watcher.received)),
        "frames_published": images_sent,
        "outputs_matched": answered,
        "frames_without_output": missing,
        "wall_s": elapsed,
        "node": dict(watcher.diagnostics),
    }
    if is_drive_bag(bag_path) and frames:
        metrics.update(drive_scores(bag_path, recorded, frames, settings.with_params(grid.to_dict())))
    return OnlineResult(metrics, accuracy, recorded, _tail(log_path, 4000), dict(watcher.diagnostics))


def drive_scores(bag_path: Path, recorded: Path, frame_stamps: Sequence[int], config: RoadbevConfig,
                 lead_time_s: float = 0.1) -> dict[str, Any]:
    """The recorded previews at the wheels' arrival and the recorded fused map against the drive
    bag's truth: the JSON keys ``roadbev eval`` gives offline (``preview_at_arrival``, ``map``).

    Args:
        config: the node's settings on the bag's grid (its ``base_height``, preview, vehicle).
    """
    previews, windows = [], []
    for item in bag.read_messages(recorded, [PREVIEW_TOPIC, MAP_TOPIC]):
        if item.topic == PREVIEW_TOPIC:
            decoded = preview_from_message(item.msg)
            previews.append(TimedPreview(decoded.stamp_ns, decoded.profiles.reference, decoded.profiles))
        else:
            windows.append(map_window_from_message(item.msg))
    out: dict[str, Any] = {}
    if not (previews or windows):
        return out
    truth = read_drive_truth(bag_path, base_frame=config.topics.base_frame, odom_topic=config.topics.odom)
    if previews:
        arrival = score_previews(truth, previews, list(frame_stamps), config, lead_time_s=lead_time_s)
        out["preview_at_arrival"] = json_safe(arrival)
    if windows:
        out["map"] = json_safe(map_accuracy(windows, truth.road_map, truth.trajectory, config.vehicle,
                                                truth.odometry))
    return out


def latencies_on_arrival(sent: Mapping[int, float], received: Mapping[int, float]) -> list[float]:
    """The latency (ms) of every answered frame, in stamp order, less the time it waited for the
    node to finish the frame it answered before: what a frame costs when the node takes it as it
    arrives.

    A node slower than the camera answers a frame only once it is free (its mailbox holds the
    newest set), so the end-to-end latency of such a frame is that wait plus the node's own time.
    The node is taken to be free when the previous answer is received; it is in fact free a few
    milliseconds earlier or later (the answer's transport against the node's own bookkeeping after
    publishing), and the wait is off by as much. Where a model of the node schedules the waits itself
    (:func:`benchmarks.preview_budget.node_schedule`), this is the latency to charge: the
    end-to-end one would count the waits twice.

    Args:
        sent: stamp -> monotonic time (s) the left image was published.
        received: stamp -> monotonic time (s) its answer was received (answered frames only).
    """
    out: list[float] = []
    free = -math.inf
    for stamp in sorted(sent):
        if stamp not in received:
            continue
        wait = max(0.0, free - sent[stamp])
        out.append(1e3 * (received[stamp] - sent[stamp] - wait))
        free = received[stamp]
    return out


def _summary(values: Sequence[float]) -> dict[str, float]:
    """mean, p50, p95 and max of ``values`` (NaN when empty)."""
    if not values:
        return {"mean": math.nan, "p50": math.nan, "p95": math.nan, "max": math.nan, "n": 0}
    arr = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(arr.mean()),
        "p50": float(np.percentile(arr, 50)),
        "p95": float(np.percentile(arr, 95)),
        "max": float(arr.max()),
        "n": len(values),
    }


def _tail(path: Path, n: int = 600) -> str:
    try:
        return path.read_text(errors="replace")[-n:].strip()
    except OSError:
        return ""


def format_online(metrics: Mapping[str, Any]) -> str:
    """One line: the main numbers."""
    online = metrics.get("online", {})
    return (
        f"{metrics['backend']} ({metrics.get('mode')}): frames {metrics['frames']}, abs err "
        f"{metrics['abs_err_cm']:.3f} cm, RMSE {metrics['rmse_cm']:.3f} cm, >0.5 cm "
        f"{metrics['gt_0p5cm_pct']:.1f} %, coverage {metrics['coverage_pct']:.1f} %, "
        f"{metrics['fps']:.2f} fps, missing {online.get('frames_without_output', 0)}"
    )
