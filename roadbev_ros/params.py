"""The node's parameters: one table of names, defaults, ranges and descriptions.

Used three ways, with no rclpy import at module level so the offline tools can use it too:

* :func:`load_params_file` reads a standard ROS 2 params YAML (``/**`` wildcard first, then the
  node's own ``ros__parameters``), as ``roadbev eval --params`` and the demo do;
* :func:`grid_from_params` turns the grid parameters (named exactly like the
  :class:`~roadbev_core.config.GridSpec` fields) into a validated grid;
* :data:`PARAMETERS` and :func:`validate` describe and check every node parameter; the node
  declares them with descriptions and ranges and rejects a change that fails :func:`validate`
  with the reason.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from roadbev_core.config import ConfigError, GridSpec

__all__ = [
    "BACKENDS",
    "BACKEND_OPTION_PREFIXES",
    "GRID_FIELDS",
    "PARAMETERS",
    "ParamError",
    "ParamSpec",
    "backend_options",
    "defaults",
    "grid_from_params",
    "is_backend_option",
    "load_params_file",
    "parse_assignments",
    "validate",
    "validate_one",
]

NODE_NAME = "roadbev"
GRID_FIELDS: tuple[str, ...] = tuple(GridSpec.__dataclass_fields__)
BACKENDS: tuple[str, ...] = ("bev_sweep", "stereo", "mono", "sgbm", "bm")
# Backend options are parameters named "<backend>.<option>" (e.g. bev_sweep.patch_cells), as
# `roadbev eval --params` reads them; they go to the backend's factory unchecked here.
BACKEND_OPTION_PREFIXES: tuple[str, ...] = tuple(f"{name}." for name in BACKENDS)


class ParamError(ValueError):
    """A parameter file or value that cannot be used, with the reason."""


# --------------------------------------------------------------------------------------------
# params YAML
# --------------------------------------------------------------------------------------------
def _node_keys(node_name: str) -> list[str]:
    """Keys a params YAML may use for ``node_name`` (with or without the leading slash)."""
    bare = node_name.lstrip("/")
    return [bare, f"/{bare}"]


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Parameters for ``node_name`` from a standard ROS 2 params YAML.

    The ``/**`` wildcard section is merged first, then the node's own section (``roadbev:`` or
    ``/roadbev:``), so the node's values win. Nested parameter dictionaries are flattened with
    dots, like ROS 2 does (``preview: {tyre_width_m: 0.2}`` -> ``preview.tyre_width_m``).

    Args:
        path: the YAML file.
        node_name: the node whose section to read (a namespaced name ``/ns/roadbev`` matches
            ``/ns/roadbev`` and ``roadbev`` sections).

    Returns:
        Parameter name -> value (empty when the file names neither the node nor ``/**``).

    Raises:
        ParamError: the file is missing, not YAML, or not shaped like a params file.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ParamError(f"cannot read params file {path}: {exc.strerror or exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ParamError(f"params file {path} is not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ParamError(f"params file {path} must map node names to sections, got {type(data).__name__}")
    sections: list[str] = ["/**"]
    short = node_name.rstrip("/").rsplit("/", 1)[-1]
    for key in _node_keys(short) + _node_keys(node_name):
        if key not in sections:
            sections.append(key)
    merged: dict[str, Any] = {}
    for key in sections:
        if key not in data:
            continue
        section = data[key]
        if not isinstance(section, dict) or "ros__parameters" not in section:
            raise ParamError(f"params file {path}: section {key!r} lacks 'ros__parameters'")
        params = section["ros__parameters"]
        if params is None:
            continue
        if not isinstance(params, dict):
            raise ParamError(f"params file {path}: {key!r} ros__parameters must be a mapping")
        merged.update(_flatten(params))
    return merged


def parse_assignments(items: Iterable[str], option: str) -> dict[str, Any]:
    """Command-line ``NAME=VALUE`` items -> ``{NAME: value}``; values read as JSON (2, 0.5, true), else text.

    Raises:
        ParamError: an item without ``=`` or a name, naming the command-line ``option``.
    """
    parsed: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ParamError(f"{option} takes NAME=VALUE, got {item!r}")
        try:
            parsed[name.strip()] = json.loads(text)
        except json.JSONDecodeError:
            parsed[name.strip()] = text
    return parsed


def _flatten(params: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in params.items():
        full = f"{prefix}{name}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{full}."))
        else:
            out[full] = value
    return out


def grid_from_params(params: Mapping[str, Any], base: GridSpec | None = None) -> GridSpec:
    """The grid described by the parameters named like :class:`GridSpec` fields.

    Args:
        params: parameter name -> value; names that are not grid fields are ignored.
        base: the grid whose fields the parameters override (the contract default when None).

    Raises:
        ParamError: a grid value is not a number or the resulting grid is inconsistent.
    """
    base = base or GridSpec()
    overrides: dict[str, float] = {}
    for name in GRID_FIELDS:
        if name not in params:
            continue
        value = params[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"grid parameter {name} must be a number, got {value!r}")
        overrides[name] = float(value)
    try:
        return base.with_overrides(**overrides)
    except ConfigError as exc:
        raise ParamError(f"grid parameters do not form a valid grid: {exc}") from None


# --------------------------------------------------------------------------------------------
# the node's parameter table
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ParamSpec:
    """One node parameter.

    Attributes:
        name: the ROS parameter name.
        default: default value; its Python type is the parameter's type (bool, int, float, str,
            list of float, list of str).
        description: one line for ``ros2 param describe``.
        low, high: inclusive numeric range (None = unbounded), also declared to ROS.
        choices: allowed string values (None = any).
        read_only: cannot change after start (topics, QoS, backend resources).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False


