"""``roadbev demo``: synthetic drive -> node over ROS 2 -> recorded outputs -> metrics -> report.

Stages (each with a progress bar):

1. **bag**: write (or reuse from the cache) a synthetic evaluation bag with ground truth: a road
   with potholes, speed bumps, ruts and ISO 8608 roughness (:data:`DEMO_ROAD`); or take ``--bag``.
2. **online**: :func:`roadbev_lab.evaluation.online.evaluate_online`: the node runs in its own
   process, the bag is replayed over DDS (loopback, the shipped Fast DDS profile, a private
   ``ROS_DOMAIN_ID``), the outputs are recorded to MCAP and scored against the ground truth.
3. **offline**: the same backend over the same bag without DDS (:func:`roadbev_lab.evaluation.frames.evaluate`,
   exactly what ``roadbev eval`` runs), to show that both agree.
4. **drive** (:mod:`roadbev_lab.demo.drive`): a synthetic drive where the car rides on its road
   (cached too; or ``--bag`` when it is a drive bag) through ``roadbev eval --map`` and
   ``--no-map``'s code: the fused map over the drive, both front wheels' previews at arrival,
   hazards on the fused map and the preview controller's ride (``--no-drive`` leaves it out).
5. **report**: figures and an HTML page (:mod:`roadbev_lab.reports.report`, the drive's
   :mod:`roadbev_lab.reports.drive_report`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from tqdm import tqdm

import roadbev_lab.evaluation.drivebag
import roadbev_lab.evaluation.evalbag
import roadbev_lab.synth
from msg_bridge import bag
from msg_bridge.grid_map import grid_map_to_arrays
from msg_bridge.preview import preview_from_message
from roadbev_core.config import DEFAULT_BACKEND, GridSpec, RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.pipeline import Pipeline, check_config
from roadbev_core.preview import PreviewProfiles, wheel_track_profiles
from roadbev_core.uncertainty import camera_positions
from roadbev_core.visibility import hidden_cells
from roadbev_lab.demo.drive import (
    DEFAULT_DRIVE_FRAMES,
    DRIVE_SEED,
    RIDE_ROWS,
    DriveDemoError,
    DriveSection,
    drive_config,
    features_path,
    run_drive_section,
)
from roadbev_lab.evaluation.drivebag import is_drive_bag, write_drive_bag
from roadbev_lab.evaluation.evalbag import EvalSample, read_eval_bag, write_eval_bag
from roadbev_lab.evaluation.frames import evaluate, to_json
from roadbev_lab.evaluation.metrics import differences
from roadbev_lab.progress import progress_bar
from roadbev_lab.reports.report import FrameView, ReportData, RunSummary, TimingTrace, TrackProfile, write_report
from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RidingConfig, RidingDrive, RoadConfig, SyntheticDrive
from roadbev_ros.dds import init_ros, raise_interrupt

__all__ = [
    "DEFAULT_FRAMES",
    "DEMO_ROAD_FEATURES",
    "DemoError",
    "DemoOptions",
    "DemoResult",
    "demo_drive_config",
    "drive_lines",
    "ensure_demo_bag",
    "pick_frames",
    "run_demo",
    "summary_lines",
]

DEFAULT_FRAMES = 30
DEFAULT_OUT = Path("demo_out")
DEMO_ROAD_FEATURES: tuple[str, ...] = ("pothole", "speed_bump", "rut")
ELEVATION_TOPIC = "/roadbev/elevation"
PREVIEW_TOPIC = "/roadbev/preview"
# Bumped when the demo's bag recipe changes in a way the cache key would not see.
_RECIPE_VERSION = 1


class DemoError(RoadbevError, RuntimeError):
    """A demo stage failed; the message is the one-line reason."""


@dataclass(frozen=True)
class DemoOptions:
    """What ``roadbev demo`` does.

    Attributes:
        frames: frames of the synthetic drive (ignored with ``bag``).
        out_dir: the report folder.
        backend: the node's backend.
        bag: an evaluation bag to use instead of the synthetic drive.
        cache_dir: where synthetic bags are cached (default ``./.cache/roadbev``).
        seed: seed of the synthetic drive.
        image_scale: image size factor of the synthetic drive (tests use small images).
        report_frames: frames shown in the figures.
        progress: show progress bars.
        drive: also the drive section (:mod:`roadbev_lab.demo.drive`): a synthetic drive where
            the car rides on its road (or ``bag`` when it is a drive bag), map on and off.
        drive_frames, drive_seed: that drive's camera frames (10 Hz) and seed.
    """

    frames: int = DEFAULT_FRAMES
    out_dir: Path = DEFAULT_OUT
    backend: str = DEFAULT_BACKEND
    bag: Path | None = None
    cache_dir: Path | None = None
    seed: int = 0
    image_scale: float = 1.0
    report_frames: int = 3
    progress: bool = True
    drive: bool = True
    drive_frames: int = DEFAULT_DRIVE_FRAMES
    drive_seed: int = DRIVE_SEED

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise DemoError(f"--frames must be >= 1, got {self.frames}")
        if self.drive_frames < 5:
            raise DemoError(f"--drive-frames must be >= 5 (0.4 s at 10 Hz), got {self.drive_frames}")
        if not 0 < self.image_scale <= 1.0:
            raise DemoError(f"image scale must be in (0, 1], got {self.image_scale}")
        if self.report_frames < 1:
            raise DemoError(f"report frames must be >= 1, got {self.report_frames}")


@dataclass
class DemoResult:
    """What the demo measured and where it wrote it."""

    bag: Path
    bag_reused: bool
    out_dir: Path
    online: dict[str, Any]
    offline: dict[str, Any]
    agreement: dict[str, float]
    files: dict[str, Path]
    stage_seconds: dict[str, float] = field(default_factory=dict)
    drive: DriveSection | None = None


# --------------------------------------------------------------------------------------------
# stage 1: the bag
# --------------------------------------------------------------------------------------------
def demo_drive_config(frames: int, seed: int = 0, image_scale: float = 1.0) -> DriveConfig:
    """The demo's synthetic drive: ISO 8608 class C roughness plus a pothole, a speed bump and a
    rut repeated every 4 m, 5 m/s, 5 Hz stereo, 100 Hz IMU."""
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class="C", features=DEMO_ROAD_FEATURES, feature_spacing_m=4.0))
    config = DriveConfig(frames=frames, seed=seed, road=road)
    if image_scale != 1.0:
        config = replace(config, camera=config.camera.scaled(image_scale))
    return config


def _source_digest() -> str:
    """Hash of the code that makes a bag (synth + evalbag + drivebag), so a changed renderer
    refreshes the cache."""
    digest = hashlib.sha256()
    synth_dir = Path(roadbev_lab.synth.__file__).parent
    for path in sorted([*synth_dir.glob("*.py"), Path(roadbev_lab.evaluation.evalbag.__file__),
                        Path(roadbev_lab.evaluation.drivebag.__file__)]):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _cache_key(config: DriveConfig | RidingConfig) -> str:
    text = f"{_RECIPE_VERSION}|{config!r}|{_source_digest()}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def ensure_demo_bag(
    config: DriveConfig | RidingConfig, cache_dir: Path, *, progress: Callable[[int], object] | None = None
) -> tuple[Path, bool]:
    """The cached bag for ``config``, written first when missing.

    A :class:`roadbev_lab.synth.DriveConfig` gives an evaluation bag (``demo_*.mcap``), a
    :class:`roadbev_lab.synth.RidingConfig` a drive bag (``drive_*.mcap``, as ``roadbev synth
    --drive``) with the road's true features next to it
    (:func:`roadbev_lab.demo.drive.features_path`). The bag is written under a temporary name and
    renamed when complete, so an interrupted run never leaves a half bag that a later run would reuse.

    Returns:
        (path of the ``.mcap`` bag, whether it was reused).
    """
    cache_dir.mkdir(parents=True, exist_ok=True)
    riding = isinstance(config, RidingConfig)
    drive_of = config.drive if isinstance(config, RidingConfig) else config
    frames, seed = drive_of.frames, drive_of.seed
    path = cache_dir / f"{'drive' if riding else 'demo'}_{frames}f_seed{seed}_{_cache_key(config)}.mcap"
    if path.is_file() and (not riding or features_path(path).is_file()):
        return path, True
    # write_eval_bag writes a single file only for a name ending in .mcap
    partial = cache_dir / f".partial-{os.getpid()}-{path.name}"
    try:
        if isinstance(config, RidingConfig):
            drive = RidingDrive(config)
            write_drive_bag(partial, drive, progress=progress)
            features_path(path).write_text(json.dumps([[f[0], float(f[1]), float(f[2]), float(f[3])]
                                                       for f in drive.features_in_odom()]))
        else:
            write_eval_bag(partial, SyntheticDrive(config), progress=progress)
        partial.replace(path)
    finally:
        if partial.exists():
            partial.unlink() if partial.is_file() else shutil.rmtree(partial)
    return path, False


# --------------------------------------------------------------------------------------------
# stage 2: online (ROS 2)
# --------------------------------------------------------------------------------------------
def _private_domain() -> None:
    """A private DDS domain on loopback unless the user chose one (before rclpy is imported)."""
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@contextmanager
def _interruptible_ros() -> Iterator[None]:
    """rclpy initialised without its own signal handlers, SIGTERM turned into KeyboardInterrupt.

    rclpy's SIGINT handler shuts the context down from under the online evaluation's threads
    and the demo would carry on; with Python's handlers Ctrl-C raises KeyboardInterrupt in the
    main thread, the evaluation's ``finally`` stops the node process and closes the recording,
    and the CLI exits 130. rclpy is shut down at the end only when it was initialised here.
    """
    # rclpy only after _private_domain() chose the DDS domain (run_demo calls it first)
    import rclpy

    owned = not rclpy.ok()
    init_ros(handle_signals=False)
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, raise_interrupt) if in_main else None
    try:
        yield
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)
        if owned:
            rclpy.try_shutdown()


def _node_failure(metrics: dict[str, Any], log_tail: str) -> str | None:
    """A one-line reason when the node answered no frame at all, else None."""
    online = metrics.get("online", {})
    if online.get("outputs_matched", 1) == 0:
        tail = " | ".join(line.strip() for line in log_tail.strip().splitlines()[-6:] if line.strip())
        sent = online.get("frames_published", 0)
        return f"the node produced no output for any of {sent} frames; node log: {tail or '(empty)'}"
    return None


# --------------------------------------------------------------------------------------------
# recorded outputs
# --------------------------------------------------------------------------------------------
@dataclass
class _Recorded:
    elevation: dict[int, np.ndarray]
    sigma: dict[int, np.ndarray]  # the maps' uncertainty layer, where they have one
    receive_ns: dict[int, int]
    previews: dict[int, PreviewProfiles]  # by stamp


def _read_recorded(path: Path, grid: GridSpec) -> _Recorded:
    out = _Recorded({}, {}, {}, {})
    for item in bag.read_messages(path, [ELEVATION_TOPIC, PREVIEW_TOPIC], on_damage="skip"):
        if item.topic == ELEVATION_TOPIC:
            decoded = grid_map_to_arrays(item.msg, base=grid)
            out.elevation[decoded.stamp_ns] = np.asarray(decoded.layers["elevation"], dtype=np.float32)
            if "uncertainty" in decoded.layers:
                out.sigma[decoded.stamp_ns] = np.asarray(decoded.layers["uncertainty"], dtype=np.float32)
            out.receive_ns.setdefault(decoded.stamp_ns, item.log_time_ns)
        else:
            preview = preview_from_message(item.msg)
            out.previews[preview.stamp_ns] = preview.profiles
    return out


def _profiles_to_report(profiles: PreviewProfiles) -> tuple[TrackProfile, ...]:
    distance = profiles.distances()
    return tuple(
        TrackProfile(t.name, float(t.lateral_offset), distance, np.asarray(t.elevation, np.float64),
                     np.asarray(t.uncertainty, np.float64))
        for t in profiles.tracks
    )


def _truth_profiles(truth: np.ndarray, grid: GridSpec, like: PreviewProfiles, hidden: np.ndarray | None = None
                    ) -> tuple[TrackProfile, ...]:
    """Ground-truth wheel-track profiles with the recorded preview's tracks, width and spacing;
    with ``hidden`` [R, C] (cells the truth hides from the cameras) each sample also says whether
    any cell of its tyre footprint is hidden."""
    def profiles(layer: np.ndarray) -> tuple[TrackProfile, ...]:
        return _profiles_to_report(wheel_track_profiles(
            layer, None, grid,
            track_offsets_m=[t.lateral_offset for t in like.tracks],
            track_names=[t.name for t in like.tracks],
            tyre_width_m=float(like.tracks[0].width),
            spacing_m=float(like.spacing),
            max_distance_m=float(like.distances()[-1]) if like.n_samples else None,
        ))

    gt = profiles(truth)
    if hidden is None:
        return tuple(replace(p, sigma_m=None) for p in gt)
    # the same footprints over the hidden mask: the share of each footprint that is hidden
    shares = profiles(np.asarray(hidden, np.float64))
    return tuple(replace(p, sigma_m=None, hidden=np.nan_to_num(h.elevation_m) > 0.0)
                 for p, h in zip(gt, shares, strict=True))


def pick_frames(truths: Sequence[np.ndarray | None], count: int) -> list[int]:
    """Indices of up to ``count`` frames with the most relief in their ground truth, spread over
    the drive (at least ``len / (2 count)`` frames apart), in drive order."""
    n = len(truths)
    if n == 0:
        return []

    def relief(t: np.ndarray | None) -> float:
        if t is None or not np.isfinite(t).any():
            return -1.0
        lo, hi = np.nanpercentile(t, [0.5, 99.5])
        return float(hi - lo)

    order = sorted(range(n), key=lambda i: -relief(truths[i]))
    gap = max(1, n // (2 * count))
    chosen: list[int] = []
    for i in order:
        if all(abs(i - j) >= gap for j in chosen):
            chosen.append(i)
        if len(chosen) == count:
            break
    return sorted(chosen)


# --------------------------------------------------------------------------------------------
# the whole demo
# --------------------------------------------------------------------------------------------
def _bar(total: int | None, desc: str, enabled: bool, unit: str = "frame") -> tqdm[NoReturn]:
    return progress_bar(total=total, desc=f"{desc:<8}", unit=unit, disable=not enabled)


def _cached_bag(config: DriveConfig | RidingConfig, frames: int, label: str, options: DemoOptions
                ) -> tuple[Path, bool]:
    """:func:`ensure_demo_bag` in the options' cache folder behind a progress bar labelled ``label``."""
    cache = Path(options.cache_dir) if options.cache_dir else Path(".cache") / "roadbev"
    with _bar(frames, label, options.progress) as bar:
        try:
            path, reused = ensure_demo_bag(config, cache, progress=bar.update)
        except (ValueError, OSError) as exc:
            raise DemoError(f"writing the synthetic {label} failed: {exc}") from exc
        if reused:
            bar.update(frames - bar.n)
            bar.set_postfix_str("cached")
    return path, reused


