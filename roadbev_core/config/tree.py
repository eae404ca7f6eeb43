"""The typed configuration tree: every setting of the pipeline and the node, validated once.

:class:`RoadbevConfig` holds one frozen section per concern (backend, grid, topics, sync, IMU,
preview, vehicle, map, diagnostics, far field). Each field carries the ROS parameter it is read from, with its
description, range, choices and whether it may change at run time (:func:`param`); the node's
parameter table (:func:`parameter_specs`: ``ros2 param describe``, ranges, read-only), the
shipped ``config/roadbev.params.yaml`` and every loader are generated from those fields, so
adding a parameter is one edit here.

Every entry point (node start-up, ``-p name:=value``, ``ros2 param set``, ``roadbev eval
--params``, the demo, the benchmarks) builds its config with :meth:`RoadbevConfig.from_params`,
which refuses an unknown name or a wrong type with the parameter's name, checks ranges, and
checks the whole: the backend's name, the grid, and what the settings would cost
(:data:`MAX_GRID_VOXELS`, :data:`MAX_SYNC_SETS`) before anything is allocated. What only a
component can judge (the fused map's settings, the wheel tracks on the grid) is checked by
:func:`roadbev_core.pipeline.check_config`, which those entry points call next; the config
imports no component.

Backend names and options are looked up in :mod:`roadbev_core.backend_plugins` (the built-in
backends, installed plugins, ``module:attr`` paths) without importing any backend. Options are
the open-ended parameters ``<backend>.<option>`` (for example ``bev_sweep.patch_cells``); the
backend itself checks their names and values when it is built.
"""

from __future__ import annotations

import difflib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from functools import cache
from typing import Any, ClassVar

import numpy as np

from roadbev_core.backend_plugins import available, is_backend_name, option_backend, takes_checkpoint
from roadbev_core.config.grid import ConfigError, GridSpec, whole_cells_end
from roadbev_core.config.params_file import ParamError, split_backend_spec

__all__ = [
    "DEFAULT_BACKEND",
    "DEFAULT_PACE_BACKEND",
    "MAX_CAMERA_HZ",
    "MAX_GRID_VOXELS",
    "MAX_IMAGE_PIXELS",
    "MAX_SYNC_SETS",
    "BackendConfig",
    "DiagnosticsConfig",
    "FarFieldConfig",
    "ImuConfig",
    "MapConfig",
    "ParamSpec",
    "PreviewConfig",
    "RoadbevConfig",
    "SyncConfig",
    "TopicsConfig",
    "VehicleConfig",
    "check_image_size",
    "check_name",
    "is_backend_option",
    "param",
    "parameter_specs",
]

