"""Wheel-track profiles (:class:`roadbev_core.preview.PreviewProfiles`) <-> ``roadbev_msgs/RoadPreview``.

``vehicle_speed`` is NaN in the message when unknown, and ``time_of_arrival`` is then empty;
otherwise it holds ``(x_i - reference_distance) / vehicle_speed`` per sample.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_float,
    as_str,
    buffer_view,
    field,
    make_header,
    stamp_from_header,
)
from msg_bridge.grid_map import ROAD_FRAME
from roadbev_core.preview import (
    REFERENCE_CONTACT_PLANE,
    REFERENCE_ROAD,
    ContactPlane,
    PreviewError,
    PreviewProfiles,
    TrackProfile,
)

__all__ = ["DecodedPreview", "preview_from_message", "road_preview_message"]


class DecodedPreview(NamedTuple):
    """A RoadPreview message's content."""

    profiles: PreviewProfiles
    time_of_arrival: np.ndarray | None
    stamp_ns: int
    frame_id: str


# RoadPreview field suffix -> ContactPlane attribute
_PLANE_FIELDS = (("height", "height_m"), ("roll", "roll"), ("pitch", "pitch"), ("height_sigma", "height_sigma_m"),
                 ("roll_sigma", "roll_sigma"), ("pitch_sigma", "pitch_sigma"))


def road_preview_message(
    profiles: PreviewProfiles,
    factory: MessageFactory,
    *,
    stamp_ns: int,
    frame_id: str = ROAD_FRAME,
) -> Any:
    """A ``roadbev_msgs/RoadPreview`` holding ``profiles``."""
    arrival = profiles.time_of_arrival()
    tracks = [
        factory.new(
            "roadbev_msgs/msg/WheelTrackProfile",
            name=t.name,
            lateral_offset=float(t.lateral_offset),
            width=float(t.width),
            elevation=factory.sequence(np.asarray(t.elevation, dtype=np.float32)),
            uncertainty=factory.sequence(np.asarray(t.uncertainty, dtype=np.float32)),
        )
        for t in profiles.tracks
    ]
    speed = math.nan if profiles.vehicle_speed is None else float(profiles.vehicle_speed)
    plane = profiles.contact_plane
    plane_fields = {f"contact_plane_{name}": 0.0 if plane is None else float(getattr(plane, attr))
                    for name, attr in _PLANE_FIELDS}
    return factory.new(
        "roadbev_msgs/msg/RoadPreview",
        header=make_header(factory, stamp_ns, frame_id),
        reference=profiles.reference,
        **plane_fields,
        contact_plane_source="" if plane is None else plane.source,
        start_distance=float(profiles.start_distance),
        spacing=float(profiles.spacing),
        vehicle_speed=speed,
        reference_distance=float(profiles.reference_distance),
        time_of_arrival=factory.sequence(
            np.zeros(0, np.float32) if arrival is None else arrival.astype(np.float32)
        ),
        tracks=tracks,
    )


def preview_from_message(msg: Any) -> DecodedPreview:
    """Decode a RoadPreview.

    Raises:
        MessageError: non-positive spacing, tracks of different lengths, elevation and
            uncertainty of different lengths, or times of arrival that do not match the samples.
    """
    stamp_ns = stamp_from_header(msg)
    frame_id = as_str(field(field(msg, "header"), "frame_id"), "RoadPreview.header.frame_id")
    speed_value = field(msg, "vehicle_speed")
    unknown = isinstance(speed_value, (float, np.floating)) and math.isnan(speed_value)  # NaN: unknown
    speed = None if unknown else as_float(speed_value, "RoadPreview.vehicle_speed")
    tracks = []
    for t in field(msg, "tracks"):
        name = as_str(field(t, "name"), "WheelTrackProfile.name")
        elevation = buffer_view(field(t, "elevation"), np.float32, f"track {name!r} elevation")
        sigma = buffer_view(field(t, "uncertainty"), np.float32, f"track {name!r} uncertainty")
        if elevation.shape != sigma.shape:
            raise MessageError(
                f"track {name!r} has {elevation.size} elevations but {sigma.size} uncertainties"
            )
        tracks.append(
            TrackProfile(
                name=name,
                lateral_offset=as_float(field(t, "lateral_offset"), f"track {name!r} lateral_offset"),
                width=as_float(field(t, "width"), f"track {name!r} width"),
                elevation=elevation,
                uncertainty=sigma,
            )
        )
    reference = as_str(field(msg, "reference"), "RoadPreview.reference") or REFERENCE_ROAD
    if reference not in (REFERENCE_ROAD, REFERENCE_CONTACT_PLANE):
        raise MessageError(f"RoadPreview.reference {reference!r} is neither {REFERENCE_ROAD!r} nor "
                           f"{REFERENCE_CONTACT_PLANE!r}")
    plane = None
    if reference == REFERENCE_CONTACT_PLANE:
        values = {attr: as_float(field(msg, f"contact_plane_{name}"), f"RoadPreview.contact_plane_{name}")
                  for name, attr in _PLANE_FIELDS}
        if not all(math.isfinite(v) for v in values.values()):
            raise MessageError("RoadPreview: the contact plane is not finite")
        plane = ContactPlane(**values, source=as_str(field(msg, "contact_plane_source"),
                                                     "RoadPreview.contact_plane_source"))
    try:
        profiles = PreviewProfiles(
            start_distance=as_float(field(msg, "start_distance"), "RoadPreview.start_distance"),
            spacing=as_float(field(msg, "spacing"), "RoadPreview.spacing"),
            tracks=tuple(tracks),
            vehicle_speed=speed,
            reference_distance=as_float(field(msg, "reference_distance"), "RoadPreview.reference_distance"),
            reference=reference,
            contact_plane=plane,
        )
    except PreviewError as exc:
        raise MessageError(f"RoadPreview: {exc}") from None
    arrival = buffer_view(field(msg, "time_of_arrival"), np.float32, "RoadPreview.time_of_arrival")
    if arrival.size and arrival.size != profiles.n_samples:
        raise MessageError(
            f"RoadPreview has {arrival.size} times of arrival for {profiles.n_samples} samples"
        )
    return DecodedPreview(profiles, arrival if arrival.size else None, stamp_ns, frame_id)
