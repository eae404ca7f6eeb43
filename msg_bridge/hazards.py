"""Road hazards (:class:`roadbev_core.hazard_tracking.HazardReport`) <-> ``roadbev_msgs/RoadHazardArray``,
and the severity cost <-> ``nav_msgs/OccupancyGrid``.

The cost grid is the fused map's window (grid_map order: row 0 at the largest x, column 0 at the
largest y) turned into OccupancyGrid's own order: ``data[i + j * width]`` is the cell ``i``
columns along +x and ``j`` rows along +y from ``info.origin`` (the window's corner with the
smallest x and y, identity orientation), so ``width`` is the window's rows and ``height`` its
columns. Values 0..100 (100 = a feature of ``full_cost_height_m`` or more), -1 unknown.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_float,
    as_int,
    as_str,
    buffer_view,
    field,
    make_header,
    stamp_from_header,
    stamp_to_ns,
)
from roadbev_core.hazard_tracking import HazardReport, TrackedHazard, TrackRoughness

__all__ = ["DecodedHazard", "DecodedHazards", "cost_from_occupancy_grid", "hazards_from_message",
           "occupancy_grid_message", "road_hazards_message"]

MIN_SPEED_MPS = 0.1  # below this a time to arrival is NaN


def _time(factory: MessageFactory, stamp_ns: int | None) -> Any:
    sec, nanosec = divmod(int(stamp_ns or 0), 1_000_000_000)
    return factory.new("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def _hazard(factory: MessageFactory, h: TrackedHazard, speed: float) -> Any:
    eta = h.distance_ahead_m / speed if math.isfinite(speed) and speed >= MIN_SPEED_MPS else math.nan
    return factory.new(
        "roadbev_msgs/msg/RoadHazard",
        id=int(h.id), kind=h.kind,
        position=factory.new("geometry_msgs/msg/Point", x=float(h.x), y=float(h.y),
                             z=float(h.level_z) if math.isfinite(h.level_z) else 0.0),
        position_sigma=float(h.position_sigma_m), length=float(h.length_m), width=float(h.width_m),
        height=float(h.height_m), height_sigma=float(h.height_sigma_m), confidence=float(h.confidence),
        detections=int(h.detections), first_seen=_time(factory, h.first_seen_ns),
        first_reported=_time(factory, h.first_reported_ns),
        first_reported_distance=float(h.first_reported_distance_m), distance_ahead=float(h.distance_ahead_m),
        time_to_arrival=float(eta),
    )


def road_hazards_message(report: HazardReport, factory: MessageFactory, *, frame_id: str = "odom") -> Any:
    """A ``roadbev_msgs/RoadHazardArray`` of a tracker's report, stamped like its map."""
    speed = float(report.speed_mps)
    return factory.new(
        "roadbev_msgs/msg/RoadHazardArray",
        header=make_header(factory, report.stamp_ns, frame_id),
        vehicle_speed=speed,
        hazards=[_hazard(factory, h, speed) for h in report.hazards],
        roughness=[factory.new("roadbev_msgs/msg/WheelTrackRoughness", name=r.name,
                               lateral_offset=float(r.lateral_offset_m), gd_n0=float(r.gd_n0),
                               iso8608_class=r.iso_class, length=float(r.length_m)) for r in report.roughness],
    )


class DecodedHazard(NamedTuple):
    """One ``RoadHazard`` (SI units, stamps in ns)."""

    id: int
    kind: str
    x: float
    y: float
    z: float
    position_sigma_m: float
    length_m: float
    width_m: float
    height_m: float
    height_sigma_m: float
    confidence: float
    detections: int
    first_seen_ns: int
    first_reported_ns: int
    first_reported_distance_m: float
    distance_ahead_m: float
    time_to_arrival_s: float


class DecodedHazards(NamedTuple):
    """A ``RoadHazardArray``'s content."""

    stamp_ns: int
    frame_id: str
    vehicle_speed: float
    hazards: list[DecodedHazard]
    roughness: list[TrackRoughness]


def _nan_ok(value: Any, what: str) -> float:
    """A float field that may be NaN (distances without odometry), never infinite or non-numeric."""
    try:
        result = float(value)
    except (TypeError, ValueError):
        raise MessageError(f"{what} must be a number, got {value!r}") from None
    if math.isinf(result):
        raise MessageError(f"{what} must not be infinite")
    return result


