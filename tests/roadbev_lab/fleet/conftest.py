"""A local Ray cluster of two worker processes, started once for the fleet tests that need it."""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Iterator
from typing import Any

import pytest

RAY_MISSING = "Ray is not installed (the fleet extra: pip install .[fleet])"


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[Any]:
    """``ray`` joined to a local cluster with 2 CPUs (two task workers), shut down at the end."""
    if importlib.util.find_spec("ray") is None:
        pytest.skip(RAY_MISSING)
    import ray

    # the workers import the project as this process does (PYTHONPATH), and report no usage
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()
