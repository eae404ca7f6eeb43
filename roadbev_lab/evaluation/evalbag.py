"""Evaluation bags (docs/interface/bags.md, "Evaluation bags"): a drive with ground truth, as rosbag2 MCAP.

Topics written by :func:`write_eval_bag` (the interface's defaults):

=====================================  ==============================  ==========================
topic                                  type                            per
=====================================  ==============================  ==========================
/stereo/left/image_rect                sensor_msgs/Image (rgb8)        frame
/stereo/right/image_rect               sensor_msgs/Image (rgb8)        frame
/stereo/left/camera_info               sensor_msgs/CameraInfo          frame (stamped like it)
/stereo/right/camera_info              sensor_msgs/CameraInfo          frame
/imu/data                              sensor_msgs/Imu                 IMU sample (100 Hz)
/ground_truth/elevation                grid_map_msgs/GridMap           frame (layer elevation)
/ground_truth/elevation_far            grid_map_msgs/GridMap           frame, with a far field
/roadbev/grid_config                   std_msgs/String (JSON)          once, latched
=====================================  ==============================  ==========================

The sensor topics are the node's (:class:`roadbev_core.config.TopicsConfig`, its defaults when
writing); ``/ground_truth/elevation``, ``/roadbev/grid_config`` and ``/tf_static`` are the bag's
own (:class:`BagTopics`).

With ``compressed=True`` the images are ``.../image_rect/compressed`` (sensor_msgs/CompressedImage,
jpeg).

``/roadbev/grid_config`` is a transient-local ("latched") message written first: JSON with the
``grid`` (every :class:`GridSpec` field), the ``camera`` (:class:`StereoCamera`) and the
``drive`` settings that made the bag; a drive with a far-field grid (``DriveConfig.far_grid``)
adds ``far_grid`` and the truth on it, ``/ground_truth/elevation_far`` (a bag without one is
written as before the far field existed). Every message's log time is its header stamp, so a bag is
a pure function of the drive (byte-identical when regenerated).

:func:`read_eval_bag` reads such bags and bags from elsewhere: it pairs left/right images and
CameraInfos by exact stamp, collects the IMU orientations (the attitude at an image stamp is
:class:`roadbev_core.attitude.ImuBuffer`'s, as in the node: :func:`roadbev_core.pipeline.replay`
feeds them to the pipeline in time order), and takes the horizontal grid from the ground-truth
GridMap's ``info``. ``base_height`` and the vertical fields come from the grid parameters the
user gave (:func:`grid_fields`), else from ``/roadbev/grid_config``, else the interface's defaults.
The far-field truth's grid comes from its own GridMap's ``info`` likewise (its vertical range from
the bag's ``far_grid``, else the ``far_field`` defaults).

A truncated, unfinished or partly damaged bag gives every frame that is readable: damaged chunks
are skipped (:func:`msg_bridge.bag.read_messages` with ``on_damage="skip"``), an image that does
not decode is a lost frame, and :meth:`EvalBag.losses` says how many frames were lost and why.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from msg_bridge._common import MessageError, TypestoreFactory, stamp_from_header
from msg_bridge.bag import BagError, BagWriter, ReadStats, bag_topics, read_messages, typestore
from msg_bridge.camera_info import camera_info_from_stereo, stereo_camera_from_camera_info
from msg_bridge.grid_map import ROAD_FRAME, grid_map_message, grid_map_to_arrays
from msg_bridge.image import array_to_compressed, array_to_image, compressed_to_rgb, image_to_rgb
from msg_bridge.imu import imu_message, imu_orientation
from msg_bridge.pipeline_io import odometry_sample
from msg_bridge.tf import StaticTransform, camera_mount, transforms_from_tf
from roadbev_core.attitude import ImuBuffer, ImuSample, ImuStale, imu_buffer
from roadbev_core.config import (
    GRID_PARAMS,
    ConfigError,
    FarFieldConfig,
    GridSpec,
    ImuConfig,
    StereoCamera,
    TopicsConfig,
)
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.frame import Frame
from roadbev_core.pipeline import CameraInput

__all__ = [
    "FAR_GROUND_TRUTH_TOPIC",
    "GRID_CONFIG_TOPIC",
    "GROUND_TRUTH_TOPIC",
    "TF_STATIC_TOPIC",
    "BagTopics",
    "EvalBag",
    "EvalSample",
    "ExtraTopics",
    "LabelledFrame",
    "bag_frames",
    "grid_fields",
    "read_eval_bag",
    "write_eval_bag",
]

# The evaluation bag's own topics (docs/interface/bags.md, "Evaluation bags"); the sensor topics are the node's.
GROUND_TRUTH_TOPIC = "/ground_truth/elevation"
FAR_GROUND_TRUTH_TOPIC = "/ground_truth/elevation_far"
GRID_CONFIG_TOPIC = "/roadbev/grid_config"
TF_STATIC_TOPIC = "/tf_static"
COMPRESSED = "/compressed"
LEFT_FRAME = "stereo_left_optical_frame"
RIGHT_FRAME = "stereo_right_optical_frame"
IMU_FRAME = "imu_link"
# Grid fields that do not come from the GridMap info.
_VERTICAL_FIELDS = ("base_height", "z_min", "z_max", "z_resolution", "class_resolution")
_HORIZONTAL_FIELDS = ("x_min", "x_max", "y_min", "y_max", "resolution")


@dataclasses.dataclass(frozen=True)
class BagTopics:
    """The topics an evaluation bag is read from (or written to): the node's sensor topics
    (:class:`roadbev_core.config.TopicsConfig`; the images' with ``/compressed`` when the bag
    carries them so) and the bag's own."""

    left_image: str
    right_image: str
    left_info: str
    right_info: str
    imu: str
    odom: str
    ground_truth: str = GROUND_TRUTH_TOPIC
    grid_config: str = GRID_CONFIG_TOPIC
    tf_static: str = TF_STATIC_TOPIC
    ground_truth_far: str = FAR_GROUND_TRUTH_TOPIC

    @classmethod
    def of(cls, topics: TopicsConfig, *, compressed: bool = False) -> BagTopics:
        """The bag topics of the node's ``topics`` (image topics with ``/compressed`` when
        ``compressed``)."""
        suffix = COMPRESSED if compressed else ""
        return cls(topics.left_image + suffix, topics.right_image + suffix, topics.left_info, topics.right_info,
                   topics.imu, topics.odom)

    def names(self) -> list[str]:
        """Every topic, in field order."""
        return [str(value) for value in dataclasses.astuple(self)]


