"""Process-wide compute settings, applied by the pipeline (never at import).

* threads: OpenCV's and torch's intra-op pools. On a loaded machine a parallel section waits for
  its slowest thread, and a node's executor thread needs a core for the callbacks: on a 2-core
  CPU one torch thread runs bev_sweep faster inside the node than two.
* denormals: random or lightly trained weights produce denormal floats that make CPU inference
  several times slower and erratic; flushing them to zero is a
  per-thread CPU flag, so it is set in every thread that runs a backend.
"""

from __future__ import annotations

import os
import sys

import cv2

__all__ = ["configure_threads", "flush_denormals", "resolve_threads"]


def resolve_threads(threads: int) -> int:
    """``threads``, or one less than the CPU cores (at least 1) for 0."""
    return threads if threads > 0 else max(1, (os.cpu_count() or 2) - 1)


def configure_threads(threads: int) -> int:
    """Set OpenCV's and (if loaded) torch's thread count; 0 = cores - 1.

    torch is only touched when a backend has imported it: choosing ``bm`` never imports torch.

    Returns:
        The number of threads set.
    """

    n = resolve_threads(threads)
    cv2.setNumThreads(n)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
    return n


def flush_denormals() -> None:
    """Flush denormal floats to zero in the calling thread (when torch is in use)."""
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_flush_denormal(True)
