"""Ride: what a road preview is worth to a suspension controller (issue 22).

A quarter-car ride model (:class:`QuarterCar`), the ISO 2631-1 Wk comfort weighting
(:class:`WkFilter`, :func:`weighted_rms`), the optimal linear preview controller of Bender
(1968) and Tomizuka (1976) in discrete time (:class:`PreviewLqr`), and the pure simulation
that rides it over a drive's true road fed by a preview source (:func:`ride`). ROS-free, pure
numpy; ``roadbev_ros.preview_controller`` runs the same controller on ``/roadbev/preview``.
"""

from __future__ import annotations

from roadbev_core.ride.iso2631 import WK_TABLE, WeightingError, WkFilter, weighted_rms, wk_response
from roadbev_core.ride.lti import LtiError, discretise, expm_integral, solve_dare
from roadbev_core.ride.online import HeldPreview, OnlinePreviewController, WheelCommand
from roadbev_core.ride.preview_gain import PreviewGain, preview_gains
from roadbev_core.ride.preview_lqr import LqrWeights, PreviewLqr
from roadbev_core.ride.quarter_car import GRAVITY, QuarterCar, RideError
from roadbev_core.ride.simulate import (
    FRONT_WHEELS,
    RideMetrics,
    RideSettings,
    WheelRoad,
    carried_plane_slopes,
    gain_share,
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
    "FRONT_WHEELS",
    "GRAVITY",
    "WK_TABLE",
    "HeldPreview",
    "LqrWeights",
    "LtiError",
    "OnlinePreviewController",
    "PreviewGain",
    "PreviewLqr",
    "QuarterCar",
    "RideError",
    "RideMetrics",
    "RideSettings",
    "WeightingError",
    "WheelCommand",
    "WheelRoad",
    "WkFilter",
    "carried_plane_slopes",
    "discretise",
    "expm_integral",
    "gain_share",
    "perfect_map_previews",
    "perfect_previews",
    "preview_feedforward",
    "preview_gains",
    "ride",
    "ride_metrics",
    "simulate",
    "solve_dare",
    "true_contact_planes",
    "true_plane_slopes",
    "weighted_rms",
    "wheel_road",
    "wk_response",
]
