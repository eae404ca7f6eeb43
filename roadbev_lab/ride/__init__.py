"""The ride simulation that scores a preview: what it is worth to a suspension controller.

The pure simulation that rides the runtime's controller (:mod:`roadbev_core.ride`) over a drive's
true road fed by a preview source (:func:`ride`), and the ISO 2631-1 Wk comfort weighting
(:class:`WkFilter`, :func:`weighted_rms`) that scores the ride. ROS-free, pure numpy.
"""

from __future__ import annotations

from roadbev_lab.ride.iso2631 import (
    WK_TABLE,
    WeightingError,
    WkFilter,
    weighted_rms,
    wk_response,
)
from roadbev_lab.ride.simulate import (
    RideMetrics,
    RideSettings,
    WheelRoad,
    carried_plane_slopes,
    gain_share,
    hidden_from,
    perfect_map_previews,
    perfect_previews,
    preview_feedforward,
    ride,
    ride_metrics,
    simulate,
    true_contact_planes,
    true_plane_slopes,
    wheel_road,
)

__all__ = [
    "WK_TABLE",
    "RideMetrics",
    "RideSettings",
    "WeightingError",
    "WheelRoad",
    "WkFilter",
    "carried_plane_slopes",
    "gain_share",
    "hidden_from",
    "perfect_map_previews",
    "perfect_previews",
    "preview_feedforward",
    "ride",
    "ride_metrics",
    "simulate",
    "true_contact_planes",
    "true_plane_slopes",
    "weighted_rms",
    "wheel_road",
    "wk_response",
]
