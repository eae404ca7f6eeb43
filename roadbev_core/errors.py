"""The project's error hierarchy: one root, :class:`RoadbevError`, for every refusal of bad input.

Each package keeps its own typed errors next to the code that raises them (``ConfigError`` in
:mod:`roadbev_core.config`, ``BagError`` in :mod:`msg_bridge.bag`, ...), all derived from
:class:`RoadbevError`. Most also derive from the built-in class they always were (``ValueError``
or ``RuntimeError``), so callers that caught those keep working.

The command line turns a :class:`RoadbevError` into a one-line message and a non-zero exit;
anything else (a programming error) keeps its traceback, so bugs are not reported as bad input.
"""

from __future__ import annotations

__all__ = ["RoadbevError"]


class RoadbevError(Exception):
    """Bad input, refused with a reason a user can act on (the root of the project's errors)."""
