"""The errors of bag reading and writing."""

from __future__ import annotations

from roadbev_core.errors import RoadbevError

__all__ = ["BagError", "DamagedBagError"]


class BagError(RoadbevError, ValueError):
    """A bag that cannot be read or written; names the file and what went wrong."""


class DamagedBagError(BagError):
    """A bag with a damaged, cut or unfinished part, met while reading with ``on_damage="raise"``.

    Attributes:
        damage: the damaged part(s), as lines naming the file, the chunk and the reason.
    """

    def __init__(self, message: str, damage: list[str]) -> None:
        super().__init__(message)
        self.damage = damage
