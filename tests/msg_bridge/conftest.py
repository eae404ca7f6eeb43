"""Fixtures of the msg_bridge tests."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from ._msg_bridge_fakes import FakeDrive

if TYPE_CHECKING:
    from msg_bridge import MessageFactory


@pytest.fixture
def fake_drive() -> FakeDrive:
    return FakeDrive()


@pytest.fixture(params=["rclpy", "typestore"])
def factory(request: pytest.FixtureRequest) -> MessageFactory:
    """Both message factories: every converter must work on both libraries' messages."""
    from msg_bridge import RclpyFactory, bag_factory

    return RclpyFactory() if request.param == "rclpy" else bag_factory()