# Cost limits, checked before anything is allocated. The default grid has 419,840 voxels
# (164 x 64 x 40); bev_sweep holds a few float32 volumes of that size, a learned model more.
MAX_GRID_VOXELS = 4_000_000
# Images larger than this are refused (4096 x 4096: a 50 MB rgb8 frame, inside the shipped
# Fast DDS profile's 64 MB shared-memory segment).
MAX_IMAGE_PIXELS = 4096 * 4096
# The synchroniser tries every combination of candidate stamps within the slop for each new
# message; candidates per topic are at most min(queue, 1 + 2 * slop * MAX_CAMERA_HZ).
MAX_CAMERA_HZ = 60.0
MAX_SYNC_SETS = 1_000_000
# The backend of the node, `roadbev eval` and the demo when none is named: the configuration whose
# preview the ride benchmark found worth the most (docs/results/preview.md, the ride benchmark).
DEFAULT_BACKEND = "ensemble"
# The backend that answers while the chosen one cannot keep pace with the camera: the default
# ensemble's cheapest member (docs/results/preview.md, "Keeping pace on the ride").
DEFAULT_PACE_BACKEND = "bm"
# The vehicle body frame (REP-105; Autoware's convention, docs/interface/frames-and-grid.md): the frame of contact-plane
# previews and the parent the camera mount is looked up from.
BASE_FRAME = "base_link"


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter.

    Attributes:
        name: the ROS parameter name.
        default: default value; its Python type is the parameter's type (bool, int, float, str,
            list of float).
        description: one line for ``ros2 param describe``.
        low, high: inclusive numeric range (None = unbounded), also declared to ROS.
        choices: allowed string values (None = any).
        read_only: cannot change after start (topics, transports).
        open_choices: ``choices`` are the values known now, not all of them: :meth:`check`
            lets others through and the config judges them as a whole (the backend, which may
            also be a ``module:attr`` path).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    open_choices: bool = False

    def check(self, value: Any) -> Any:
        """``value`` checked (type, range, choices) and coerced to the parameter's type.

        Raises:
            ParamError: naming the parameter.
        """
        value = _coerce(self, value)
        if self.choices is not None and not self.open_choices and value not in self.choices:
            raise ParamError(f"{self.name} must be one of {', '.join(self.choices)}; got {value!r}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if self.low is not None and value < self.low:
                raise ParamError(f"{self.name} = {value} is below its minimum {self.low}")
            if self.high is not None and value > self.high:
                raise ParamError(f"{self.name} = {value} is above its maximum {self.high}")
        return value


def _coerce(spec: ParamSpec, value: Any) -> Any:
    kind = type(spec.default)
    if kind is bool:
        if not isinstance(value, bool):
            raise ParamError(f"{spec.name} must be true or false, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(f"{spec.name} must be an integer, got {value!r}")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"{spec.name} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ParamError(f"{spec.name} must be finite, got {value!r}")
        return float(value)
    if kind is str:
        if not isinstance(value, str):
            raise ParamError(f"{spec.name} must be a string, got {value!r}")
        return value
    # a list of floats of fixed length
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
    ):
        raise ParamError(f"{spec.name} must be a list of finite numbers, got {value!r}")
    if len(value) != len(spec.default):
        raise ParamError(f"{spec.name} needs {len(spec.default)} numbers, got {len(value)}")
    return tuple(float(v) for v in value)


def param(
    name: str,
    default: Any,
    description: str,
    low: float | None = None,
    high: float | None = None,
    *,
    choices: tuple[str, ...] | None = None,
    read_only: bool = False,
    open_choices: bool = False,
) -> Any:
    """A config field read from ROS parameter ``name`` (lists are stored as tuples)."""
    spec = ParamSpec(name, list(default) if isinstance(default, tuple) else default, description,
                     low, high, choices, read_only, open_choices)
    return field(default=default, metadata={"param": spec})


def _specs_of(section: type) -> list[tuple[str, ParamSpec]]:
    """(field name, spec) of every parameter field of a section class."""
    return [(f.name, f.metadata["param"]) for f in fields(section) if "param" in f.metadata]


# --- sections -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BackendConfig:
    """What estimates the elevation."""

    name: str = param("backend", DEFAULT_BACKEND, "elevation backend (see roadbev_core.backends)",
                      open_choices=True)
    checkpoint: str = param("checkpoint", "", "checkpoint file for the learned backends (stereo, mono, gwcnet, "
                            "adabins); empty = the shipped one")
    inference_threads: int = param("inference_threads", 0, "threads for the backend's torch/OpenCV work; "
                                   "0 = one less than the CPU cores (a core stays free for the callbacks)", 0, 256)
    pace_backend: str = param("pace_backend", DEFAULT_PACE_BACKEND, "a cheaper backend that answers the node's "
                              "frames while the chosen one takes more than pace_load of the camera's period per "
                              "frame (roadbev_core/pacing.py), with the node's options of it, or its own after a "
                              "colon (NAME:OPTION=VALUE,...); empty, or the chosen backend itself = none (the "
                              "node then falls behind a faster camera and skips frames)", open_choices=True)
    pace_load: float = param("pace_load", 0.9, "the largest share of the camera's period the chosen backend may "
                             "take per frame before pace_backend answers", 0.1, 10.0)
    pace_lead_m: float = param("pace_lead_m", 0.5, "pace_backend also answers while the car's speed times the "
                               "chosen backend's extra time per frame over it exceeds this travel (m): at highway "
                               "speed an earlier preview gains more than a better estimate; 0 = by pace_load alone",
                               0.0, 100.0)
    # "<backend>.<option>" parameters, as given (the backend checks them when it is built)
    options: Mapping[str, Any] = field(default_factory=dict)

    def options_of(self, backend: str | None = None) -> dict[str, Any]:
        """Keyword options for ``backend`` (default: the chosen one), with the checkpoint for
        backends that take one."""
        name = backend or self.name
        prefix = f"{name}."
        out = {key[len(prefix):]: value for key, value in self.options.items() if key.startswith(prefix)}
        if takes_checkpoint(name) and self.checkpoint:
            out["checkpoint"] = self.checkpoint
        return out


@dataclass(frozen=True)
class TopicsConfig:
    """Topic names, transports and the output frame (fixed after start)."""

    image_transport: str = param("image_transport", "raw", "input image transport",
                                 choices=("raw", "compressed"), read_only=True)
    left_image: str = param("left_image_topic", "/stereo/left/image_rect", "left rectified image", read_only=True)
    right_image: str = param("right_image_topic", "/stereo/right/image_rect", "right rectified image",
                             read_only=True)
    left_info: str = param("left_info_topic", "/stereo/left/camera_info", "left CameraInfo", read_only=True)
    right_info: str = param("right_info_topic", "/stereo/right/camera_info", "right CameraInfo", read_only=True)
    imu: str = param("imu_topic", "/imu/data", "IMU (orientation relative to ENU)", read_only=True)
    speed: str = param("speed_topic", "", "vehicle speed (nav_msgs/Odometry or geometry_msgs/TwistStamped); "
                       "empty = no time of arrival in the preview", read_only=True)
    odom: str = param("odom_topic", "/odom", "vehicle odometry (nav_msgs/Odometry, odom -> base_link): the "
                      "ego-motion the fused map and its previews are built on ('' = no map unless speed_topic is "
                      "set); roadbev label also accumulates scans with it", read_only=True)
    publish_odom_tf: bool = param("publish_odom_tf", False, "re-broadcast each odom_topic message as the TF "
                                  "header.frame_id -> child_frame_id (odom -> base_link) on /tf, for bags and "
                                  "vehicles that carry odometry without TF; leave false where the vehicle's "
                                  "localisation publishes that TF", read_only=True)
    speed_type: str = param("speed_topic_type", "odometry", "message type of speed_topic",
                            choices=("odometry", "twist_stamped"), read_only=True)
    elevation: str = param("elevation_topic", "/roadbev/elevation", "GridMap output", read_only=True)
    preview: str = param("preview_topic", "/roadbev/preview", "RoadPreview output", read_only=True)
    points: str = param("points_topic", "/roadbev/points", "PointCloud2 output for viewers ('' = off)",
                        read_only=True)
    preview_markers: str = param("preview_markers_topic", "/roadbev/preview_markers", "visualization_msgs/"
                                 "MarkerArray of the preview for viewers (RViz, Foxglove): a line per wheel track "
                                 "coloured by sigma, built only while subscribed ('' = off)", read_only=True)
    frame_id: str = param("frame_id", "roadbev_road", "frame of the outputs", read_only=True)
    base_frame: str = param("base_frame", BASE_FRAME, "the vehicle body frame (REP-105): the frame of the "
                            "contact-plane previews, and the parent the camera mount is looked up from on "
                            "/tf_static and /tf", read_only=True)
    odom_from_tf: bool = param("odom_from_tf", False, "take the odometry from /tf instead of a topic: map_frame -> "
                               "base_frame, looked up at the stamp of each /tf transform on the way (speed and yaw "
                               "rate from sample to sample); needs odom_topic ''", read_only=True)
    tf_cache_time_s: float = param("tf_cache_time_s", 10.0, "how far back each /tf link's history reaches from its "
                                   "newest transform (s; tf2's default 10); older /tf data is refused",
                                   0.5, 600.0, read_only=True)
    tf_tolerance_s: float = param("tf_tolerance_s", 0.05, "a TF lookup (the camera mount at a frame's stamp) this "
                                  "close beyond a /tf link's first or last transform takes that transform as it is "
                                  "(s); further is refused as an extrapolation, as in tf2", 0.0, 1.0, read_only=True)

    def __post_init__(self) -> None:
        if self.odom_from_tf and self.odom:
            raise ParamError(f"odom_from_tf takes the odometry from /tf instead of odom_topic ({self.odom!r}): set "
                             "odom_topic to '' with it")


@dataclass(frozen=True)
class SyncConfig:
    """Approximate-time pairing of the images and camera infos."""

    queue_size: int = param("sync_queue_size", 10, "approximate-time synchroniser queue per topic", 1, 1000)
    slop_s: float = param("sync_slop_s", 0.02, "largest stamp spread within a synchronised set (s)", 0.0, 1.0)
    queue_mb: float = param("sync_queue_mb", 256.0, "largest total size of the messages the synchroniser "
                            "holds (MiB, all topics); beyond it the oldest are dropped (queue overflow)", 1.0, 65536.0)
    max_image_mb: float = param("max_image_mb", 64.0, "an image message larger than this (MiB of data) is refused "
                                "on arrival, counted as 'image too large' (the shipped Fast DDS profile's "
                                "shared-memory segment is 64 MiB)", 0.001, 4096.0)

    def __post_init__(self) -> None:
        if self.queue_mb < 2 * self.max_image_mb:
            raise ParamError(f"sync_queue_mb = {self.queue_mb:g} must hold a stereo pair of the largest images: "
                             f"at least 2 x max_image_mb = {2 * self.max_image_mb:g}")

    def sets_per_message(self, topics: int) -> float:
        """Upper bound of the stamp combinations one new message makes the synchroniser try."""
        candidates = min(float(self.queue_size), 1.0 + 2.0 * self.slop_s * MAX_CAMERA_HZ)
        return candidates ** max(topics - 1, 0)


@dataclass(frozen=True)
class ImuConfig:
    """The attitude at an image stamp (:class:`roadbev_core.attitude.ImuBuffer`'s rules)."""

    max_age_s: float = param("imu_max_age_s", 0.1, "refuse the IMU attitude when the nearest sample is "
                             "further from the image stamp (s); also the largest gap between two samples",
                             0.001, 10.0)
    buffer_s: float = param("imu_buffer_s", 2.0, "IMU history kept for interpolation (s)", 0.1, 60.0)
    wait_s: float = param("imu_wait_s", 0.05, "how long a set may wait for an IMU sample after its stamp (s)",
                          0.0, 1.0)
    require: bool = param("require_imu", True, "drop frames without a fresh IMU attitude (else use "
                          "default_roll_deg/default_pitch_deg)")
    default_roll_deg: float = param("default_roll_deg", 0.0, "attitude used when require_imu is false and "
                                    "no IMU", -45.0, 45.0)
    default_pitch_deg: float = param("default_pitch_deg", 0.0, "attitude used when require_imu is false and "
                                     "no IMU", -45.0, 45.0)
    imu_to_camera_rpy_deg: tuple[float, float, float] = param(
        "imu_to_camera_rpy_deg", (0.0, 0.0, 0.0), "roll, pitch, yaw (deg) of the camera body in the IMU body frame")


@dataclass(frozen=True)
class PreviewConfig:
    """The wheel-track profiles."""

    track_offsets_m: tuple[float, float] = param("preview.track_offsets_m", (0.8, -0.8),
                                                 "lateral offsets of the left, right wheel tracks (m, y left)")
    tyre_width_m: float = param("preview.tyre_width_m", 0.2, "tyre width averaged across (m)", 0.0, 2.0)
    spacing_m: float = param("preview.spacing_m", 0.03, "spacing of the profile samples (m)", 0.001, 1.0)
    reference_distance_m: float = param("preview.reference_distance_m", 0.0, "x of the point the times of "
                                        "arrival refer to (e.g. the front axle; m ahead of the camera)",
                                        -20.0, 50.0)
    rear_axle: bool = param("preview.rear_axle", False, "with the map on: also the rear wheels' tracks "
                            "(all tracks then start at the rear axle)")
    max_gap_m: float = param("preview.max_gap_m", 1.0, "gaps in a profile up to this long (m) are bridged by a "
                             "straight line with a sigma that grows inside the gap (the far side of a bump, a "
                             "pothole's hidden wall); 0 = gaps stay NaN", 0.0, 10.0)
    markers_sigma_max_m: float = param("preview.markers_sigma_max_m", 0.02, "the sigma (m) preview_markers_topic "
                                       "draws red: green at 0, yellow at half of it, red from it up", 0.001, 1.0)


@dataclass(frozen=True)
class MapConfig:
    """The fused road map in ``odom`` (docs/concepts/fused_map.md; roadbev_core.fusion)."""

    enabled: bool = param("map.enabled", True, "fuse frames into the road map when odometry (or a speed) "
                          "arrives; the preview then comes from the map, relative to the contact plane")
    topic: str = param("map_topic", "/roadbev/map", "fused map output (grid_map_msgs/GridMap)", read_only=True)
    frame: str = param("map_frame", "odom", "frame of the fused map: the odometry's frame (odom_topic's "
                       "header.frame_id; with odom_from_tf, the frame base_frame is looked up in)", read_only=True)
    behind_m: float = param("map.behind_m", 1.0, "the map reaches this far behind the rear axle (m)", 0.0, 20.0)
    error_correlation: float = param("map.error_correlation", 1.0, "correlation of one cell's errors from "
                                     "frame to frame (0 = independent: the fused sigma shrinks as 1/sqrt(N))",
                                     0.0, 1.0)
    align_correlation: float = param("map.align_correlation", 0.1, "correlation of one frame's cell errors "
                                     "in the alignment fit (how much the overlap is worth against the priors)",
                                     0.0, 1.0)
    gate_sigma: float = param("map.gate_sigma", 3.0, "observations farther than this many sigmas from a cell "
                              "are rejected", 1.0, 100.0)
    reset_after: int = param("map.reset_after", 3, "rejections in a row that restart a cell", 1, 1000)
    align: bool = param("map.align", True, "align each frame with the map on their overlap (offset)")
    align_slopes: bool = param("map.align_slopes", True, "align the slopes too (pitch and roll errors)")
    offset_prior_m: float = param("map.offset_prior_m", 0.05, "1-sigma prior of a frame's vertical offset "
                                  "around the prediction (m)", 0.001, 10.0)
    slope_prior_deg: float = param("map.slope_prior_deg", 0.3, "1-sigma prior of a frame's pitch and roll "
                                   "correction (deg)", 0.001, 10.0)
    min_overlap_cells: int = param("map.min_overlap_cells", 50, "fewer cells shared with the map: the frame "
                                   "keeps the predicted offset", 3, 1_000_000)
    range_exponent: float = param("map.range_exponent", 4.0, "an observation x ahead of the camera weighs "
                                  "(x_near / x)^k times what its sigma says (nearer is better)", 0.0, 8.0)
    datum_sigma_m: float = param("map.datum_sigma_m", -1.0, "1-sigma of the map's vertical datum when it is "
                                 "fixed (m), in the published uncertainty; -1 = the backend's calibrated value "
                                 "(roadbev_core/data/datum_calibration.json, 0 without one)", -1.0, 10.0)
    datum_drift: float = param("map.datum_drift", -1.0, "growth of that 1-sigma per metre driven (m/m); -1 = the "
                               "backend's calibrated value (0 without one)", -1.0, 1.0)
    save_dir: str = param("map.save_dir", "~/.ros/roadbev", "folder where ~/save_map writes the current map "
                          "(roadbev_map_<stamp>.mcap; ~ expanded, a relative folder taken from the node's "
                          "working directory; the reply gives the absolute path), and which a relative path "
                          "given to ~/save_map_to is taken from")
    odom_max_age_s: float = param("map.odom_max_age_s", 0.2, "largest distance from a frame's stamp to the "
                                  "odometry around it (s); beyond it the frame is not fused", 0.001, 10.0)
    odom_max_speed_mps: float = param("map.odom_max_speed_mps", 70.0, "odometry gate: a sample reporting a faster "
                                      "speed, or moved further from the one before than this speed allows "
                                      "(+ 0.5 m of noise), is refused and counted (m/s)", 1.0, 200.0)
    odom_max_yaw_rate: float = param("map.odom_max_yaw_rate", 2.0, "odometry gate: the fastest the heading may "
                                     "turn, reported or implied (rad/s)", 0.1, 10.0)
    odom_reanchor_samples: int = param("map.odom_reanchor_samples", 5, "refused odometry samples in a row that "
                                       "agree with each other mean the odometry jumped: it is followed from "
                                       "them and the map starts again (a WARN)", 2, 1000)


@dataclass(frozen=True)
class VehicleConfig:
    """The vehicle body, ``base_link`` at the rear-axle centre on the road (docs/interface/frames-and-grid.md)."""

    wheelbase_m: float = param("vehicle.wheelbase_m", 2.80, "distance from the rear to the front axle (m)",
                               0.5, 10.0)
    track_width_m: float = param("vehicle.track_width_m", 1.60, "distance between the left and right tyre "
                                 "contacts (m)", 0.5, 4.0)
    camera_position_m: tuple[float, float, float] = param(
        "vehicle.camera_position_m", (1.60, 0.0, 1.10), "x, y, z of the left camera's optical centre in "
        "base_link (m); TF base_link -> the images' frame (/tf_static, /tf) wins when present")

    def __post_init__(self) -> None:
        for attr, spec in _specs_of(VehicleConfig):  # built directly (drives, tests) too: same ranges
            spec.check(getattr(self, attr))
        pos = tuple(float(v) for v in self.camera_position_m)
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos) or pos[2] <= 0:
            raise ParamError(f"vehicle.camera_position_m must be 3 finite numbers with z > 0 (above the "
                             f"road), got {self.camera_position_m}")
        object.__setattr__(self, "camera_position_m", pos)

    @property
    def front_axle_ahead_of_camera_m(self) -> float:
        """How far the front axle is ahead of the camera (m; 1.20 with the defaults)."""
        return self.wheelbase_m - self.camera_position_m[0]

    def wheel_positions(self) -> np.ndarray:
        """[4, 2] (x, y) of the tyre centres in ``base_link``, front left, front right, rear left,
        rear right."""
        half = 0.5 * self.track_width_m
        L = self.wheelbase_m
        return np.array([[L, half], [L, -half], [0.0, half], [0.0, -half]])