def _jsonable(value: object) -> object:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value) if f.compare}
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def write_eval_bag(
    path: str | os.PathLike[str],
    drive: Any,
    *,
    compressed: bool = False,
    compression: str = "zstd",
    jpeg_quality: int = 90,
    progress: Callable[[int], object] | None = None,
    extra: ExtraTopics | None = None,
) -> dict[str, int]:
    """Write a synthetic drive as an evaluation bag.

    Args:
        path: ``*.mcap`` (single file) or a rosbag2 directory to create; must not exist.
        drive: a :class:`roadbev_lab.synth.SyntheticDrive` (iterates ``DriveSample``s with
            ``frame``, ``truth`` and ``far_truth``; ``imu_samples()``; ``config`` with the grid and
            the ``far_grid``, None without a far field).
        compressed: JPEG ``CompressedImage`` on ``.../image_rect/compressed`` instead of rgb8.
        compression: "zstd" (MCAP chunk compression) or "none".
        jpeg_quality: JPEG quality when ``compressed``.
        progress: called with 1 after each frame (e.g. ``tqdm.update``).
        extra: more topics, written in time order with the rest (a drive bag's odometry, TF
            and road map: :mod:`roadbev_lab.evaluation.drivebag`).

    Returns:
        Messages written per topic.
    """
    config = getattr(drive, "config", None)
    grid: GridSpec = getattr(config, "grid", None) or GridSpec()
    far_grid: GridSpec | None = getattr(config, "far_grid", None)
    factory = TypestoreFactory(typestore())
    imu = sorted(drive.imu_samples(), key=lambda s: s.stamp_ns)
    t = BagTopics.of(TopicsConfig(), compressed=compressed)
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"

    def to_image(pixels: np.ndarray, stamp_ns: int, frame_id: str) -> object:
        if compressed:
            return array_to_compressed(
                pixels, factory, stamp_ns=stamp_ns, frame_id=frame_id, jpeg_quality=jpeg_quality
            )
        return array_to_image(pixels, factory, stamp_ns=stamp_ns, frame_id=frame_id)

    with BagWriter(path, compression=compression) as bag:
        bag.add_topic(t.grid_config, "std_msgs/msg/String", latched=True)
        bag.add_topic(t.left_image, image_type)
        bag.add_topic(t.right_image, image_type)
        bag.add_topic(t.left_info, "sensor_msgs/msg/CameraInfo")
        bag.add_topic(t.right_info, "sensor_msgs/msg/CameraInfo")
        bag.add_topic(t.imu, "sensor_msgs/msg/Imu")
        bag.add_topic(t.ground_truth, "grid_map_msgs/msg/GridMap")
        if far_grid is not None:
            bag.add_topic(t.ground_truth_far, "grid_map_msgs/msg/GridMap")
        if extra is not None:
            extra.add_topics(bag)
        next_imu = 0

        def write_imu_until(stamp_ns: int) -> None:
            nonlocal next_imu
            if extra is not None:
                extra.write_until(bag, factory, stamp_ns)
            while next_imu < len(imu) and imu[next_imu].stamp_ns <= stamp_ns:
                s = imu[next_imu]
                msg = imu_message(
                    factory,
                    stamp_ns=s.stamp_ns,
                    orientation_xyzw=s.orientation_xyzw,
                    angular_velocity=s.angular_velocity,
                    linear_acceleration=s.linear_acceleration,
                    frame_id=IMU_FRAME,
                )
                bag.write(t.imu, msg, s.stamp_ns)
                next_imu += 1

        config_written = False
        for sample in drive:
            frame = sample.frame
            stamp = int(frame.stamp_ns)
            if not config_written:
                first = min(stamp, imu[0].stamp_ns) if imu else stamp
                settings = _jsonable(config)
                if isinstance(settings, dict) and settings.get("far_grid", 0) is None:
                    del settings["far_grid"]  # without a far field the bag reads as before there was one
                described = {
                    "grid": grid.to_dict(),
                    "camera": frame.camera.to_dict(),
                    "drive": settings,
                    "frame_ids": {"left": LEFT_FRAME, "right": RIGHT_FRAME, "imu": IMU_FRAME},
                }
                if far_grid is not None:
                    described["far_grid"] = far_grid.to_dict()
                text = json.dumps(described, sort_keys=True)
                bag.write(t.grid_config, factory.new("std_msgs/msg/String", data=text), first)
                config_written = True
            write_imu_until(stamp)
            bag.write(t.left_image, to_image(frame.left, stamp, LEFT_FRAME), stamp)
            if frame.right is not None:
                bag.write(t.right_image, to_image(frame.right, stamp, RIGHT_FRAME), stamp)
            bag.write(
                t.left_info,
                camera_info_from_stereo(frame.camera, factory, stamp_ns=stamp, frame_id=LEFT_FRAME),
                stamp,
            )
            if frame.right is not None:
                info = camera_info_from_stereo(
                    frame.camera, factory, right=True, stamp_ns=stamp, frame_id=RIGHT_FRAME
                )
                bag.write(t.right_info, info, stamp)
            truth = sample.truth.elevation if hasattr(sample.truth, "elevation") else sample.truth
            gt = grid_map_message({"elevation": truth}, grid, factory, stamp_ns=stamp, frame_id=ROAD_FRAME)
            bag.write(t.ground_truth, gt, stamp)
            far_truth = getattr(sample, "far_truth", None)
            if far_grid is not None and far_truth is not None:
                far = grid_map_message({"elevation": far_truth.elevation}, far_grid, factory, stamp_ns=stamp,
                                       frame_id=ROAD_FRAME)
                bag.write(t.ground_truth_far, far, stamp)
            if progress is not None:
                progress(1)
        write_imu_until(2**63 - 1)
        return dict(bag.counts)


