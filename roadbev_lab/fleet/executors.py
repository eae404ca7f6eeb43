"""Where a fleet's tasks run: in this process, on a local process pool, or on a Ray cluster.

Every executor runs a function over items and gives one :class:`Outcome` per item, the value or
the one-line reason it failed, and never stops at a failure: an exception in a task is that
task's outcome. ``on_done`` is called in the calling process as each item finishes, in the order
they finish, exactly once per item (a result store writes it there: nothing is lost when the run
is interrupted later, and nothing is counted twice).

* :class:`SerialPool`: one item after another in this process (the serial loop).
* :class:`LocalPool`: a pool of ``workers`` processes (:class:`concurrent.futures.ProcessPoolExecutor`,
  spawned). A worker that dies (killed, out of memory, a crash in native code) takes the tasks it
  and its siblings were running with it; those run again one at a time, so that the one that
  kills its worker is found: it is retried up to ``retries`` times and then reported, while the
  others finish.
* :class:`RayPool`: tasks on a Ray cluster (``ray.init(address)``: ``auto`` for the cluster of
  the environment, ``local`` to start one on this machine); Ray retries a task whose worker died
  (``max_retries``). Ray is an optional extra (``pip install .[fleet]``).

:func:`make_executor` picks one from the command line's ``--workers`` and ``--ray``.
"""

from __future__ import annotations

import multiprocessing
import os
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Generic, TypeVar

from roadbev_core.errors import RoadbevError

__all__ = ["Executor", "FleetError", "LocalPool", "Outcome", "RayPool", "SerialPool", "make_executor"]

T = TypeVar("T")
R = TypeVar("R")
DEFAULT_RETRIES = 2  # a task whose worker died runs again up to this many times


class FleetError(RoadbevError):
    """The fleet cannot run (no Ray, no cluster at the address, a failed task where all must succeed)."""


@dataclass(frozen=True)
class Outcome(Generic[R]):
    """One item's outcome: its value, or the one-line reason it failed."""

    value: R | None = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def _reason(exc: BaseException) -> str:
    """One line: the exception's type and the first line of its message."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _call(fn: Callable[[T], R], item: T) -> tuple[bool, R | str]:
    """``fn(item)`` as (True, value), or (False, the reason) when it raised: a task's failure is
    its outcome, in any process."""
    try:
        return True, fn(item)
    except Exception as exc:  # any failure of one task is reported for that task only
        return False, _reason(exc)


OnDone = Callable[[int, Outcome[Any]], object]


class Executor(ABC):
    """Runs a function over items (see the module docstring)."""

    kind: str = ""
    workers: int = 1

    @abstractmethod
    def run(self, fn: Callable[[T], R], items: Sequence[T], on_done: OnDone | None = None, *,
            keep_values: bool = True) -> list[Outcome[R]]:
        """``fn`` over ``items``: one :class:`Outcome` per item, in the items' order.

        Args:
            fn: a function the workers can import (module level; ``functools.partial`` of one).
            items: picklable arguments.
            on_done: called in this process with (index, outcome) as each item finishes.
            keep_values: keep each value in the returned outcomes (False: only ``on_done`` sees
                them, so that a long run does not hold every result in memory).
        """

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> list[R]:
        """``fn`` over ``items``, the values in order (the benchmarks' loop over drives).

        Raises:
            FleetError: an item failed (after every item ran), naming the failures.
        """
        outcomes = self.run(fn, items)
        failed = [f"item {i}: {o.error}" for i, o in enumerate(outcomes) if not o.ok]
        if failed:
            raise FleetError(f"{len(failed)} of {len(outcomes)} tasks failed: " + "; ".join(failed))
        return [o.value for o in outcomes]  # type: ignore[misc]  # every outcome is ok: its value is set

    def describe(self) -> dict[str, Any]:
        """What ran the tasks (for a summary's record)."""
        return {"kind": self.kind, "workers": self.workers}

    @abstractmethod
    def close(self) -> None:
        """Release the workers."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class SerialPool(Executor):
    """Every item in this process, one after another."""

    kind = "serial"

    def close(self) -> None:
        """Nothing to release: the items ran in this process."""

    def run(self, fn: Callable[[T], R], items: Sequence[T], on_done: OnDone | None = None, *,
            keep_values: bool = True) -> list[Outcome[R]]:
        outcomes: list[Outcome[R]] = []
        for index, item in enumerate(items):
            ok, value = _call(fn, item)
            outcome: Outcome[R] = Outcome(value) if ok else Outcome(error=str(value))  # type: ignore[arg-type]
            if on_done is not None:
                on_done(index, outcome)
            outcomes.append(outcome if keep_values else Outcome(error=outcome.error))
        return outcomes


class LocalPool(Executor):
    """A pool of worker processes on this machine (see the module docstring).

    Args:
        workers: processes (default: the CPU cores).
        retries: how often a task whose worker died (alone in the pool) runs again before it is
            reported.
    """

    kind = "local"

    def __init__(self, workers: int | None = None, *, retries: int = DEFAULT_RETRIES) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.retries = retries

    def close(self) -> None:
        """Nothing to release: each run's processes end with it."""

    def _pool(self) -> ProcessPoolExecutor:
        # spawned, not forked: a fork would copy this process's threads' locks (torch, OpenCV) mid-use
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))

    def run(self, fn: Callable[[T], R], items: Sequence[T], on_done: OnDone | None = None, *,
            keep_values: bool = True) -> list[Outcome[R]]:
        outcomes: list[Outcome[R] | None] = [None] * len(items)
        deaths = [0] * len(items)  # times each task's worker died while it ran alone
        queue = deque(range(len(items)))
        suspects: deque[int] = deque()  # in flight when a worker died: each runs alone next
        inflight: dict[Future[tuple[bool, Any]], tuple[int, bool]] = {}  # future -> (index, ran alone)

        def finish(index: int, outcome: Outcome[R]) -> None:
            if on_done is not None:
                on_done(index, outcome)
            outcomes[index] = outcome if keep_values else Outcome(error=outcome.error)

        pool = self._pool()
        try:
            while queue or suspects or inflight:
                lost: list[tuple[int, bool]] = []
                broken = False
                try:
                    if suspects:
                        if not inflight:
                            inflight[pool.submit(_call, fn, items[suspects[0]])] = (suspects[0], True)
                            suspects.popleft()
                    else:
                        while queue and len(inflight) < self.workers:
                            inflight[pool.submit(_call, fn, items[queue[0]])] = (queue[0], False)
                            queue.popleft()
                except BrokenProcessPool:  # a worker died since the last wait: this item never ran, it stays queued
                    broken = True
                if not broken:
                    done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                    for future in done:
                        index, alone = inflight.pop(future)
                        try:
                            ok, value = future.result()
                        except BrokenProcessPool:
                            lost.append((index, alone))
                            broken = True
                            continue
                        except Exception as exc:  # the result did not come back (unpicklable...): this task's outcome
                            ok, value = False, _reason(exc)
                        finish(index, Outcome(value) if ok else Outcome(error=str(value)))
                if not broken:
                    continue
                # a worker died: the pool is broken and every task still in it is lost with it
                lost += list(inflight.values())
                inflight.clear()
                pool.shutdown(wait=True, cancel_futures=True)
                pool = self._pool()
                for index, alone in lost:
                    if not alone:
                        suspects.append(index)
                        continue
                    deaths[index] += 1
                    if deaths[index] > self.retries:
                        finish(index, Outcome(error=f"its worker process died {deaths[index]} times running it"))
                    else:
                        suspects.append(index)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return [o if o is not None else Outcome(error="not run") for o in outcomes]


