"""Helpers shared by the roadbev_core tests."""

from __future__ import annotations

import numpy as np

from roadbev_core.frame import Frame


def right_of(frame: Frame) -> np.ndarray:
    """The right image of a frame the test built as stereo (fails the test on a mono frame)."""
    assert frame.right is not None, "the test needs a stereo frame"
    return frame.right
