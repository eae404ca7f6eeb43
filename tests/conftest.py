"""Shared test set-up: deterministic, denormal-free torch; paths to shared data; a private DDS
domain per test session; both message factories.

Several sessions run ROS tests on this machine at once; a random ``ROS_DOMAIN_ID`` per session
(set before anything imports rclpy) and localhost-only discovery keep them from hearing each
other. Processes the tests start inherit both.
"""

from __future__ import annotations

import importlib.util
import os
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from msg_bridge import MessageFactory, RclpyFactory, bag_factory
from tests.msg_bridge._msg_bridge_fakes import FakeDrive

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
RSRD = SHARED / "rsrd"

os.environ.setdefault("MPLBACKEND", "Agg")
if "ROADBEV_TEST_DOMAIN_ID" not in os.environ:
    os.environ["ROADBEV_TEST_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
os.environ["ROS_DOMAIN_ID"] = os.environ["ROADBEV_TEST_DOMAIN_ID"]
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

try:  # torch is optional for the pure-numpy tests
    import torch

    torch.set_flush_denormal(True)
    torch.set_num_threads(2)
except ImportError:  # pragma: no cover
    pass


RAY_MISSING = "Ray is not installed (the fleet extra: pip install .[fleet])"


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[Any]:
    """``ray`` joined to a local cluster with 2 CPUs (two task workers) for the session, shut down at
    the end; the tests that need it skip (with the reason) where Ray is not installed."""
    if importlib.util.find_spec("ray") is None:
        pytest.skip(RAY_MISSING)
    # Ray is the fleet extra: only the tests that ask for a cluster load it
    import ray

    # the workers import the project as this process does (PYTHONPATH), and report no usage
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.fixture(scope="session")
def rsrd_dir() -> Path:
    if not RSRD.is_dir():
        pytest.skip(f"real RSRD metadata not found at {RSRD}")
    return RSRD


KITTI = SHARED / "realdata" / "kitti"


@pytest.fixture(scope="session")
def kitti_dir() -> Path:
    """The three real KITTI frames (at ``KITTI``, beside the repository; a test set: never tune on it)."""
    if not (KITTI / "stereo_rcnn_demo" / "demo" / "lidar.bin").is_file():
        pytest.skip(f"real KITTI frames not found at {KITTI}")
    return KITTI


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Every matplotlib Figure saved during the test, drawn first (artists laid out), in order:
    the figure functions return a path, and a test that looks at the artists reads them here."""
    from matplotlib.figure import Figure

    saved: list[Any] = []
    original = Figure.savefig

    def keep(fig: Figure, *args: Any, **kwargs: Any) -> None:
        fig.canvas.draw()
        saved.append(fig)
        original(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "soak: long-running memory soak test (deselect with -m 'not soak')")


@pytest.fixture(scope="session")
def ros() -> Iterator[Any]:
    """rclpy initialised once for the session (with the DDS profile), shut down at the end."""
    from roadbev_ros.dds import init_ros

    rclpy = init_ros()
    yield rclpy
    rclpy.try_shutdown()


@pytest.fixture
def fake_drive() -> FakeDrive:
    return FakeDrive()


@pytest.fixture(params=["rclpy", "typestore"])
def factory(request: pytest.FixtureRequest) -> MessageFactory:
    """Both message factories: every converter must work on both libraries' messages."""
    return RclpyFactory() if request.param == "rclpy" else bag_factory()