def _agreement_note(agreement: dict[str, float], online: dict[str, Any]) -> str:
    missing = online.get("online", {}).get("frames_without_output", 0)
    worst = max((v for k, v in agreement.items() if k.endswith("_cm") and math.isfinite(v)), default=math.nan)
    if missing:
        return (f"Online and offline differ: {missing} frame(s) got no output over ROS 2 and count as "
                f"missing (coverage); the largest difference in a cm metric is {worst:.4f} cm.")
    if agreement.get("cells", 0) == 0 and math.isfinite(worst) and worst < 1e-6:
        return ("The ROS 2 run (node process, DDS, recorded MCAP) and the offline evaluation "
                "(`roadbev eval`, no DDS) agree: same frames, same cells compared, every metric equal "
                f"to within {worst:.1e} cm (float rounding). Lockstep replay means the node processes "
                "every frame, with the same backend code on the same images and attitude; the "
                "elevation map travels as float32 both ways.")
    return (f"The ROS 2 run and the offline evaluation differ by up to {worst:.4f} cm and "
            f"{agreement.get('cells', math.nan):.0f} cells: the node sees the attitude from its own IMU "
            "buffer and synchroniser, the offline path from the bag reader's interpolation.")


def run_demo(options: DemoOptions, *, log: Callable[[str], Any] = print) -> DemoResult:
    """Run every stage and write the report; see the module docstring.

    Raises:
        DemoError: a stage failed (the message says which and why).
    """
    _private_domain()
    stage_s: dict[str, float] = {}
    out_dir = Path(options.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    # 1. bag
    t0 = time.monotonic()
    if options.bag is not None:
        bag_path = Path(options.bag)
        if not bag_path.exists():
            raise DemoError(f"bag not found: {bag_path}")
        reused = True
    else:
        config = demo_drive_config(options.frames, options.seed, options.image_scale)
        bag_path, reused = _cached_bag(config, options.frames, "bag", options)
    stage_s["bag"] = time.monotonic() - t0

    try:
        eval_bag = read_eval_bag(bag_path)
    except Exception as exc:  # a damaged or foreign bag: one line
        raise DemoError(f"cannot read bag {bag_path}: {type(exc).__name__}: {exc}") from exc
    grid = eval_bag.grid
    n_frames = len(eval_bag)
    losses = eval_bag.losses()  # a truncated or damaged bag: every readable frame, the rest counted
    for line in losses:
        log(f"lost: {line}")
    if n_frames == 0:
        raise DemoError(f"bag {bag_path} has no complete frames")

    # 2. online over ROS 2 (rclpy, which the online evaluation loads, only after _private_domain())
    from roadbev_lab.evaluation.online import OnlineEvalError, evaluate_online

    t0 = time.monotonic()
    sent_ns: dict[int, int] = {}
    with _bar(n_frames, "ROS 2", options.progress) as bar:
        def on_image(stamp: int, now_ns: int) -> None:
            sent_ns.setdefault(stamp, now_ns)
            bar.update(1)

        try:
            with _interruptible_ros():
                result = evaluate_online(bag_path, out_dir, backend=options.backend, on_image_sent=on_image)
        except OnlineEvalError as exc:
            raise DemoError(f"ROS 2 stage failed: {' '.join(str(exc).split())}") from exc
    reason = _node_failure(result.metrics, result.node_log)
    if reason:
        raise DemoError(reason)
    online = result.metrics
    stage_s["ROS 2 (node, replay, record)"] = time.monotonic() - t0

    # 3. offline, exactly as `roadbev eval`
    t0 = time.monotonic()
    truths: list[np.ndarray | None] = []
    stamps: list[int] = []

    def keep(samples: Iterable[EvalSample]) -> Iterator[EvalSample]:
        for sample in samples:
            truths.append(sample.truth)
            stamps.append(sample.inputs.stamp_ns)
            yield sample

    pipeline = Pipeline(check_config(RoadbevConfig.from_params({"backend": options.backend, **grid.to_dict()})))
    with _bar(n_frames, "offline", options.progress) as bar:
        offline_result = evaluate(pipeline, keep(eval_bag), imu=eval_bag.imu, progress=bar.update, keep_estimates=True)
    offline = offline_result.to_dict()
    frames = {o.frame.stamp_ns: o.frame for o in offline_result.outputs or []}
    stage_s["offline eval"] = time.monotonic() - t0

    # 4. the drive: map on and off, previews at arrival, hazards, ride
    drive, drive_note = _drive_stage(options, bag_path, stage_s)
    if drive is not None and drive.bag == bag_path and "preview_at_arrival" in result.metrics:
        drive.online = {k: result.metrics[k] for k in ("preview_at_arrival", "map") if k in result.metrics}

    # 5. report
    t0 = time.monotonic()
    recorded = _read_recorded(result.recorded, grid)
    shown = pick_frames(truths, options.report_frames)
    views = []
    for i in shown:
        frame = frames.get(stamps[i])
        if frame is None:  # refused by the pipeline offline
            continue
        estimate = recorded.elevation.get(frame.stamp_ns)
        if estimate is None:
            continue
        preview = recorded.previews.get(frame.stamp_ns)
        truth = truths[i]
        tracks: tuple[TrackProfile, ...] = _profiles_to_report(preview) if preview is not None else ()
        # what the ground truth hides from the backend's cameras: no estimator sees these cells
        hidden = None if truth is None else hidden_cells(
            truth, grid, camera_positions(frame, pipeline.backend.needs_stereo), clearance=0.0)
        truth_tracks: tuple[TrackProfile, ...] = ()
        if preview is not None and truth is not None:
            truth_tracks = _truth_profiles(truth, grid, preview, hidden)
        views.append(FrameView(i, frame.stamp_ns, frame.left, frame.camera, frame.attitude, truths[i],
                               estimate, tracks, truth_tracks, recorded.sigma.get(frame.stamp_ns), hidden))
    if not views:
        raise DemoError("no recorded elevation map matches a frame of the bag: nothing to show")
    stamps = sorted(s for s in sent_ns if s in recorded.receive_ns)
    timing = None
    if stamps:
        first_sent = min(sent_ns.values())
        timing = TimingTrace(
            stamp_s=np.array([(s - stamps[0]) * 1e-9 for s in stamps]),
            latency_ms=np.array([(recorded.receive_ns[s] - sent_ns[s]) * 1e-6 for s in stamps]),
            receive_s=np.array([(recorded.receive_ns[s] - first_sent) * 1e-9 for s in stamps]),
        )
        online = {**online, "latency_ms_median": float(np.median(timing.latency_ms))}
    agreement = differences(result.accuracy, offline_result.accuracy)
    runs = [
        RunSummary(f"{options.backend} · ROS 2 node (recorded)", options.backend, "online", online),
        RunSummary(f"{options.backend} · offline (roadbev eval)", options.backend, "offline", offline),
    ]
    notes = [
        _agreement_note(agreement, online),
        "Rate: ROS 2 row = outputs per second end to end in lockstep (each image is sent when the "
        "previous answer arrived, so every frame is processed); offline row = backend pipeline "
        "frames per second on this machine without DDS.",
        f"Offline check: roadbev eval {bag_path} --backend {options.backend}",
        *(f"Lost from the bag: {line}" for line in eval_bag.losses()),
        *([drive_note] if drive_note else []),
    ]
    if not any(t is not None for t in truths):
        notes.insert(0, "The bag has no ground truth: nothing to score. The figures show what the node made "
                        "of the drive (maps, previews, timing); the error columns stay empty.")
    settings = {
        "bag": str(bag_path) + (" (cached)" if reused and options.bag is None else ""),
        "frames": n_frames,
        "backend": options.backend,
        "grid": f"{grid.n_rows} x {grid.n_cols} cells of {grid.resolution * 100:.0f} cm, "
                f"x {grid.x_min}..{grid.x_max} m, y {grid.y_min}..{grid.y_max} m",
        "camera": f"{eval_bag.camera.width} x {eval_bag.camera.height}",
        "ROS_DOMAIN_ID": os.environ.get("ROS_DOMAIN_ID", ""),
        "recorded outputs": result.recorded.name,
        "node log": "node.log",
    }
    data = ReportData(f"RoadBEV demo: {options.backend} over ROS 2", grid, runs, views, timing, notes,
                      settings, stage_s, drive)
    with _bar(None, "report", options.progress, unit="file") as bar:
        bar.unit = "figure"

        def figure_written(name: str) -> None:
            bar.update(1)
            bar.set_postfix_str(name)

        files = write_report(data, out_dir, progress=figure_written)
    stage_s["report"] = time.monotonic() - t0
    # the stage times in the JSON include the report's own
    report_json = files["report.json"]
    payload = json.loads(report_json.read_text())
    payload["stage_seconds"] = stage_s
    payload["agreement"] = dict(agreement)
    payload["bag"] = str(bag_path)
    payload["lost_frames"] = eval_bag.lost_frames()
    payload["losses"] = eval_bag.losses()
    report_json.write_text(to_json(payload))
    return DemoResult(bag_path, reused, out_dir, online, offline, agreement, files, stage_s, drive)


def _drive_stage(options: DemoOptions, bag_path: Path, stage_s: dict[str, float]) -> tuple[DriveSection | None, str]:
    """The drive section (or None and the reason it was left out)."""
    if not options.drive:
        return None, ""
    t0 = time.monotonic()
    seed: int | None = None
    if options.bag is not None:
        if not is_drive_bag(bag_path):
            return None, (f"No drive section: {bag_path} is not a drive bag (no /ground_truth/odom and "
                          "/ground_truth/road_map); `roadbev synth --drive` writes one.")
        path, reused = bag_path, True
    else:
        seed = options.drive_seed
        config = drive_config(options.drive_frames, seed, options.image_scale)
        path, reused = _cached_bag(config, options.drive_frames, "drive", options)
    stage_s["drive bag"] = time.monotonic() - t0

    def bar_for(total: int, label: str) -> tqdm[NoReturn]:
        return _bar(total, label, options.progress)

    try:
        section = run_drive_section(path, backend=options.backend, reused=reused, seed=seed, bar=bar_for)
    except DriveDemoError as exc:
        if options.bag is not None:  # the user's drive bag cannot be scored (no ground truth...): say so
            return None, f"No drive section: {exc}"
        raise DemoError(str(exc)) from exc
    stage_s.update(section.seconds)
    return section, ""


def summary_lines(result: DemoResult) -> list[str]:
    """The short terminal summary: metrics, rate, latency, agreement, where the report is."""
    on, off = result.online, result.offline
    lat = on.get("online", {}).get("latency_after_first_ms", {})
    lines = [
        f"{'':<22}{'frames':>7}{'abs.err cm':>12}{'RMSE cm':>9}{'>0.5cm %':>10}{'coverage %':>12}{'rate Hz':>9}"
        f"{'in 2sigma %':>13}{'conf.wrong %':>14}",
    ]
    for label, m in (("ROS 2 node (recorded)", on), ("offline (roadbev eval)", off)):
        lines.append(
            f"{label:<22}{m['frames']:>7}{_num(m.get('abs_err_cm'), 3):>12}{_num(m.get('rmse_cm'), 3):>9}"
            f"{_num(m.get('gt_0p5cm_pct'), 1):>10}{_num(m.get('coverage_pct'), 1):>12}{_num(m.get('fps'), 1):>9}"
            f"{_num(m.get('within_2sigma_pct'), 1):>13}{_num(m.get('confident_wrong_pct'), 2):>14}"
        )
    worst = max((v for k, v in result.agreement.items() if k.endswith("cm") and math.isfinite(v)), default=math.nan)
    lines.append(
        f"latency (image published -> map received): median {_num(lat.get('p50'), 0)} ms, "
        f"p95 {_num(lat.get('p95'), 0)} ms (after the first frame); online vs offline: max |diff| {worst:.1e} cm"
    )
    if result.drive is not None:
        lines.extend(drive_lines(result.drive))
    lines.append(f"report: {(result.out_dir / 'index.html').resolve()}")
    return lines


def drive_lines(drive: DriveSection) -> list[str]:
    """The drive section in three lines: previews at arrival map on / off, hazards, the ride."""
    on, off = drive.map_on["preview_at_arrival"], drive.map_off["preview_at_arrival"]
    fused = drive.map_on.get("map") or {}
    where = f"seed {drive.seed}" if drive.seed is not None else str(drive.bag)
    rows, share = drive.ride["rows"], drive.ride["share"]
    found = sum(d is not None for _, d in drive.matches)
    return [
        f"drive ({where}, {drive.map_on['frames']} frames): preview at arrival map on / off: abs. error "
        f"{_num(on['abs_err_cm'], 3)} / {_num(off['abs_err_cm'], 3)} cm, features {_num(on['features_abs_err_cm'], 3)}"
        f" / {_num(off['features_abs_err_cm'], 3)} cm, coverage {_num(on['coverage_pct'], 1)} / "
        f"{_num(off['coverage_pct'], 1)} %; fused map {_num(fused.get('abs_err_cm'), 3)} cm",
        f"drive hazards on the fused map: {found} of {len(drive.matches)} features >= 3 cm found, "
        f"{len(drive.false_alarms)} false alarm(s)",
        "drive ride, Wk RMS m/s^2: " + ", ".join(
            f"{label.split(' (')[0]} {rows[k]['mean']['wk_rms_mps2']:.3f}"
            + (f" ({share[k]:.2f} of gain)" if k in ("per_frame", "fused") and math.isfinite(share[k]) else "")
            for k, label in RIDE_ROWS if k in rows),
    ]


def _num(value: Any, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{float(value):.{digits}f}"
