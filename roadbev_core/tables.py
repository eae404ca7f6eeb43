"""The calibration tables shipped in ``roadbev_core/data`` (JSON), read once per process."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

__all__ = ["json_table"]


@cache
def json_table(path: Path) -> dict[str, Any]:
    """The JSON object at ``path`` ({} when the file is missing, unreadable or not an object).

    Cached by path: a table is read once per process (the calibrations do not change while the
    node runs; a caller that rewrites one passes another path)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return dict(data) if isinstance(data, dict) else {}
