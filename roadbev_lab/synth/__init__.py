"""Realistic synthetic stereo road data: height fields, textures, a ray-casting renderer, drives.

Public API (``shared`` agreement, see the project notes)::

    from roadbev_lab.synth import RoadConfig, DriveConfig, SyntheticDrive, DriveSample, ImuSample, make_sample
    from roadbev_lab.synth import RidingConfig, RidingDrive  # a car riding on its road (drive bags)
"""

from __future__ import annotations

from roadbev_core.roughness import ISO8608_GD0
from roadbev_lab.synth.appearance import (
    APPEARANCE_NAMES,
    APPEARANCE_RANGES,
    CLEAN,
    DEFAULT_APPEARANCE,
    REAL_ROAD,
    REAL_ROAD_MIDDLE,
    Appearance,
    AppearanceRange,
    appearance_range,
)
from roadbev_lab.synth.drive import (
    RSRD_ATTITUDE,
    DriveConfig,
    DriveSample,
    ImuSample,
    LidarConfig,
    SyntheticDrive,
    make_sample,
    random_road,
    slerp,
)
from roadbev_lab.synth.heightfield import FEATURE_NAMES, SynthError
from roadbev_lab.synth.render import CameraPose, render_view
from roadbev_lab.synth.riding import OdometryNoise, RidingConfig, RidingDrive, SuspensionSpec
from roadbev_lab.synth.scene import RoadConfig, Scene, build_scene

__all__ = [
    "APPEARANCE_NAMES",
    "APPEARANCE_RANGES",
    "CLEAN",
    "DEFAULT_APPEARANCE",
    "FEATURE_NAMES",
    "ISO8608_GD0",
    "REAL_ROAD",
    "REAL_ROAD_MIDDLE",
    "RSRD_ATTITUDE",
    "Appearance",
    "AppearanceRange",
    "CameraPose",
    "DriveConfig",
    "DriveSample",
    "ImuSample",
    "LidarConfig",
    "OdometryNoise",
    "RidingConfig",
    "RidingDrive",
    "RoadConfig",
    "Scene",
    "SuspensionSpec",
    "SynthError",
    "SyntheticDrive",
    "appearance_range",
    "build_scene",
    "make_sample",
    "random_road",
    "render_view",
    "slerp",
]