class ExtraTopics(Protocol):
    """Topics :func:`write_eval_bag` interleaves with its own, in time order."""

    def add_topics(self, bag: BagWriter) -> None:
        """Declare the topics (``bag.add_topic``)."""
        ...

    def write_until(self, bag: BagWriter, factory: TypestoreFactory, stamp_ns: int) -> None:
        """Write every message stamped at or before ``stamp_ns`` not written yet."""
        ...


class EvalSample(NamedTuple):
    """One camera set of an evaluation bag and its ground truth ([n_rows, n_cols] metres or None),
    and the truth on the far-field grid (None without one)."""

    inputs: CameraInput
    truth: np.ndarray | None
    far_truth: np.ndarray | None = None


class LabelledFrame(NamedTuple):
    """A frame with its attitude and its ground truth (training data)."""

    frame: Frame
    truth: np.ndarray | None


class _FrameIndex(NamedTuple):
    stamp_ns: int
    camera: StereoCamera


class EvalBag:
    """An evaluation bag, indexed: ``len(bag)`` camera sets, iterating :class:`EvalSample`.

    Attributes:
        path: the bag.
        grid: the evaluation grid (horizontal from the ground truth's info).
        far_grid: the far-field grid of ``/ground_truth/elevation_far`` (None without it).
        camera: the rig of the first frame.
        stereo: whether the bag has right images.
        imu: the IMU orientations in stamp order (for :func:`roadbev_core.pipeline.replay`).
        odometry: ``base_link`` poses from ``odom_topic`` in stamp order (the map's ego-motion).
        camera_frame: the left images' ``header.frame_id``.
        camera_mount: ``base_link`` -> that frame from ``/tf_static`` (position [3], R [3, 3]
            optical -> base_link), or None.
        topics: the topics actually read (image topics with ``/compressed``).
        skipped: reason -> number of left images that could not become camera sets (while
            iterating, also images that do not decode or do not fit the camera).
        notes: remarks on how the bag was interpreted.
        read_stats: what reading the bag delivered and lost (damaged or cut chunks).
    """

    def __init__(
        self,
        path: Path,
        grid: GridSpec,
        frames: list[_FrameIndex],
        truths: dict[int, np.ndarray],
        imu: list[ImuSample],
        topics: BagTopics,
        compressed: bool,
        stereo: bool,
        skipped: dict[str, int],
        notes: list[str],
        read_stats: ReadStats | None = None,
    ) -> None:
        self.path = path
        self.grid = grid
        self._frames = frames
        self._truths = truths
        self.imu = imu
        self.topics = topics
        self.compressed = compressed
        self.stereo = stereo
        self.skipped = skipped
        self.notes = notes
        self.read_stats = read_stats if read_stats is not None else ReadStats()
        self.odometry: list[PlanarPose] = []
        self.camera_frame = LEFT_FRAME
        self.camera_mount: tuple[np.ndarray, np.ndarray] | None = None
        self.far_grid: GridSpec | None = None
        self._far_truths: dict[int, np.ndarray] = {}

    def lost_frames(self) -> int:
        """Frames of the bag that cannot be evaluated: incomplete or undecodable ones, and left
        images lost in damaged chunks (frames after a cut are not known, so not counted)."""
        return sum(self.skipped.values()) + self.read_stats.lost.get(self.topics.left_image, 0)

    def losses(self) -> list[str]:
        """Lines saying how many frames were lost and why (empty for a whole, sound bag)."""
        lines = [f"{n} frame(s) lost: {reason}" for reason, n in sorted(self.skipped.items())]
        left = self.read_stats.lost.get(self.topics.left_image, 0)
        if left:
            lines.append(f"{left} frame(s) lost: their left image is in a damaged part of the bag")
        lines += [f"bag: {line}" for line in self.read_stats.damage]
        if self.read_stats.lost_unknown:
            lines.append("bag: it breaks off; frames after the cut are unknown")
        elif self.read_stats.unfinished:
            lines.append("bag: not closed cleanly (no summary); read to its last complete chunk")
        if self.read_stats.unverified_chunks:
            lines.append(f"bag: {self.read_stats.unverified_chunks} chunk(s) carry no CRC (an older writer): damage "
                         "inside them cannot be detected; `roadbev bag recover` writes a copy with CRCs")
        return lines

    @property
    def camera(self) -> StereoCamera:
        if not self._frames:
            raise BagError(f"{self.path}: no usable frames")
        return self._frames[0].camera

    @property
    def stamps(self) -> list[int]:
        return [f.stamp_ns for f in self._frames]

    def far_truth(self, stamp_ns: int) -> np.ndarray | None:
        """[R, C] the far-field truth at ``stamp_ns`` on :attr:`far_grid` (None: none there)."""
        return self._far_truths.get(int(stamp_ns))

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self) -> Iterator[EvalSample]:
        by_stamp = {f.stamp_ns: f for f in self._frames}
        left_topic, right_topic = self.topics.left_image, self.topics.right_image
        decode = compressed_to_rgb if self.compressed else image_to_rgb
        wanted = [left_topic, right_topic] if self.stereo else [left_topic]
        pending: dict[int, dict[str, np.ndarray]] = {}
        undecodable: set[int] = set()
        for item in read_messages(self.path, wanted, on_damage="skip"):  # losses counted by the index
            stamp = stamp_from_header(item.msg)
            if stamp not in by_stamp or stamp in undecodable:
                continue
            images = pending.setdefault(stamp, {})
            try:
                images[item.topic] = decode(item.msg)
            except MessageError:  # as the node: a frame that does not decode is dropped, counted
                undecodable.add(stamp)
                del pending[stamp]
                self.skipped["an image does not decode"] = self.skipped.get("an image does not decode", 0) + 1
                continue
            if len(images) < len(wanted):
                continue
            del pending[stamp]
            camera = by_stamp[stamp].camera
            left, right = images[left_topic], images.get(right_topic) if self.stereo else None
            if any(img.shape[1::-1] != camera.size for img in (left, right) if img is not None):
                self.skipped["images do not fit the camera"] = self.skipped.get("images do not fit the camera", 0) + 1
                continue
            yield EvalSample(CameraInput(left, right, camera, stamp), self._truths.get(stamp),
                             self._far_truths.get(stamp))

    def labelled_frames(self, buffer: ImuBuffer) -> Iterator[LabelledFrame]:
        """Frames with their attitude from ``buffer``'s rules (filled with every IMU sample of the
        bag: :func:`roadbev_core.attitude.imu_buffer` with ``whole_history``), for readers that
        need whole frames (training). Frames without a trustworthy attitude are left out and
        counted in ``skipped``."""
        for sample in self.imu:
            buffer.add(sample.stamp_ns, sample.orientation_xyzw)
        for inputs, truth, _ in self:
            try:
                attitude = buffer.attitude_at(inputs.stamp_ns)
            except ImuStale as exc:
                reason = f"no IMU attitude ({exc})"
                self.skipped[reason] = self.skipped.get(reason, 0) + 1
                continue
            yield LabelledFrame(Frame(inputs.left, inputs.right, inputs.camera, attitude, inputs.stamp_ns), truth)