_G = GridSpec()
PARAMETERS: tuple[ParamSpec, ...] = (
    # --- what to run
    ParamSpec("backend", "bev_sweep", "elevation backend", choices=BACKENDS),
    ParamSpec("checkpoint", "", "checkpoint file for the learned backends (stereo, mono)"),
    ParamSpec("inference_threads", 0, "threads for the backend's torch/OpenCV work; 0 = one less than "
              "the CPU cores (a core stays free for the callbacks)", 0, 256),
    ParamSpec("image_transport", "raw", "input image transport", choices=("raw", "compressed"),
              read_only=True),
    # --- inputs
    ParamSpec("left_image_topic", "/stereo/left/image_rect", "left rectified image", read_only=True),
    ParamSpec("right_image_topic", "/stereo/right/image_rect", "right rectified image", read_only=True),
    ParamSpec("left_info_topic", "/stereo/left/camera_info", "left CameraInfo", read_only=True),
    ParamSpec("right_info_topic", "/stereo/right/camera_info", "right CameraInfo", read_only=True),
    ParamSpec("imu_topic", "/imu/data", "IMU (orientation relative to ENU)", read_only=True),
    ParamSpec("speed_topic", "", "vehicle speed (nav_msgs/Odometry or geometry_msgs/TwistStamped); "
              "empty = no time of arrival in the preview", read_only=True),
    ParamSpec("speed_topic_type", "odometry", "message type of speed_topic",
              choices=("odometry", "twist_stamped"), read_only=True),
    # --- outputs
    ParamSpec("elevation_topic", "/roadbev/elevation", "GridMap output", read_only=True),
    ParamSpec("preview_topic", "/roadbev/preview", "RoadPreview output", read_only=True),
    ParamSpec("points_topic", "/roadbev/points", "PointCloud2 output for viewers ('' = off)",
              read_only=True),
    ParamSpec("frame_id", "roadbev_road", "frame of the outputs", read_only=True),
    # --- synchronisation
    ParamSpec("sync_queue_size", 10, "approximate-time synchroniser queue per topic", 1, 1000),
    ParamSpec("sync_slop_s", 0.02, "largest stamp spread within a synchronised set (s)", 0.0, 1.0),
    ParamSpec("imu_max_age_s", 0.1, "refuse the IMU attitude when the nearest sample is older (s)",
              0.001, 10.0),
    ParamSpec("imu_buffer_s", 2.0, "IMU history kept for interpolation (s)", 0.1, 60.0),
    ParamSpec("imu_wait_s", 0.05, "how long a set may wait for an IMU sample after its stamp (s)",
              0.0, 1.0),
    ParamSpec("require_imu", True, "drop frames without a fresh IMU attitude (else use "
              "default_roll_deg/default_pitch_deg)"),
    ParamSpec("default_roll_deg", 0.0, "attitude used when require_imu is false and no IMU", -45.0, 45.0),
    ParamSpec("default_pitch_deg", 0.0, "attitude used when require_imu is false and no IMU", -45.0, 45.0),
    ParamSpec("imu_to_camera_rpy_deg", [0.0, 0.0, 0.0],
              "roll, pitch, yaw (deg) of the camera body in the IMU body frame"),
    # --- preview
    ParamSpec("preview.track_offsets_m", [0.8, -0.8], "lateral offsets of the left, right wheel "
              "tracks (m, y left)"),
    ParamSpec("preview.tyre_width_m", 0.2, "tyre width averaged across (m)", 0.0, 2.0),
    ParamSpec("preview.spacing_m", 0.03, "spacing of the profile samples (m)", 0.001, 1.0),
    ParamSpec("preview.reference_distance_m", 0.0, "x of the point the times of arrival refer to "
              "(e.g. the front axle; m ahead of the camera)", -20.0, 50.0),
    # --- diagnostics
    ParamSpec("diagnostics_period_s", 1.0, "diagnostics publication period (s)", 0.05, 60.0),
    ParamSpec("log_throttle_s", 5.0, "minimum period between repeated warnings (s)", 0.0, 3600.0),
    # --- grid (GridSpec fields)
    ParamSpec("base_height", _G.base_height, "camera height above the road reference plane (m)",
              0.1, 10.0),
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
_BY_NAME: dict[str, ParamSpec] = {spec.name: spec for spec in PARAMETERS}


def defaults() -> dict[str, Any]:
    """Parameter name -> default value (lists copied)."""
    return {s.name: list(s.default) if isinstance(s.default, list) else s.default for s in PARAMETERS}


def _check_type(spec: ParamSpec, value: Any) -> Any:
    """``value`` coerced to the parameter's type, or ParamError."""
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
    # list of floats
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
    ):
        raise ParamError(f"{spec.name} must be a list of finite numbers, got {value!r}")
    if len(value) != len(spec.default):
        raise ParamError(f"{spec.name} needs {len(spec.default)} numbers, got {len(value)}")
    return [float(v) for v in value]


