"""Progress bars on stderr, drawn only on a terminal (the CLI's commands and the demo)."""

from __future__ import annotations

import sys
from typing import NoReturn

from tqdm import tqdm

__all__ = ["progress_bar"]


def progress_bar(*, unit: str, desc: str, total: int | None = None, disable: bool = False,
                 leave: bool = True) -> tqdm[NoReturn]:
    """A tqdm bar on stderr counting ``unit`` (one unit per bar), drawn only when stderr is a
    terminal (never ``\\r`` lines in a CI log); a disabled bar accepts ``update`` all the same."""
    return tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, leave=leave,
                disable=disable or not sys.stderr.isatty())
