"""Backends behind one protocol: ``estimate(frame) -> Estimate``, chosen by name.

The node, ``roadbev eval``, the demo and the benchmarks all create backends here, so a number in
one is the number in all. Each backend module registers a factory with :func:`register`; modules
are imported lazily so that choosing ``bm`` never imports torch, for example.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame

__all__ = ["Backend", "BackendError", "available", "create", "register", "takes_checkpoint"]


class BackendError(RoadbevError, RuntimeError):
    """A backend that cannot be created (unknown name, missing checkpoint, bad option)."""


@runtime_checkable
class Backend(Protocol):
    """An elevation estimator on a fixed grid."""

    name: str
    grid: GridSpec
    needs_stereo: bool

    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one frame."""
        ...


Factory = Callable[..., Backend]
_FACTORIES: dict[str, Factory] = {}
# name -> module that registers it (imported on first use)
_MODULES: dict[str, str] = {
    "bev_sweep": "roadbev_core.backends.bev_sweep",
    "sgbm": "roadbev_core.backends.image_view",
    "bm": "roadbev_core.backends.image_view",
    "stereo": "roadbev_core.backends.learned",
    "mono": "roadbev_core.backends.learned",
}
# Backends whose networks come from a checkpoint (the `checkpoint` parameter applies to them).
_LEARNED = frozenset({"stereo", "mono"})


def register(name: str) -> Callable[[Factory], Factory]:
    """Class/function decorator adding a backend factory ``factory(grid, **options)``."""

    def wrap(factory: Factory) -> Factory:
        _FACTORIES[name] = factory
        return factory

    return wrap


def available() -> list[str]:
    """Names of all known backends."""
    return sorted(_MODULES)


def takes_checkpoint(name: str) -> bool:
    """Whether backend ``name`` reads a checkpoint (the learned ones)."""
    return name in _LEARNED


def create(name: str, grid: GridSpec | None = None, **options: Any) -> Backend:
    """Create backend ``name`` for ``grid`` (default grid when None).

    Raises:
        BackendError: unknown name, or the backend refused its options.
    """
    if name not in _MODULES:
        raise BackendError(f"unknown backend {name!r}; choose from {', '.join(available())}")
    if name not in _FACTORIES:
        importlib.import_module(_MODULES[name])
    if name not in _FACTORIES:
        raise BackendError(f"backend module {_MODULES[name]} did not register {name!r}")
    try:
        return _FACTORIES[name](grid or GridSpec(), **options)
    except (TypeError, ValueError) as exc:
        raise BackendError(f"backend {name!r}: {exc}") from exc
