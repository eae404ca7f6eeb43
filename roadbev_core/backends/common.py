"""Small helpers shared by the classical backends: stage timing and grey conversion."""

from __future__ import annotations

import time

import cv2
import numpy as np

__all__ = ["StageClock", "grey_u8"]


class StageClock:
    """Accumulates the wall time between successive :meth:`lap` calls under stage names (ms)."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Charge the time since the previous lap (or creation) to ``stage``."""
        now = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + 1000.0 * (now - self._last)
        self._last = now


def grey_u8(image: np.ndarray) -> np.ndarray:
    """[H, W] uint8 grey of an RGB [H, W, 3] or grey [H, W] uint8 image (contiguous)."""
    if image.ndim == 3:
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(image)