def grid_fields(params: Mapping[str, Any]) -> dict[str, float]:
    """The grid fields among the parameters the user gave (:data:`roadbev_core.config.GRID_PARAMS`
    names: ``base_height``, ``x_min``...): they win over a bag's ``/roadbev/grid_config``."""
    return {spec.name: float(params[spec.name]) for spec in GRID_PARAMS if spec.name in params}


class _Collected(NamedTuple):
    left: dict[int, int]  # stamp -> count (duplicates detected)
    right: set[int]
    left_info: dict[int, object]  # stamp -> CameraInfo message
    right_info: dict[int, object]
    imu: list[ImuSample]
    truths: dict[int, object]  # stamp -> GridMap message
    far_truths: dict[int, object]  # stamp -> GridMap message of the far-field truth
    grid_config: dict[str, Any] | None
    bad_imu: int
    read: ReadStats
    odometry: list[PlanarPose]
    bad_odometry: int
    static: list[StaticTransform]
    left_frame: str


def _collect(path: Path, topics: BagTopics) -> _Collected:
    left: dict[int, int] = {}
    right: set[int] = set()
    left_info: dict[int, object] = {}
    right_info: dict[int, object] = {}
    imu: list[tuple[int, np.ndarray]] = []
    truths: dict[int, object] = {}
    far_truths: dict[int, object] = {}
    grid_config = None
    bad_imu = bad_odometry = 0
    odometry: list[PlanarPose] = []
    static: list[StaticTransform] = []
    left_frame = ""
    read = ReadStats()
    for item in read_messages(path, topics.names(), on_damage="skip", stats=read):
        topic, msg = item.topic, item.msg
        if topic == topics.grid_config:
            try:
                grid_config = json.loads(msg.data)
            except (TypeError, ValueError) as exc:
                raise BagError(f"{path}: {topic} is not JSON: {exc}") from None
            continue
        if topic == topics.tf_static:
            with contextlib.suppress(MessageError):  # malformed: the mount comes from vehicle.camera_position_m
                static.extend(transforms_from_tf(msg))
            continue
        try:
            stamp = stamp_from_header(msg)
        except MessageError as exc:
            raise BagError(f"{path}: a message on {topic} has a bad stamp: {exc}") from None
        if topic == topics.left_image:
            left[stamp] = left.get(stamp, 0) + 1
            left_frame = left_frame or str(getattr(msg.header, "frame_id", ""))
        elif topic == topics.right_image:
            right.add(stamp)
        elif topic == topics.left_info:
            left_info[stamp] = msg
        elif topic == topics.right_info:
            right_info[stamp] = msg
        elif topic == topics.imu:
            try:
                imu.append((stamp, imu_orientation(msg)))
            except MessageError:
                bad_imu += 1
        elif topic == topics.ground_truth:
            truths[stamp] = msg
        elif topic == topics.ground_truth_far:
            far_truths[stamp] = msg
        elif topic == topics.odom:
            try:
                odometry.append(odometry_sample(msg))
            except MessageError:
                bad_odometry += 1
    imu.sort(key=lambda s: s[0])
    odometry.sort(key=lambda p: p.stamp_ns)
    samples = [ImuSample(stamp, (float(q[0]), float(q[1]), float(q[2]), float(q[3]))) for stamp, q in imu]
    return _Collected(left, right, left_info, right_info, samples, truths, far_truths, grid_config, bad_imu, read,
                      odometry, bad_odometry, static, left_frame)