def hazards_from_message(msg: Any) -> DecodedHazards:
    """The content of a ``roadbev_msgs/RoadHazardArray``.

    Raises:
        MessageError: a missing or malformed field (an unknown kind, a negative extent or sigma,
            a confidence outside 0..1, non-finite positions).
    """
    header = field(msg, "header")
    out = []
    for k, h in enumerate(field(msg, "hazards")):
        what = f"hazards[{k}]"
        kind = as_str(field(h, "kind"), f"{what}.kind")
        if kind not in ("bump", "pothole"):
            raise MessageError(f"{what}.kind must be 'bump' or 'pothole', got {kind!r}")
        p = field(h, "position")
        values = {name: as_float(field(h, name), f"{what}.{name}")
                  for name in ("position_sigma", "length", "width", "height", "height_sigma", "confidence")}
        if min(values["position_sigma"], values["length"], values["width"], values["height_sigma"]) < 0:
            raise MessageError(f"{what}: extents and sigmas must be >= 0")
        if not 0.0 <= values["confidence"] <= 1.0:
            raise MessageError(f"{what}.confidence must be in [0, 1], got {values['confidence']}")
        out.append(DecodedHazard(
            as_int(field(h, "id"), f"{what}.id"), kind, as_float(field(p, "x"), f"{what}.position.x"),
            as_float(field(p, "y"), f"{what}.position.y"), as_float(field(p, "z"), f"{what}.position.z"),
            values["position_sigma"], values["length"], values["width"], values["height"], values["height_sigma"],
            values["confidence"], as_int(field(h, "detections"), f"{what}.detections"),
            stamp_to_ns(field(h, "first_seen")), stamp_to_ns(field(h, "first_reported")),
            _nan_ok(field(h, "first_reported_distance"), f"{what}.first_reported_distance"),
            _nan_ok(field(h, "distance_ahead"), f"{what}.distance_ahead"),
            _nan_ok(field(h, "time_to_arrival"), f"{what}.time_to_arrival")))
    roughness = [TrackRoughness(as_str(field(r, "name"), f"roughness[{k}].name"),
                                as_float(field(r, "lateral_offset"), f"roughness[{k}].lateral_offset"),
                                _nan_ok(field(r, "gd_n0"), f"roughness[{k}].gd_n0"),
                                as_str(field(r, "iso8608_class"), f"roughness[{k}].iso8608_class"),
                                as_float(field(r, "length"), f"roughness[{k}].length"))
                 for k, r in enumerate(field(msg, "roughness"))]
    return DecodedHazards(stamp_from_header(msg), as_str(field(header, "frame_id"), "header.frame_id"),
                          _nan_ok(field(msg, "vehicle_speed"), "vehicle_speed"), out, roughness)


def occupancy_grid_message(cost: np.ndarray, resolution: float, centre: tuple[float, float], factory: MessageFactory,
                           *, stamp_ns: int, frame_id: str = "odom") -> Any:
    """A ``nav_msgs/OccupancyGrid`` of a cost grid [R, C] int8 in grid_map order (module docstring).

    Raises:
        MessageError: not a 2-D grid of values in -1..100, or a bad resolution.
    """
    c = np.asarray(cost)
    if c.ndim != 2 or c.size == 0 or not (math.isfinite(resolution) and resolution > 0):
        raise MessageError(f"need a non-empty [rows, cols] cost grid and a positive resolution, got {c.shape}, "
                           f"{resolution}")
    if c.min() < -1 or c.max() > 100:
        raise MessageError("OccupancyGrid values must lie in -1..100")
    n_rows, n_cols = c.shape
    occupancy = np.ascontiguousarray(c[::-1, ::-1].T.astype(np.int8))  # [C (y up), R (x up)]
    origin = factory.new(
        "geometry_msgs/msg/Pose",
        position=factory.new("geometry_msgs/msg/Point", x=float(centre[0] - 0.5 * n_rows * resolution),
                             y=float(centre[1] - 0.5 * n_cols * resolution), z=0.0),
        orientation=factory.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0))
    info = factory.new("nav_msgs/msg/MapMetaData", map_load_time=_time(factory, stamp_ns),
                       resolution=float(resolution), width=int(n_rows), height=int(n_cols), origin=origin)
    return factory.new("nav_msgs/msg/OccupancyGrid", header=make_header(factory, stamp_ns, frame_id), info=info,
                       data=factory.sequence(occupancy.reshape(-1)))


def cost_from_occupancy_grid(msg: Any) -> tuple[np.ndarray, float, tuple[float, float]]:
    """([R, C] int8 cost in grid_map order, resolution, window centre) of an OccupancyGrid written
    by :func:`occupancy_grid_message` (identity orientation).

    Raises:
        MessageError: a size that does not match ``width x height``, or a rotated origin.
    """
    info = field(msg, "info")
    width, height = as_int(field(info, "width"), "info.width"), as_int(field(info, "height"), "info.height")
    res = as_float(field(info, "resolution"), "info.resolution")
    if res <= 0:
        raise MessageError(f"info.resolution must be > 0, got {res}")
    q = field(field(info, "origin"), "orientation")
    if abs(abs(as_float(field(q, "w"), "info.origin.orientation.w")) - 1.0) > 1e-6:
        raise MessageError("a rotated OccupancyGrid origin is not supported")
    data = buffer_view(field(msg, "data"), np.int8, "data")
    if data.size != width * height:
        raise MessageError(f"data holds {data.size} cells, width x height = {width * height}")
    p = field(field(info, "origin"), "position")
    cost = data.reshape(height, width).T[::-1, ::-1]  # back to [R (x down), C (y down)]
    centre = (as_float(field(p, "x"), "info.origin.position.x") + 0.5 * width * res,
              as_float(field(p, "y"), "info.origin.position.y") + 0.5 * height * res)
    return np.ascontiguousarray(cost), res, centre
