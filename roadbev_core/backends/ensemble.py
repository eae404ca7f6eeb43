"""``ensemble``: several backends on the same frame, their estimates combined cell by cell.

Backends fail differently on a road: the learned stereo model answers nearly every cell but
smooths what is shorter than its internal cells (a few centimetres); an image-view matcher keeps
that detail and is noisier. Each member answers the frame (concurrently: the engines release the
GIL, so on a multi-core CPU the ensemble costs about its slowest member), through the registry's
visibility step and its own calibrated sigma (:class:`roadbev_core.backends.RefinedBackend`), and
per cell the ensemble takes

* the inverse-variance weighted mean of the members that answered (weights ``1 / sigma_i^2``);
* as its 1-sigma, the weighted mean of their sigmas (their errors come from the same images, so
  they are treated as fully correlated: combining does not shrink the sigma) together with the
  members' spread about the mean (``sqrt(sum w_i (z_i - z)^2 / W)``, in quadrature): where they
  disagree, the cell is less certain than either says;
* NaN where no member answered.

With the far field on, the pipeline gives the far-field ensemble the near one's workers
(:meth:`EnsembleBackend.share_workers`) and submits both on the frame (:meth:`EnsembleBackend.submit`),
near members first: the far-field matchers (a few ms each) run on whichever worker is free first
while the slowest near member is still matching, so the far field adds little to a frame's latency.

Options:
    members: the member backends joined by ``+`` (or commas), default ``bm+sgbm`` (the configuration
        whose preview the ride benchmark found worth the most), each with its default options.
    <member>.<option>: an option of one member (``sgbm.refine_width=21``; as a node parameter
        ``ensemble.sgbm.refine_width``).
"""

from __future__ import annotations

import atexit
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from roadbev_core.backends import Backend, BackendError, create
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate, Frame

__all__ = ["DEFAULT_MEMBERS", "EnsembleBackend", "combine", "create_ensemble"]

DEFAULT_MEMBERS = "bm+sgbm"


def combine(estimates: list[Estimate]) -> tuple[np.ndarray, np.ndarray]:
    """Cell-wise combination (module docstring) of estimates on one grid: elevation and 1-sigma
    [R, C] float32 (NaN where no estimate answered)."""
    z = np.stack([e.elevation for e in estimates]).astype(np.float64)  # [M, R, C]
    s = np.stack([e.uncertainty for e in estimates]).astype(np.float64)
    known = np.isfinite(z) & np.isfinite(s) & (s > 0)
    w = np.where(known, 1.0 / np.where(known, s, 1.0) ** 2, 0.0)  # [M, R, C]
    total = w.sum(axis=0)  # [R, C]
    answered = total > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (np.where(known, z, 0.0) * w).sum(axis=0) / total
        sigma_mean = (w * np.where(known, s, 0.0)).sum(axis=0) / total
        spread = (w * np.square(np.where(known, z, 0.0) - mean)).sum(axis=0) / total
    elevation = np.where(answered, mean, np.nan).astype(np.float32)
    sigma = np.where(answered, np.sqrt(sigma_mean**2 + spread), np.nan).astype(np.float32)
    return elevation, sigma


class EnsembleBackend:
    """Several backends combined cell by cell (see the module docstring)."""

    name = "ensemble"
    # its members pass through the registry's visibility step and sigma calibration themselves
    refines_itself = True

    def __init__(self, grid: GridSpec, members: list[Backend]) -> None:
        if len(members) < 2:
            raise BackendError("an ensemble needs at least two members")
        self.grid = grid
        self.members = members
        self.needs_stereo = any(m.needs_stereo for m in members)
        # a far-field grid is answered when every member answers one
        self.far_field = all(getattr(m, "far_field", False) for m in members)
        self._pool = ThreadPoolExecutor(max_workers=len(members), thread_name_prefix="roadbev-ensemble")
        atexit.register(self._pool.shutdown, wait=False)

    def share_workers(self, other: EnsembleBackend) -> None:
        """Run the members on ``other``'s workers from now on (its members and these queue on one
        pool, in the order they are submitted); this ensemble's own workers end."""
        if other._pool is not self._pool:
            self._pool.shutdown(wait=True)
            self._pool = other._pool

    def submit(self, frame: Frame) -> Callable[[], Estimate]:
        """Start every member on ``frame``; the returned call waits for them and combines
        (raising what a member raised)."""
        start = time.perf_counter()
        futures = [self._pool.submit(m.estimate, frame) for m in self.members]
        return lambda: self._combined(futures, start)

    def estimate(self, frame: Frame) -> Estimate:
        """Every member's estimate of ``frame``, combined."""
        return self.submit(frame)()

    def _combined(self, futures: list[Future[Estimate]], start: float) -> Estimate:
        estimates = [f.result() for f in futures]
        answered = time.perf_counter()
        elevation, sigma = combine(estimates)
        timings = {f"{m.name}_ms": sum(e.timings_ms.values()) for m, e in zip(self.members, estimates, strict=True)}
        timings["members"] = 1e3 * (answered - start)
        timings["post"] = 1e3 * (time.perf_counter() - answered)
        return Estimate(elevation, sigma, timings, out_of_distribution=any(e.out_of_distribution for e in estimates))

    def describe(self) -> dict[str, Any]:
        """The members, for benchmark records."""
        return {"backend": self.name, "members": [m.name for m in self.members]}


def create_ensemble(grid: GridSpec, members: str = DEFAULT_MEMBERS, **member_options: Any) -> EnsembleBackend:
    """Backend factory: ``create("ensemble", grid, members="stereo+sgbm", **{"sgbm.block_size": 9})``.

    Raises:
        BackendError: fewer than two members, an unknown or repeated one, a member option not
            of the form ``<member>.<option>`` for one of the members, or a member that cannot run
            (its options refused).
    """
    names = [n.strip() for n in str(members).replace(",", "+").split("+") if n.strip()]
    if len(set(names)) != len(names) or "ensemble" in names:
        raise BackendError(f"ensemble members must be distinct backends other than the ensemble, got {members!r}")
    options: dict[str, dict[str, Any]] = {n: {} for n in names}
    for key, value in member_options.items():
        member, _, option = key.partition(".")
        if member not in options or not option:
            raise BackendError(f"ensemble option {key!r} is neither 'members' nor '<member>.<option>' for a member "
                               f"({', '.join(names)})")
        options[member][option] = value
    return EnsembleBackend(grid, [create(n, grid, **options[n]) for n in names])
