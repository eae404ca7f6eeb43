"""The ensemble backend: cell-wise combination of its members, concurrency, refusals."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from roadbev_core.backends import BackendError, RefinedBackend, create
from roadbev_core.backends.ensemble import EnsembleBackend, combine
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate

GRID = GridSpec()


def _estimate(value: float, sigma: float, nan_rows: slice | None = None) -> Estimate:
    e = np.full(GRID.shape, value, np.float32)
    s = np.full(GRID.shape, sigma, np.float32)
    if nan_rows is not None:
        e[nan_rows] = np.nan
        s[nan_rows] = np.nan
    return Estimate(e, s)


def test_cells_are_weighted_by_their_sigmas_and_disagreement_widens_the_sigma() -> None:
    a, b = _estimate(0.010, 0.002, slice(0, 10)), _estimate(0.020, 0.004, slice(5, 20))
    elevation, sigma = combine([a, b])
    both = elevation[30]  # both answered: the inverse-variance weighted mean
    assert both == pytest.approx(np.full(GRID.n_cols, (0.010 / 0.002**2 + 0.020 / 0.004**2) /
                                         (1 / 0.002**2 + 1 / 0.004**2)), abs=1e-6)
    w_a, w_b = 1 / 0.002**2, 1 / 0.004**2
    mean = (0.010 * w_a + 0.020 * w_b) / (w_a + w_b)
    correlated = (w_a * 0.002 + w_b * 0.004) / (w_a + w_b)
    spread = (w_a * (0.010 - mean) ** 2 + w_b * (0.020 - mean) ** 2) / (w_a + w_b)
    assert sigma[30, 0] == pytest.approx(np.sqrt(correlated**2 + spread), rel=1e-5)
    assert sigma[30, 0] > 0.002  # never below the better member's own when they disagree
    assert elevation[2, 0] == pytest.approx(0.020) and sigma[2, 0] == pytest.approx(0.004)  # only b
    assert elevation[12, 0] == pytest.approx(0.010) and sigma[12, 0] == pytest.approx(0.002)  # only a
    assert np.all(np.isnan(elevation[5:10])) and np.all(np.isnan(sigma[5:10]))  # neither
    same, same_sigma = combine([a, _estimate(0.010, 0.002, slice(0, 10))])
    assert same[30, 0] == pytest.approx(0.010) and same_sigma[30, 0] == pytest.approx(0.002)


class _Meeting:
    """A member that answers only once the other member is inside its own estimate: run one after
    the other, the first would wait at the barrier until it breaks."""

    needs_stereo = True

    def __init__(self, name: str, value: float, barrier: threading.Barrier) -> None:
        self.name, self.grid, self.value, self.barrier = name, GRID, value, barrier
        self.threads: list[str] = []

    def estimate(self, frame: Any) -> Estimate:
        self.threads.append(threading.current_thread().name)
        self.barrier.wait()
        return _estimate(self.value, 0.003)


def test_members_answer_concurrently() -> None:
    barrier = threading.Barrier(2, timeout=30.0)
    slow_a, slow_b = _Meeting("a", 0.0, barrier), _Meeting("b", 0.02, barrier)
    ensemble = EnsembleBackend(GRID, [slow_a, slow_b])
    out = ensemble.estimate(None)  # type: ignore[arg-type]
    assert not barrier.broken
    assert slow_a.threads[0] != slow_b.threads[0]
    assert float(out.elevation[0, 0]) == pytest.approx(0.01)
    assert {"a_ms", "b_ms", "members", "post"} <= set(out.timings_ms)


def test_the_registry_builds_refined_members_and_refuses_bad_ones() -> None:
    ensemble = create("ensemble", GRID, members="bm,sgbm")
    assert isinstance(ensemble, EnsembleBackend)  # not wrapped again: its members are
    assert [m.name for m in ensemble.members] == ["bm", "sgbm"]
    assert all(isinstance(m, RefinedBackend) for m in ensemble.members)
    for members in ("bm", "bm,bm", "bm,ensemble", "bm,magic"):
        with pytest.raises(BackendError):
            create("ensemble", GRID, members=members)


def test_member_options_reach_their_member_only() -> None:
    options: dict[str, Any] = {"sgbm.refine_width": 21, "bm.block_size": 9}
    ensemble = create("ensemble", GRID, **options)
    assert isinstance(ensemble, EnsembleBackend)
    members: list[Any] = list(ensemble.members)
    bm, sgbm = (m.params for m in members)
    assert (bm.block_size, bm.refine_width) == (9, 0)
    assert (sgbm.block_size, sgbm.refine_width) == (7, 21)
    refused: list[dict[str, Any]] = [{"stereo.threads": 1}, {"sgbm": 3}, {"sgbm.": 3}]
    for bad in refused:
        with pytest.raises(BackendError, match="member"):
            create("ensemble", GRID, **bad)
    unknown: dict[str, Any] = {"sgbm.window": 9}
    with pytest.raises(BackendError, match="unknown option"):
        create("ensemble", GRID, **unknown)


class _Recording:
    """A member that notes the order the shared workers start it in."""

    needs_stereo = True

    def __init__(self, name: str, value: float, started: list[str], fail: Exception | None = None) -> None:
        self.name, self.grid, self.value, self.started, self.fail = name, GRID, value, started, fail

    def estimate(self, frame: Any) -> Estimate:
        self.started.append(self.name)
        if self.fail is not None:
            raise self.fail
        return _estimate(self.value, 0.003)


def test_an_ensemble_sharing_workers_queues_behind_the_one_submitted_first() -> None:
    started: list[str] = []
    near = EnsembleBackend(GRID, [_Recording("near_a", 0.0, started), _Recording("near_b", 0.02, started)])
    far = EnsembleBackend(GRID, [_Recording("far_a", 0.01, started), _Recording("far_b", 0.03, started)])
    far.share_workers(near)
    finish_near, finish_far = near.submit(None), far.submit(None)  # type: ignore[arg-type]
    assert float(finish_near().elevation[0, 0]) == pytest.approx(0.01)
    assert float(finish_far().elevation[0, 0]) == pytest.approx(0.02)
    assert set(started[:2]) == {"near_a", "near_b"}  # two workers: the near members start first
    assert far.estimate(None).elevation[0, 0] == pytest.approx(0.02)  # type: ignore[arg-type]


def test_a_submitted_estimate_raises_what_its_member_raised_when_it_is_finished() -> None:
    started: list[str] = []
    broken = EnsembleBackend(GRID, [_Recording("a", 0.0, started), _Recording("b", 0.0, started, ValueError("no"))])
    finish = broken.submit(None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="no"):
        finish()
