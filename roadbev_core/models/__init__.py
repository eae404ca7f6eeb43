"""RoadBEV-mono and RoadBEV-stereo (paper section 4): backbone, voxel query, heads, loss, presets.

Importing this package imports torch; the classical backends never do.
"""

from __future__ import annotations

from roadbev_core.models.presets import KINDS, PRESETS, ModelConfig, model_config
from roadbev_core.models.roadbev import ModelInputError, Prediction, RoadBEV, prepare_image

__all__ = [
    "KINDS",
    "PRESETS",
    "ModelConfig",
    "ModelInputError",
    "Prediction",
    "RoadBEV",
    "model_config",
    "prepare_image",
]