@dataclass(frozen=True)
class DiagnosticsConfig:
    """``/diagnostics`` and logging."""

    period_s: float = param("diagnostics_period_s", 1.0, "diagnostics publication period (s)", 0.05, 60.0)
    log_throttle_s: float = param("log_throttle_s", 5.0, "minimum period between repeated warnings (s)",
                                  0.0, 3600.0)
    window_s: float = param("diagnostics.window_s", 5.0, "window of the rates, latency percentiles and stamp "
                            "ages (s): older figures are forgotten, so the status goes stale when input stops",
                            0.5, 600.0)
    min_rate_hz: float = param("diagnostics.min_rate_hz", 1.0, "lowest acceptable left-image rate (Hz; 0 = no "
                               "bound), as diagnostic_updater's FrequencyStatus", 0.0, 1000.0)
    max_rate_hz: float = param("diagnostics.max_rate_hz", 100.0, "highest acceptable left-image rate (Hz; 0 = "
                               "no bound)", 0.0, 10000.0)
    rate_tolerance: float = param("diagnostics.rate_tolerance", 0.1, "relative tolerance of the rate bounds",
                                  0.0, 1.0)
    min_stamp_age_s: float = param("diagnostics.min_stamp_age_s", -1.0, "earliest acceptable age of a left "
                                   "image's stamp on arrival, by the node's clock (s; negative = ahead of the "
                                   "clock), as diagnostic_updater's TimeStampStatus", -3600.0, 0.0)
    max_stamp_age_s: float = param("diagnostics.max_stamp_age_s", 5.0, "latest acceptable age of a left image's "
                                   "stamp on arrival, by the node's clock (s; 0 = no check; replaying a bag: "
                                   "use_sim_time with replay --clock)", 0.0, 1e9)

    max_latency_s: float = param("max_latency_s", 0.3, "bound on the time from a frame's last input arriving to "
                                 "its outputs (s): a later preview points at road already driven over, so it is "
                                 "not published (dropped_stale; ERROR while it happens, WARN when the latency "
                                 "p95 exceeds it); 0 = no bound", 0.0, 10.0)

    def __post_init__(self) -> None:
        if self.max_rate_hz and self.min_rate_hz > self.max_rate_hz:
            raise ParamError(f"diagnostics.min_rate_hz = {self.min_rate_hz} is above diagnostics.max_rate_hz "
                             f"= {self.max_rate_hz}")


