"""Viewer markers (``visualization_msgs/MarkerArray``) of the preview and of the hazards, for RViz
and Foxglove, which show neither ``roadbev_msgs`` message by themselves.

Every array starts with a ``DELETEALL`` marker, so a viewer shows exactly the latest array (a
track that lost its samples, a hazard that was retired, disappear with the next message).

:func:`preview_markers`: one ``LINE_STRIP`` per wheel track (namespace: the track's name), in the
preview's frame (``roadbev_road`` for per-frame previews, ``base_link`` for contact-plane ones):
sample i at ``(x_i, lateral_offset, z_i)`` with ``x_i = start_distance + i * spacing``. z is the
previewed height, and for a contact-plane preview the height plus the contact plane's own height
at (x, y) (:meth:`roadbev_core.preview.ContactPlane.height_at`, the plane the message carries),
so the strips follow the road the tyres stand on (its height and tilt under the car) instead of
``base_link``'s own ground plane, which heaves and pitches with the body. A sample without a
height or without a σ (NaN) breaks the strip: each run of two or more known samples is a strip of
its own (ids 0, 1, ... in the track's namespace); a lone known sample between two gaps is not
drawn. Each point is coloured by its σ (:func:`sigma_colours`).

:func:`hazard_markers`: per reported hazard (ids: the hazard's tracking id, stable while it is
tracked), in the map's frame: a ``CUBE`` (namespace ``hazards``) spanning the hazard's length and
width along the frame's x and y, from the road's level under it up to its crest (a bump) or down to
its floor (a pothole), red for bumps and blue for potholes (as the demo report's figures), its
alpha ``HAZARD_MIN_ALPHA + (1 - HAZARD_MIN_ALPHA) * confidence`` so an unconfident hazard is faint
but never invisible; and a ``TEXT_VIEW_FACING`` label (namespace ``hazard_labels``) above it with
the kind, the signed height in cm and the confidence.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from msg_bridge._common import MessageError, MessageFactory, make_header
from roadbev_core.hazard_tracking import HazardReport, TrackedHazard
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, PreviewProfiles

__all__ = [
    "BUMP_RGB",
    "HAZARD_MIN_ALPHA",
    "POTHOLE_RGB",
    "PREVIEW_LINE_WIDTH_M",
    "hazard_markers",
    "preview_markers",
    "sigma_colours",
]

# visualization_msgs/Marker types and actions
LINE_STRIP = 4
CUBE = 1
TEXT_VIEW_FACING = 9
ADD = 0
DELETEALL = 3

PREVIEW_LINE_WIDTH_M = 0.05  # narrower than a tyre: the strips of neighbouring tracks stay apart
BUMP_RGB = (0.9, 0.15, 0.1)
POTHOLE_RGB = (0.15, 0.35, 0.95)
HAZARD_MIN_ALPHA = 0.25  # the alpha of a hazard of confidence 0
HAZARD_MIN_EXTENT_M = 0.01  # a box's smallest edge, so a flat or thin hazard still shows
LABEL_HEIGHT_M = 0.2  # the labels' text height
LABEL_CLEARANCE_M = 0.15  # between a hazard's top and its label


def sigma_colours(sigma: np.ndarray, sigma_max_m: float) -> np.ndarray:
    """The preview markers' colour scale: [N] σ (m) -> [N, 3] RGB in 0..1.

    Green at σ = 0, yellow at ``sigma_max_m / 2``, red from ``sigma_max_m`` up, linear in σ
    between (red rises over the first half, green falls over the second). NaN σ is red.

    Raises:
        MessageError: a ``sigma_max_m`` that is not positive and finite.
    """
    if not (math.isfinite(sigma_max_m) and sigma_max_m > 0):
        raise MessageError(f"the σ colour scale needs a positive sigma_max_m, got {sigma_max_m}")
    t = np.clip(np.nan_to_num(np.asarray(sigma, np.float64) / sigma_max_m, nan=1.0), 0.0, 1.0)  # [N]
    rgb = np.zeros((*t.shape, 3))  # [N, 3]
    rgb[..., 0] = np.minimum(1.0, 2.0 * t)
    rgb[..., 1] = np.minimum(1.0, 2.0 * (1.0 - t))
    return rgb


def _colour(factory: MessageFactory, rgb: Any, alpha: float = 1.0) -> Any:
    return factory.new("std_msgs/msg/ColorRGBA", r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(alpha))


def _point(factory: MessageFactory, x: float, y: float, z: float) -> Any:
    return factory.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=float(z))


def _pose(factory: MessageFactory, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return factory.new("geometry_msgs/msg/Pose", position=_point(factory, x, y, z),
                       orientation=factory.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0))


def _vector(factory: MessageFactory, x: float, y: float, z: float) -> Any:
    return factory.new("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def _delete_all(factory: MessageFactory, header: Any) -> Any:
    return factory.new("visualization_msgs/msg/Marker", header=header, action=DELETEALL,
                       pose=_pose(factory), scale=_vector(factory, 1.0, 1.0, 1.0))


def _runs(known: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of two or more True in ``known`` [N]."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], known.astype(np.int8), [0]))))  # [2 * runs]
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 2]


def preview_markers(profiles: PreviewProfiles, factory: MessageFactory, *, stamp_ns: int, frame_id: str,
                    sigma_max_m: float) -> Any:
    """A ``visualization_msgs/MarkerArray`` of the preview's wheel tracks (module docstring).

    Args:
        profiles: the preview.
        stamp_ns, frame_id: the preview message's stamp and frame.
        sigma_max_m: the σ drawn red (:func:`sigma_colours`).

    Raises:
        MessageError: a ``sigma_max_m`` that is not positive and finite.
    """
    header = make_header(factory, stamp_ns, frame_id)
    x = profiles.distances()  # [N]
    plane = profiles.contact_plane if profiles.reference == REFERENCE_CONTACT_PLANE else None
    markers = [_delete_all(factory, header)]
    for track in profiles.tracks:
        height = np.asarray(track.elevation, np.float64)  # [N]
        sigma = np.asarray(track.uncertainty, np.float64)  # [N]
        z = height if plane is None else height + plane.height_at(x, np.full_like(x, track.lateral_offset))
        rgb = sigma_colours(sigma, sigma_max_m)  # [N, 3]
        for k, (a, b) in enumerate(_runs(np.isfinite(z) & np.isfinite(sigma))):
            markers.append(factory.new(
                "visualization_msgs/msg/Marker", header=header, ns=track.name, id=k, type=LINE_STRIP, action=ADD,
                pose=_pose(factory), scale=_vector(factory, PREVIEW_LINE_WIDTH_M, 0.0, 0.0),
                color=_colour(factory, (1.0, 1.0, 1.0)),
                points=[_point(factory, x[i], track.lateral_offset, z[i]) for i in range(a, b)],
                colors=[_colour(factory, rgb[i]) for i in range(a, b)]))
    return factory.new("visualization_msgs/msg/MarkerArray", markers=markers)


def _hazard_box_and_label(factory: MessageFactory, header: Any, h: TrackedHazard) -> tuple[Any, Any]:
    level = float(h.level_z) if math.isfinite(h.level_z) else 0.0
    height = float(h.height_m)
    confidence = min(max(float(h.confidence), 0.0), 1.0)
    alpha = HAZARD_MIN_ALPHA + (1.0 - HAZARD_MIN_ALPHA) * confidence
    box = factory.new(
        "visualization_msgs/msg/Marker", header=header, ns="hazards", id=int(h.id), type=CUBE, action=ADD,
        pose=_pose(factory, h.x, h.y, level + 0.5 * height),
        scale=_vector(factory, max(float(h.length_m), HAZARD_MIN_EXTENT_M), max(float(h.width_m), HAZARD_MIN_EXTENT_M),
                      max(abs(height), HAZARD_MIN_EXTENT_M)),
        color=_colour(factory, BUMP_RGB if h.kind == "bump" else POTHOLE_RGB, alpha))
    label = factory.new(
        "visualization_msgs/msg/Marker", header=header, ns="hazard_labels", id=int(h.id), type=TEXT_VIEW_FACING,
        action=ADD, pose=_pose(factory, h.x, h.y, level + max(height, 0.0) + LABEL_CLEARANCE_M + 0.5 * LABEL_HEIGHT_M),
        scale=_vector(factory, 0.0, 0.0, LABEL_HEIGHT_M), color=_colour(factory, (1.0, 1.0, 1.0)),
        text=f"{h.kind} {height * 100:+.1f} cm\nconfidence {confidence:.2f}")
    return box, label


def hazard_markers(report: HazardReport, factory: MessageFactory, *, frame_id: str = "odom") -> Any:
    """A ``visualization_msgs/MarkerArray`` of a tracker's reported hazards (module docstring),
    stamped like its map."""
    header = make_header(factory, report.stamp_ns, frame_id)
    markers = [_delete_all(factory, header)]
    for h in report.hazards:
        markers.extend(_hazard_box_and_label(factory, header, h))
    return factory.new("visualization_msgs/msg/MarkerArray", markers=markers)
