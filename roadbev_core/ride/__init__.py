"""Ride: the reference preview controller a suspension runs on ``/roadbev/preview``.

A quarter-car ride model (:class:`QuarterCar`), the optimal linear preview controller of Bender
(1968) and Tomizuka (1976) in discrete time (:class:`PreviewLqr`), the preview's gain measured on
the road ridden (:class:`PreviewGain`) and the online controller that holds the latest previews
(:class:`OnlinePreviewController`). ROS-free, pure numpy; ``roadbev_ros.preview_controller`` runs
it on ``/roadbev/preview``. The offline ride simulation and the ISO 2631-1 comfort weighting that
score a preview are the lab's (:mod:`roadbev_lab.ride`).
"""

from __future__ import annotations

from roadbev_core.ride.lti import LtiError, discretise, expm_integral, solve_dare
from roadbev_core.ride.online import HeldPreview, OnlinePreviewController, WheelCommand
from roadbev_core.ride.preview_gain import PreviewGain, preview_gains
from roadbev_core.ride.preview_lqr import LqrWeights, PreviewLqr
from roadbev_core.ride.quarter_car import FRONT_WHEELS, GRAVITY, QuarterCar, RideError

__all__ = [
    "FRONT_WHEELS",
    "GRAVITY",
    "HeldPreview",
    "LqrWeights",
    "LtiError",
    "OnlinePreviewController",
    "PreviewGain",
    "PreviewLqr",
    "QuarterCar",
    "RideError",
    "WheelCommand",
    "discretise",
    "expm_integral",
    "preview_gains",
    "solve_dare",
]