@dataclass(frozen=True)
class FarFieldConfig:
    """The far-field grid: a second, coarser grid per frame beyond the grid's far edge
    (docs/concepts/grid.md, "The far field").

    It starts at the grid's far edge (``x_max``), reaches ``far_field.x_max`` and spans the
    grid's lateral range, in square cells of ``far_field.resolution``; the vertical range is its
    own (the road 15 m ahead on a grade lies further from the reference plane than the road 5 m
    ahead). It follows whatever grid it is given: a window that is not a whole number of cells is
    widened to the next whole cell (:meth:`grid`), and a grid that already reaches
    ``far_field.x_max`` leaves it nothing to estimate (:meth:`off_reason`). On by default (a
    preview cut to the grid's window delivers a fraction of what the road offers above city
    speed: docs/results/preview.md); off, nothing beyond the grid is estimated or published.
    """

    enabled: bool = param("far_field.enabled", True, "also estimate the far-field grid beyond the grid's far "
                          "edge and publish it on elevation_far_topic; with the map on, fuse it into the map, "
                          "whose window and previews then reach its far edge (the image-view backends bm, sgbm "
                          "and their ensemble; with the others the node runs the grid alone and says why)",
                          read_only=True)
    topic: str = param("elevation_far_topic", "/roadbev/elevation_far", "far-field GridMap output (with "
                       "far_field.enabled)", read_only=True)
    x_max: float = param("far_field.x_max", 15.0, "far edge of the far-field grid (m ahead of the camera, moved "
                         "out to the next whole cell where the window is not a whole number of cells); its near "
                         "edge is the grid's far edge x_max, and a grid that reaches this far turns the far field "
                         "off (diagnostic far_field says so)", 0.0, 100.0)
    resolution: float = param("far_field.resolution", 0.12, "far-field cell size (m): one image row of the RSRD "
                              "rig at the window's middle, rounded up to whole cells (docs/concepts/grid.md)",
                              0.01, 1.0)
    z_min: float = param("far_field.z_min", -0.5, "lowest far-field elevation (m)", -5.0, 0.0)
    z_max: float = param("far_field.z_max", 0.5, "highest far-field elevation (m)", 0.0, 5.0)

    def off_reason(self, near: GridSpec) -> str:
        """Why there is no far-field grid beyond ``near`` (its far edge already at or beyond
        ``far_field.x_max``), or "" when there is one. Says nothing of ``enabled``."""
        if near.x_max < self.x_max:
            return ""
        return (f"the grid already reaches far_field.x_max ({self.x_max:g} m): its far edge x_max is "
                f"{near.x_max:g} m")

    def grid(self, near: GridSpec) -> GridSpec:
        """The far-field grid beyond ``near`` (its lateral range, ``base_height`` and vertical
        steps; validated by :class:`GridSpec`).

        The window runs from ``near.x_max`` to ``far_field.x_max`` and across ``near``'s width;
        where either is not a whole number of ``far_field.resolution`` cells it is widened to the
        next whole cell (the far edge moved out, the sides out by half the remainder each), so any
        grid the node accepts has a far field.

        Raises:
            ConfigError: no window beyond ``near`` (:meth:`off_reason`), or a vertical range that
                is not a whole number of ``near``'s steps.
        """
        reason = self.off_reason(near)
        if reason:
            raise ConfigError(reason)
        # the lateral widening is shared by both sides, so the far field stays centred on the grid
        side = 0.5 * (whole_cells_end(near.y_min, near.y_max, self.resolution) - near.y_max)
        y_min, y_max = (round(near.y_min - side, 9), round(near.y_max + side, 9)) if side else (near.y_min, near.y_max)
        return GridSpec(x_min=near.x_max, x_max=whole_cells_end(near.x_max, self.x_max, self.resolution),
                        y_min=y_min, y_max=y_max, resolution=self.resolution,
                        z_min=self.z_min, z_max=self.z_max, z_resolution=near.z_resolution,
                        class_resolution=near.class_resolution, base_height=near.base_height)


