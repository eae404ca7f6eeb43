"""ROS 2 test set-up: a private DDS domain per test session, the large-image DDS profile.

Several sessions run ROS tests on this machine at once; a random ``ROS_DOMAIN_ID`` per session
(set before anything imports rclpy) and localhost-only discovery keep them from hearing each
other. Processes the tests start inherit both.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from typing import Any

import pytest

if "ROADBEV_TEST_DOMAIN_ID" not in os.environ:
    os.environ["ROADBEV_TEST_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
os.environ["ROS_DOMAIN_ID"] = os.environ["ROADBEV_TEST_DOMAIN_ID"]
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "soak: long-running memory soak test (deselect with -m 'not soak')")


@pytest.fixture(scope="session")
def ros() -> Iterator[Any]:
    """rclpy initialised once for the session (with the DDS profile), shut down at the end."""
    from roadbev_ros.dds import init_ros

    rclpy = init_ros()
    yield rclpy
    rclpy.try_shutdown()