class RayPool(Executor):
    """Tasks on a Ray cluster (see the module docstring).

    Args:
        address: ``auto`` (the cluster of the environment), ``local`` (start one on this machine
            with ``workers`` CPUs, shut down by :meth:`close`), or a cluster's address
            (``HOST:PORT``, ``ray://HOST:PORT``); None: the Ray this process has already joined
            (``ray.init`` called by the caller), else ``auto``.
        workers: the CPUs of a ``local`` cluster (default: the cores).
        retries: how often Ray runs a task again whose worker died (``max_retries``).

    Raises:
        FleetError: Ray is not installed, or no cluster answers at ``address``.
    """

    kind = "ray"

    def __init__(self, address: str | None = None, *, workers: int | None = None,
                 retries: int = DEFAULT_RETRIES) -> None:
        try:
            # Ray is the fleet extra's (pip install .[fleet]); imported only when a Ray pool is made
            import ray
        except ImportError:
            raise FleetError("--ray needs Ray: pip install 'roadbev_ros[fleet]' (or pip install 'ray[default]')") \
                from None
        self._ray = ray
        self.retries = retries
        self.address = address
        self._started = False
        if not ray.is_initialized():
            try:
                if address == "local":
                    ray.init(num_cpus=workers or os.cpu_count() or 1, include_dashboard=False)
                else:
                    ray.init(address=address or "auto")
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise FleetError(f"no Ray cluster at {address or 'auto'!r}: {_reason(exc)}") from None
            self._started = True
        self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))

    def run(self, fn: Callable[[T], R], items: Sequence[T], on_done: OnDone | None = None, *,
            keep_values: bool = True) -> list[Outcome[R]]:
        ray = self._ray
        remote = ray.remote(_call).options(num_cpus=1, max_retries=self.retries)
        refs = {remote.remote(fn, item): index for index, item in enumerate(items)}
        outcomes: list[Outcome[R] | None] = [None] * len(items)
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for ref in ready:
                index = refs.pop(ref)
                try:
                    ok, value = ray.get(ref)
                    outcome: Outcome[R] = Outcome(value) if ok else Outcome(error=str(value))
                except ray.exceptions.RayError as exc:  # its worker died more than max_retries times...
                    outcome = Outcome(error=_reason(exc))
                if on_done is not None:
                    on_done(index, outcome)
                outcomes[index] = outcome if keep_values else Outcome(error=outcome.error)
        return [o if o is not None else Outcome(error="not run") for o in outcomes]

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "workers": self.workers, "address": self.address or "auto"}

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False


def make_executor(workers: int | None = None, ray: str | None = None) -> Executor:
    """The executor of ``--workers N`` and ``--ray ADDRESS``: Ray when an address is given (a
    ``local`` cluster gets ``workers`` CPUs), this process for one worker, else a local pool of
    ``workers`` processes (default: the cores).

    Raises:
        FleetError: ``workers`` < 1, or Ray as :class:`RayPool` says.
    """
    if workers is not None and workers < 1:
        raise FleetError(f"--workers must be >= 1, got {workers}")
    if ray is not None:
        return RayPool(ray, workers=workers)
    if workers == 1:
        return SerialPool()
    return LocalPool(workers)
