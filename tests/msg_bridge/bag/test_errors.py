"""The bag errors: one family the callers catch, the damage kept on the error."""

from __future__ import annotations

from msg_bridge.bag.errors import BagError, DamagedBagError
from roadbev_core.errors import RoadbevError


def test_a_damaged_bag_error_is_a_bag_error_that_keeps_the_damage() -> None:
    error = DamagedBagError("a.mcap: chunk 2 at byte 10: CRC mismatch", ["a.mcap: chunk 2 at byte 10: CRC mismatch"])
    assert isinstance(error, BagError) and isinstance(error, RoadbevError) and isinstance(error, ValueError)
    assert str(error) == "a.mcap: chunk 2 at byte 10: CRC mismatch"
    assert error.damage == ["a.mcap: chunk 2 at byte 10: CRC mismatch"]
