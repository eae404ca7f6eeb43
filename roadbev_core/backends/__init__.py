"""Backends behind one protocol: ``estimate(frame) -> Estimate``, chosen by name.

The node, ``roadbev eval``, the demo and the benchmarks all create backends here, so a number in
one is the number in all. A name is looked up in :mod:`roadbev_core.backend_plugins` (the
built-in backends, the ``roadbev.backends`` entry points of installed packages, or a
``module:attr`` path) and its module is imported only when the backend is created, so choosing
``bm`` never imports torch, for example. A factory is ``factory(grid, **options) -> Backend``.

Every backend :func:`create` makes answers through :class:`RefinedBackend`: its estimates pass
through :func:`roadbev_core.uncertainty.refine` (cells hidden behind a crest become NaN; sigma
is the backend's calibrated model from ``roadbev_core/data/sigma_calibration.json``, or on a
far-field grid from ``far_sigma_calibration.json``, the one fitted with its options where there
is one: :func:`roadbev_core.uncertainty.calibration_for`), one step for
all backends (an ``ensemble``'s members each, not the ensemble again). ``create(..., raw=True)``
gives the backend's own answer (used to calibrate).

A backend that can also answer the far-field grid (:class:`roadbev_core.config.FarFieldConfig`:
coarser cells beyond the grid, on the same frame) says so with a true ``far_field`` attribute;
:func:`roadbev_core.pipeline.build_far_backend` then builds a second one on that grid. Those
that do not (the default) run the grid alone when the far field is asked for
(:attr:`roadbev_core.pipeline.Pipeline.far_field_off` says why). A backend that can start
an estimate and finish it later on workers it shares with another of its kind
(:class:`SubmitsEstimates`: the ``ensemble``) lets the pipeline run the grid's and the far
field's estimates of a frame together.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor
from typing import Any, Protocol, runtime_checkable

from roadbev_core.backend_plugins import BackendError, available, find, takes_checkpoint
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate, Frame
from roadbev_core.runtime import flush_denormals
from roadbev_core.uncertainty import calibration_for, refine

__all__ = ["Backend", "BackendError", "RefinedBackend", "SubmitsEstimates", "available", "create", "start_estimate",
           "takes_checkpoint"]


@runtime_checkable
class Backend(Protocol):
    """An elevation estimator on a fixed grid."""

    name: str
    grid: GridSpec
    needs_stereo: bool

    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one frame."""
        ...


@runtime_checkable
class SubmitsEstimates(Protocol):
    """A backend whose estimate can be started now and finished later, on workers it can share
    with another backend of its kind (so that the two frames' worth of work queue on one pool)."""

    def submit(self, frame: Frame) -> Callable[[], Estimate]:
        """Start the estimate of ``frame``; the returned call waits for it (raising what it raised)."""
        ...

    def share_workers(self, other: Any) -> None:
        """Run on ``other``'s workers from now on."""
        ...


def start_estimate(backend: Backend, frame: Frame, worker: Executor | None = None) -> Callable[[], Estimate]:
    """``backend``'s estimate of ``frame`` started now where it can be: on its own workers
    (:class:`SubmitsEstimates`), else on ``worker`` when given (the calling thread goes on with
    other work meanwhile), else made when the returned call asks for it. The returned call waits
    for the estimate and raises what the backend raised."""
    if isinstance(backend, SubmitsEstimates):
        return backend.submit(frame)
    if worker is not None:
        return worker.submit(_flushed_estimate, backend, frame).result
    return lambda: backend.estimate(frame)


def _flushed_estimate(backend: Backend, frame: Frame) -> Estimate:
    flush_denormals()  # a per-thread setting: each worker thread sets it itself
    return backend.estimate(frame)


class RefinedBackend:
    """A backend whose estimates pass through :func:`roadbev_core.uncertainty.refine`.

    Attributes other than the protocol's (``describe``, ``checkpoint``, ``params``...) are the
    wrapped backend's (``inner``).
    """

    def __init__(self, inner: Backend, options: dict[str, Any] | None = None) -> None:
        """``options``: what ``inner`` was built with (the sigma fitted with them where the
        tables have one: :func:`roadbev_core.uncertainty.calibration_for`)."""
        self.inner = inner
        self.name = inner.name
        self.grid = inner.grid
        self.needs_stereo = inner.needs_stereo
        self.sigma_model = calibration_for(inner.name, grid=inner.grid, options=options)

    def estimate(self, frame: Frame) -> Estimate:
        """The wrapped backend's estimate, hidden cells NaN and sigma calibrated."""

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


def create(name: str, grid: GridSpec | None = None, *, raw: bool = False, **options: Any) -> Backend:
    """Create backend ``name`` for ``grid`` (default grid when None).

    Args:
        name: a backend's name or ``module:attr`` path (:mod:`roadbev_core.backend_plugins`).
        grid: its grid (the interface's default, docs/interface/frames-and-grid.md, when None).
        raw: the backend's own estimates, without the visibility step and the sigma
            calibration (:class:`RefinedBackend`).
        options: the backend's options.

    Raises:
        BackendError: an unknown name (listing the known ones), a plugin that does not load or
            does not make a :class:`Backend` (naming it), or the backend refused its options.
    """
    plugin = find(name)
    factory = plugin.load()
    try:
        backend = factory(grid or GridSpec(), **options)
    except (TypeError, ValueError) as exc:
        raise BackendError(f"backend {name!r}: {exc}") from exc
    if not isinstance(backend, Backend) or not callable(getattr(backend, "estimate", None)):
        missing = [m for m in ("name", "grid", "needs_stereo", "estimate") if not hasattr(backend, m)]
        lacks = f"it lacks {', '.join(missing)}" if missing else "its estimate is not a method"
        raise BackendError(f"backend plugin {name!r} ({plugin.target}, {plugin.source}) returned "
                           f"{type(backend).__name__!r}, not a Backend: {lacks}")
    # an ensemble's members are refined themselves (their own calibrated sigma weighs them)
    return backend if raw or getattr(backend, "refines_itself", False) else RefinedBackend(backend, options)