def _info_at(infos: dict[int, object], stamp: int) -> object | None:
    """The CameraInfo stamped ``stamp``; else the latest one before it; else the first one."""
    if stamp in infos:
        return infos[stamp]
    if not infos:
        return None
    before = [s for s in infos if s <= stamp]
    return infos[max(before)] if before else infos[min(infos)]


def read_eval_bag(
    path: str | os.PathLike[str],
    topics: TopicsConfig | None = None,
    *,
    grid_overrides: Mapping[str, float] | None = None,
) -> EvalBag:
    """Index an evaluation bag (images are decoded lazily, while iterating).

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        topics: the node's topics (the defaults when None): the sensor topics, the
            ``image_transport`` (preferred when the bag has both) and the ``base_frame`` the
            camera's mount is looked up from.
        grid_overrides: grid fields the user gave (:func:`grid_fields`: ``base_height``,
            ``z_min``...; horizontal ones only where the bag has no ground truth).

    Raises:
        BagError: unreadable bag, no left images or CameraInfo, ground-truth maps on
            different grids, or a grid the parameters make invalid.
    """
    path = Path(path)
    node_topics = topics or TopicsConfig()
    present = bag_topics(path)
    notes: list[str] = []
    raw, packed = BagTopics.of(node_topics), BagTopics.of(node_topics, compressed=True)
    prefer_compressed = node_topics.image_transport == "compressed"
    compressed = packed.left_image in present and (prefer_compressed or raw.left_image not in present)
    topics_read = packed if compressed else raw
    if topics_read.left_image not in present:
        raise BagError(
            f"{path}: no left images ({raw.left_image} or {packed.left_image}); topics: {sorted(present)}"
        )
    stereo = topics_read.right_image in present
    collected = _collect(path, topics_read)
    if collected.bad_imu:
        notes.append(f"{collected.bad_imu} IMU message(s) without a valid orientation ignored")
    if collected.bad_odometry:
        notes.append(f"{collected.bad_odometry} malformed odometry message(s) ignored")

    # The grid: vertical fields from params > the bag's grid_config > defaults.
    base_fields = dict(GridSpec().to_dict())
    if collected.grid_config and isinstance(collected.grid_config.get("grid"), dict):
        base_fields.update({k: float(v) for k, v in collected.grid_config["grid"].items() if k in base_fields})
    overrides = dict(grid_overrides or {})
    try:
        base = GridSpec.from_dict(base_fields).with_overrides(
            **{k: v for k, v in overrides.items() if k in _VERTICAL_FIELDS}
        )
    except ConfigError as exc:
        raise BagError(f"{path}: the grid parameters are invalid: {exc}") from None
    truths: dict[int, np.ndarray] = {}
    grid = base
    if collected.truths:
        grid, truths = _decode_truths(path, collected.truths, base, "ground truth", "ground-truth maps")
        horizontal = {k: v for k, v in overrides.items() if k in _HORIZONTAL_FIELDS}
        if any(abs(getattr(grid, k) - v) > 1e-9 for k, v in horizontal.items()):
            notes.append("horizontal grid parameters ignored: the ground truth's GridMap info defines the grid")
    else:
        try:
            grid = base.with_overrides(**{k: v for k, v in overrides.items() if k in _HORIZONTAL_FIELDS})
        except ConfigError as exc:
            raise BagError(f"{path}: the grid parameters are invalid: {exc}") from None
        notes.append("no ground truth in the bag: samples carry truth=None")

    skipped: dict[str, int] = {}
    frames: list[_FrameIndex] = []
    cameras: dict[tuple[int, int], StereoCamera] = {}

    def skip(reason: str) -> None:
        skipped[reason] = skipped.get(reason, 0) + 1

    for stamp in sorted(collected.left):
        if stereo and stamp not in collected.right:
            skip("no right image with the same stamp")
            continue
        left_info = _info_at(collected.left_info, stamp)
        right_info = _info_at(collected.right_info, stamp) if stereo else None
        if left_info is None or (stereo and right_info is None):
            skip("no CameraInfo")
            continue
        camera_key = (id(left_info), id(right_info))
        if camera_key not in cameras:
            try:
                cameras[camera_key] = stereo_camera_from_camera_info(left_info, right_info)
            except MessageError as exc:
                raise BagError(f"{path}: CameraInfo for the frame at {stamp} ns: {exc}") from None
        frames.append(_FrameIndex(stamp, cameras[camera_key]))
    if not collected.read.complete:
        # a damaged or cut bag: a frame the readable IMU (or odometry) does not reach past would
        # take an extrapolated attitude (pose), not the one the whole bag gives it; such frames are
        # lost with the damage rather than scored with other inputs
        ends = [max(sample.stamp_ns for sample in collected.imu)] if collected.imu else []
        ends += [max(p.stamp_ns for p in collected.odometry)] if collected.odometry else []
        if ends:
            reached = [f for f in frames if f.stamp_ns <= min(ends)]
            for _ in range(len(frames) - len(reached)):
                skip("the readable IMU or odometry ends before it (the bag is damaged)")
            frames = reached
    if not frames:
        damage = f"; {collected.read.summary()}" if not collected.read.complete else ""
        raise BagError(f"{path}: no usable frames ({skipped or 'no left images'}){damage}")
    if not collected.imu:
        notes.append("no IMU orientation in the bag: every frame needs require_imu false and a default attitude")
    bag = EvalBag(path, grid, frames, truths, collected.imu, topics_read, compressed, stereo, skipped,
                  notes, collected.read)
    bag.odometry = collected.odometry
    if collected.far_truths:
        bag.far_grid, bag._far_truths = _far_truths(path, collected, base)
    camera_frame = collected.left_frame or LEFT_FRAME
    bag.camera_frame = camera_frame
    bag.camera_mount = camera_mount(collected.static, node_topics.base_frame, camera_frame)
    return bag


