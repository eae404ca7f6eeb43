"""The executors: values in order, a failure reported for its item only, a killed worker's task
run again (or reported) without losing or repeating any item; on this process, a local pool and
a local Ray cluster of two workers."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import pytest

from roadbev_lab.fleet.executors import (
    Executor,
    FleetError,
    LocalPool,
    Outcome,
    RayPool,
    SerialPool,
    make_executor,
)


def _double(item: int) -> int:
    if item == 3:
        raise ValueError("three is refused\nsecond line")
    return 2 * item


def _die(item: tuple[str, int, str]) -> int:
    """Kill this worker process: on every call (``always``), or on the first (``once``: a marker
    file remembers it); otherwise (or after that) the value doubled. Its attempts are counted in
    ``<marker>.calls``."""
    marker, value, mode = item
    with Path(f"{marker}.calls").open("a") as calls:
        calls.write("x")
    if mode == "always" or (mode == "once" and not Path(marker).exists()):
        Path(marker).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return 2 * value


def _pools(ray_cluster: Any | None = None) -> list[Executor]:
    pools: list[Executor] = [SerialPool(), LocalPool(2)]
    if ray_cluster is not None:
        pools.append(RayPool())
    return pools


def _run(executor: Executor, fn: Any, items: list[Any]) -> tuple[list[Outcome[Any]], list[int]]:
    seen: list[int] = []
    outcomes = executor.run(fn, items, lambda index, _outcome: seen.append(index))
    return outcomes, seen


@pytest.mark.parametrize("kind", ["serial", "local"])
def test_values_in_order_and_a_failure_for_its_item_only(kind: str) -> None:
    executor = SerialPool() if kind == "serial" else LocalPool(2)
    with executor:
        outcomes, seen = _run(executor, _double, [1, 2, 3, 4])
    assert [o.value for o in outcomes] == [2, 4, None, 8]
    assert outcomes[2].error == "ValueError: three is refused" and not outcomes[2].ok
    assert sorted(seen) == [0, 1, 2, 3]  # each item reported once, as it finished
    with executor, pytest.raises(FleetError, match="1 of 4 tasks failed: item 2: ValueError: three"):
        executor.map(_double, [1, 2, 3, 4])


def test_ray_runs_the_same(ray_cluster: Any) -> None:
    with RayPool() as executor:
        assert executor.workers == 2 and executor.describe()["kind"] == "ray"
        outcomes, seen = _run(executor, _double, [1, 2, 3, 4])
        assert executor.map(_double, [5, 6]) == [10, 12]
    assert [o.value for o in outcomes] == [2, 4, None, 8] and outcomes[2].error == "ValueError: three is refused"
    assert sorted(seen) == [0, 1, 2, 3]
    assert ray_cluster.is_initialized()  # a pool on the caller's Ray leaves it running


def test_values_can_stay_with_on_done_only() -> None:
    kept: dict[int, Any] = {}
    outcomes = SerialPool().run(_double, [1, 3], lambda i, o: kept.update({i: o.value}), keep_values=False)
    assert kept == {0: 2, 1: None} and outcomes[0].value is None and outcomes[1].error


@pytest.mark.parametrize("kind", ["local", "ray"])
def test_a_worker_killed_mid_task_runs_it_again_and_loses_or_repeats_nothing(
        kind: str, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    executor = RayPool() if kind == "ray" and request.getfixturevalue("ray_cluster") else LocalPool(2)
    items = [(str(tmp_path / f"m{i}"), i, "once" if i == 2 else "never") for i in range(5)]
    with executor:
        outcomes, seen = _run(executor, _die, items)
    assert [o.value for o in outcomes] == [0, 2, 4, 6, 8]
    assert sorted(seen) == [0, 1, 2, 3, 4]  # every item once: none lost, none twice
    assert (tmp_path / "m2").exists() and len((tmp_path / "m2.calls").read_text()) == 2  # killed, then run again


@pytest.mark.parametrize("kind", ["local", "ray"])
def test_a_task_that_always_kills_its_worker_is_reported_and_the_others_finish(
        kind: str, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    executor = RayPool(retries=1) if kind == "ray" and request.getfixturevalue("ray_cluster") else LocalPool(
        2, retries=1)
    items = [(str(tmp_path / f"m{i}"), i, "always" if i == 1 else "never") for i in range(4)]
    with executor:
        outcomes, seen = _run(executor, _die, items)
    assert [o.value for o in outcomes] == [0, None, 4, 6]
    assert outcomes[1].error and ("died" in outcomes[1].error or "Crashed" in outcomes[1].error), outcomes[1].error
    assert sorted(seen) == [0, 1, 2, 3]
    assert len((tmp_path / "m1.calls").read_text()) >= 2  # tried again before it was reported


def test_make_executor_picks_by_the_options(tmp_path: Path) -> None:
    assert isinstance(make_executor(1), SerialPool)
    local = make_executor(3)
    assert isinstance(local, LocalPool) and local.workers == 3
    assert isinstance(make_executor(), LocalPool)
    with pytest.raises(FleetError, match="--workers must be >= 1"):
        make_executor(0)
