"""Where the package's shared files are (``config/``, ``checkpoints/``): the source tree (or an
editable install), the virtual environment's prefix, or the ament prefixes of a colcon install
(``<prefix>/share/roadbev_ros/...``), in that order, as ament_index looks a package's share up."""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["PACKAGE", "find_shared", "shared_candidates"]

PACKAGE = "roadbev_ros"  # the ROS package whose share directory holds them


def shared_candidates(relative: str) -> list[Path]:
    """Every place ``relative`` (e.g. ``config/fastdds.xml``) may be, first the source tree."""
    paths = [Path(__file__).resolve().parents[1] / relative]
    paths.append(Path(sys.prefix) / "share" / PACKAGE / relative)
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            paths.append(Path(prefix) / "share" / PACKAGE / relative)
    return paths


def find_shared(relative: str) -> Path | None:
    """The first of :func:`shared_candidates` that exists, or None."""
    return next((path for path in shared_candidates(relative) if path.exists()), None)