# Grid parameters are GridSpec's fields under their own names (GridSpec validates the whole).
_G = GridSpec()
GRID_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("base_height", _G.base_height, "camera height above the road reference plane (m)", 0.1, 10.0),
    ParamSpec("x_min", _G.x_min, "grid near edge (m ahead)", 0.0, 100.0),
    ParamSpec("x_max", _G.x_max, "grid far edge (m ahead)", 0.0, 200.0),
    ParamSpec("y_min", _G.y_min, "grid right edge (m, y left)", -50.0, 50.0),
    ParamSpec("y_max", _G.y_max, "grid left edge (m, y left)", -50.0, 50.0),
    ParamSpec("resolution", _G.resolution, "grid cell size (m)", 0.001, 1.0),
    ParamSpec("z_min", _G.z_min, "lowest elevation (m)", -5.0, 0.0),
    ParamSpec("z_max", _G.z_max, "highest elevation (m)", 0.0, 5.0),
    ParamSpec("z_resolution", _G.z_resolution, "voxel height (m)", 0.0001, 1.0),
    ParamSpec("class_resolution", _G.class_resolution, "elevation class bin (m)", 0.0001, 1.0),
)


@dataclass(frozen=True)
class RoadbevConfig:
    """Everything the pipeline and the node are configured with (validated: build it with
    :meth:`from_params`, or :meth:`with_params` for a change)."""

    SECTIONS: ClassVar[tuple[str, ...]] = ("backend", "topics", "sync", "imu", "preview", "vehicle", "map",
                                           "diagnostics", "far_field")

    backend: BackendConfig = field(default_factory=BackendConfig)
    grid: GridSpec = field(default_factory=GridSpec)
    topics: TopicsConfig = field(default_factory=TopicsConfig)
    sync: SyncConfig = field(default_factory=SyncConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    preview: PreviewConfig = field(default_factory=PreviewConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    map: MapConfig = field(default_factory=MapConfig)
    diagnostics: DiagnosticsConfig = field(default_factory=DiagnosticsConfig)
    far_field: FarFieldConfig = field(default_factory=FarFieldConfig)

    @property
    def far_grid(self) -> GridSpec | None:
        """The far-field grid (:meth:`FarFieldConfig.grid` beyond :attr:`grid`) when
        ``far_field.enabled`` and the grid leaves it a window, else None."""
        if not self.far_field.enabled or self.far_field.off_reason(self.grid):
            return None
        return self.far_field.grid(self.grid)

    @classmethod
    def from_params(cls, params: Mapping[str, Any], *, base: RoadbevConfig | None = None) -> RoadbevConfig:
        """A validated config from flat ROS parameters (missing names keep ``base``'s values,
        the defaults when None).

        Raises:
            ParamError: an unknown name, a wrong type, a value out of range, or settings that do
                not work together (grid, wheel tracks, cost limits), naming the parameter.
        """
        base = base or cls()
        specs = {spec.name: spec for spec in parameter_specs()}
        values = {name: specs[name].check(v) if name in specs else v for name, v in base.to_params().items()}
        for name, value in params.items():
            if name in specs:
                values[name] = specs[name].check(value)
            else:
                check_name(name)
                values[name] = value
        return cls._build(values)

    def with_params(self, params: Mapping[str, Any]) -> RoadbevConfig:
        """This config with some parameters changed (validated as a whole)."""
        return type(self).from_params(params, base=self)

    @classmethod
    def _build(cls, values: Mapping[str, Any]) -> RoadbevConfig:
        sections: dict[str, Any] = {}
        for section_name in cls.SECTIONS:
            section_type = {f.name: f.type for f in fields(cls)}[section_name]
            kind = _SECTION_TYPES[str(section_type)]
            sections[section_name] = kind(**{attr: values[spec.name] for attr, spec in _specs_of(kind)})
        specs = {spec.name for spec in parameter_specs()}
        options = {k: v for k, v in values.items() if k not in specs and is_backend_option(k)}
        sections["backend"] = replace(sections["backend"], options=options)
        try:
            grid = GridSpec().with_overrides(**{spec.name: values[spec.name] for spec in GRID_PARAMS})
        except ConfigError as exc:
            raise ParamError(f"grid parameters do not form a valid grid: {exc}") from None
        if sections["far_field"].enabled and not sections["far_field"].off_reason(grid):
            try:
                sections["far_field"].grid(grid)
            except ConfigError as exc:
                raise ParamError(f"far-field parameters do not form a valid grid: {exc}") from None
        config = cls(grid=grid, **sections)
        config._check()
        return config

    def _check(self) -> None:
        """Checks across parameters: backend name, cost limits (the components' own checks:
        :func:`roadbev_core.pipeline.check_config`)."""
        if not is_backend_name(self.backend.name):
            raise ParamError(f"backend must be one of {', '.join(available())}; got {self.backend.name!r}")
        if self.backend.pace_backend and not is_backend_name(
                split_backend_spec(self.backend.pace_backend, "pace_backend")[0]):
            raise ParamError(f"pace_backend must be empty or one of {', '.join(available())} (with options: "
                             f"NAME:OPTION=VALUE,...); got {self.backend.pace_backend!r}")
        for what, grid in (("the grid", self.grid), ("the far-field grid", self.far_grid)):
            if grid is None:
                continue
            voxels = grid.n_rows * grid.n_cols * max(grid.n_z, grid.n_classes)
            if voxels > MAX_GRID_VOXELS:
                raise ParamError(
                    f"{what} {grid.n_rows} x {grid.n_cols} cells x {max(grid.n_z, grid.n_classes)} levels has "
                    f"{voxels:,} voxels, more than the limit of {MAX_GRID_VOXELS:,} (coarser resolution, "
                    "z_resolution or class_resolution, or a smaller window)"
                )
        sets = self.sync.sets_per_message(4)
        if sets > MAX_SYNC_SETS:
            raise ParamError(
                f"sync_queue_size {self.sync.queue_size} with sync_slop_s {self.sync.slop_s} would make the "
                f"synchroniser try up to {sets:,.0f} stamp combinations per message (limit {MAX_SYNC_SETS:,}): "
                "lower one of them"
            )

    def to_params(self) -> dict[str, Any]:
        """Flat ROS parameters (lists as lists), backend options included."""
        out: dict[str, Any] = {}
        for section_name in self.SECTIONS:
            section = getattr(self, section_name)
            for attr, spec in _specs_of(type(section)):
                value = getattr(section, attr)
                out[spec.name] = list(value) if isinstance(value, tuple) else value
        for spec in GRID_PARAMS:
            out[spec.name] = float(getattr(self.grid, spec.name))
        out.update(self.backend.options)
        return out


_SECTION_TYPES: dict[str, type] = {
    cls.__name__: cls
    for cls in (BackendConfig, TopicsConfig, SyncConfig, ImuConfig, PreviewConfig, VehicleConfig, MapConfig,
                DiagnosticsConfig, FarFieldConfig)
}


def is_backend_option(name: str) -> bool:
    """Whether ``name`` is a backend option ``<backend>.<option>`` of a known backend (or of a
    ``module:attr`` path: ``toy_backend:create.scale``)."""
    return option_backend(name) is not None


def check_name(name: str) -> None:
    """Refuse a parameter name the config does not know (a backend option of a known backend is
    known; the backend checks the option itself).

    Raises:
        ParamError: naming it, with the closest known name.
    """

    known = [spec.name for spec in parameter_specs()]
    if name in known or is_backend_option(name):
        return
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ParamError(f"unknown parameter {name!r}{hint}")


@cache
def _tree_specs() -> tuple[ParamSpec, ...]:
    return (*(spec for kind in _SECTION_TYPES.values() for _, spec in _specs_of(kind)), *GRID_PARAMS)


def parameter_specs() -> tuple[ParamSpec, ...]:
    """Every ROS parameter of the node, in the order of the config tree (the backend's choices:
    the backends known by name now, :func:`roadbev_core.backend_plugins.available`)."""
    backends = tuple(available())
    return tuple(replace(spec, choices=backends) if spec.name == "backend" else spec for spec in _tree_specs())


def check_image_size(width: int, height: int, what: str = "image") -> None:
    """Refuse an image larger than :data:`MAX_IMAGE_PIXELS` before it is decoded or processed.

    Raises:
        ConfigError: with the size and the limit.
    """
    if width * height > MAX_IMAGE_PIXELS:
        raise ConfigError(
            f"{what} of {width} x {height} pixels is larger than the limit of {MAX_IMAGE_PIXELS:,} pixels"
        )


def params_yaml() -> str:
    """The text of ``config/roadbev.params.yaml``: every parameter at its default, with its
    description and range (regenerate it with ``python -m roadbev_core.config`` after adding a
    parameter; a test checks the shipped file equals this)."""

    lines = [
        "# RoadBEV node parameters (a standard ROS 2 params YAML), generated from the config tree",
        "# (roadbev_core/config/tree.py: `python -m roadbev_core.config > config/roadbev.params.yaml`).",
        "# Use it with",
        "#   roadbev node --params config/roadbev.params.yaml",
        "#   ros2 run roadbev_ros roadbev_node --ros-args --params-file config/roadbev.params.yaml",
        "# Values here are the declared defaults. A `/**:` section would apply to every node; `roadbev:`",
        "# applies to the node named roadbev. Backend options go in as <backend>.<option>, for example",
        "# `bev_sweep.patch_cells: 5` or `bm.block_size: 9` (the same keys `roadbev eval --params` reads).",
        "# Unknown names and wrong types are refused by the node, `roadbev eval` and the demo alike.",
        "roadbev:",
        "  ros__parameters:",
    ]
    for spec in parameter_specs():
        notes = []
        if spec.choices:
            notes.append(f"({' | '.join(spec.choices)})")
        if spec.low is not None and spec.high is not None:
            notes.append(f"[{spec.low:g}, {spec.high:g}]")
        if spec.read_only:
            notes.append("(read-only)")
        lines.append(f"    # {' '.join([spec.description, *notes])}")
        lines.append(f"    {spec.name}: {json.dumps(spec.default)}")
    return "\n".join(lines) + "\n"
