"""Backends behind one protocol: ``estimate(frame) -> Estimate``, chosen by name.

The node, ``roadbev eval``, the demo and the benchmarks all create backends here, so a number in
one is the number in all. Each backend module registers a factory with :func:`register`; modules
are imported lazily so that choosing ``bm`` never imports torch, for example.

Every backend :func:`create` makes answers through :class:`RefinedBackend`: its estimates pass
through :func:`roadbev_core.uncertainty.refine` (cells hidden behind a crest become NaN; sigma
is the backend's calibrated model from ``roadbev_core/data/sigma_calibration.json``), one step for
all backends (an ``ensemble``'s members each, not the ensemble again). ``create(..., raw=True)``
gives the backend's own answer (used to calibrate).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Estimate, Frame

__all__ = ["Backend", "BackendError", "RefinedBackend", "available", "create", "register", "takes_checkpoint"]


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
    "ensemble": "roadbev_core.backends.ensemble",
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


class RefinedBackend:
    """A backend whose estimates pass through :func:`roadbev_core.uncertainty.refine`.

    Attributes other than the protocol's (``describe``, ``checkpoint``, ``params``...) are the
    wrapped backend's (``inner``).
    """

    def __init__(self, inner: Backend) -> None:
        from roadbev_core.uncertainty import calibration_for

        self.inner = inner
        self.name = inner.name
        self.grid = inner.grid
        self.needs_stereo = inner.needs_stereo
        self.sigma_model = calibration_for(inner.name)

    def estimate(self, frame: Frame) -> Estimate:
        """The wrapped backend's estimate, hidden cells NaN and sigma calibrated."""
        from roadbev_core.uncertainty import refine

        raw = self.inner.estimate(frame)
        start = time.perf_counter()
        model = None if raw.out_of_distribution else self.sigma_model
        out = refine(raw, frame, self.grid, stereo=self.needs_stereo, model=model)
        out.out_of_distribution = raw.out_of_distribution
        out.timings_ms["postprocess"] = out.timings_ms.get("postprocess", 0.0) + 1000.0 * (time.perf_counter() - start)
        return out

    def __getattr__(self, attribute: str) -> Any:
        if attribute == "inner":  # not set yet (during unpickling): no recursion
            raise AttributeError(attribute)
        return getattr(self.inner, attribute)


def takes_checkpoint(name: str) -> bool:
    """Whether backend ``name`` reads a checkpoint (the learned ones)."""
    return name in _LEARNED


def create(name: str, grid: GridSpec | None = None, *, raw: bool = False, **options: Any) -> Backend:
    """Create backend ``name`` for ``grid`` (default grid when None).

    Args:
        name: a registered backend.
        grid: its grid (the contract's default when None).
        raw: the backend's own estimates, without the visibility step and the sigma
            calibration (:class:`RefinedBackend`).
        options: the backend's options.

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
        backend = _FACTORIES[name](grid or GridSpec(), **options)
    except (TypeError, ValueError) as exc:
        raise BackendError(f"backend {name!r}: {exc}") from exc
    # an ensemble's members are refined themselves (their own calibrated sigma weighs them)
    return backend if raw or getattr(backend, "refines_itself", False) else RefinedBackend(backend)