def _far_truths(path: Path, collected: _Collected, base: GridSpec) -> tuple[GridSpec, dict[int, np.ndarray]]:
    """The far-field grid (horizontal from the GridMaps' info; vertical range from the bag's
    ``far_grid``, else the ``far_field`` defaults) and the truth on it per stamp.

    Raises:
        BagError: malformed maps, maps without an ``elevation`` layer or on different grids.
    """
    defaults = FarFieldConfig()
    described = (collected.grid_config or {}).get("far_grid")
    vertical = {"z_min": defaults.z_min, "z_max": defaults.z_max}
    if isinstance(described, dict):
        vertical.update({k: float(v) for k, v in described.items() if k in vertical})
    try:
        far_base = GridSpec.from_dict({**base.to_dict(), **vertical})
    except ConfigError as exc:
        raise BagError(f"{path}: the far-field grid's vertical range is invalid: {exc}") from None
    return _decode_truths(path, collected.far_truths, far_base, "far-field ground truth",
                          "far-field ground-truth maps")


def _decode_truths(path: Path, messages: Mapping[int, Any], base: GridSpec, what: str, maps: str
                   ) -> tuple[GridSpec, dict[int, np.ndarray]]:
    """The grid of ground-truth GridMaps (horizontal from their info, vertical from ``base``) and
    each stamp's ``elevation`` layer [rows, cols] on it.

    Raises:
        BagError: a malformed map, one without an ``elevation`` layer, or maps on different grids
            (``what`` names one map, ``maps`` all of them).
    """
    grids: set[GridSpec] = set()
    truths: dict[int, np.ndarray] = {}
    for stamp, msg in messages.items():
        try:
            decoded = grid_map_to_arrays(msg, base)
        except MessageError as exc:
            raise BagError(f"{path}: {what} at {stamp} ns is malformed: {exc}") from None
        if "elevation" not in decoded.layers:
            raise BagError(f"{path}: {what} at {stamp} ns has no 'elevation' layer")
        grids.add(decoded.grid)
        truths[stamp] = np.array(decoded.layers["elevation"], dtype=np.float32)
    if len(grids) > 1:
        raise BagError(f"{path}: the {maps} are on {len(grids)} different grids")
    return grids.pop(), truths


def bag_frames(
    path: str | os.PathLike[str],
    topics: TopicsConfig | None = None,
    imu: ImuConfig | None = None,
    *,
    grid_overrides: Mapping[str, float] | None = None,
) -> tuple[GridSpec, list[LabelledFrame]]:
    """The grid and the labelled frames of an evaluation bag, each with its attitude from the IMU
    under the one attitude rule set (:func:`roadbev_core.attitude.imu_buffer`, whole history).

    Args:
        topics, grid_overrides: as :func:`read_eval_bag`.
        imu: the IMU settings (``imu_max_age_s``, ``imu_to_camera_rpy_deg``; the defaults when None).
    """
    bag = read_eval_bag(path, topics, grid_overrides=grid_overrides)
    buffer = imu_buffer(imu or ImuConfig(), whole_history=True)
    return bag.grid, list(bag.labelled_frames(buffer))