def validate_one(name: str, value: Any) -> Any:
    """One parameter checked on its own (type, range, choices); returns the coerced value.

    Raises:
        ParamError: unknown name, wrong type, out of range or not one of the choices.
    """
    spec = _BY_NAME.get(name)
    if spec is None:
        raise ParamError(f"unknown parameter {name!r}")
    value = _check_type(spec, value)
    if spec.choices is not None and value not in spec.choices:
        raise ParamError(f"{name} must be one of {', '.join(spec.choices)}; got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if spec.low is not None and value < spec.low:
            raise ParamError(f"{name} = {value} is below its minimum {spec.low}")
        if spec.high is not None and value > spec.high:
            raise ParamError(f"{name} = {value} is above its maximum {spec.high}")
    return value


def is_backend_option(name: str) -> bool:
    """Whether ``name`` is a backend option (``<backend>.<option>``)."""
    return name.startswith(BACKEND_OPTION_PREFIXES)


def backend_options(params: Mapping[str, Any], backend: str) -> dict[str, Any]:
    """The options of ``backend``: parameters ``<backend>.<option>``, plus ``checkpoint`` for
    the learned backends when it is set."""
    prefix = f"{backend}."
    options = {name[len(prefix):]: value for name, value in params.items() if name.startswith(prefix)}
    if backend in ("stereo", "mono") and params.get("checkpoint"):
        options["checkpoint"] = params["checkpoint"]
    return options


def validate(params: Mapping[str, Any], *, strict: bool = True) -> dict[str, Any]:
    """A full parameter set checked value by value and as a whole (the grid must be valid).

    Args:
        params: name -> value (missing names take their defaults). Backend options
            (``<backend>.<option>``) are kept as they are.
        strict: reject unknown names (a params file for another node's parameters is not an
            error when False; they are dropped).

    Returns:
        The complete, coerced parameter set.

    Raises:
        ParamError: the first problem found, with the parameter's name.
    """
    out = defaults()
    for name, value in params.items():
        if is_backend_option(name):
            out[name] = value
            continue
        if name not in _BY_NAME:
            if strict:
                raise ParamError(f"unknown parameter {name!r}")
            continue
        out[name] = validate_one(name, value)
    grid_from_params(out)
    if len(out["preview.track_offsets_m"]) != 2:
        raise ParamError("preview.track_offsets_m needs the left and the right track offset")
    return out
