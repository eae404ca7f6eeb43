"""The drive-looping benchmarks with ``--ray``: the serial run's results, the drives run as tasks
on a local two-worker Ray cluster (and ``--jobs`` on a local pool)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks import bench_hazards, bench_ride

RIDE = ["--seeds", "1", "--speeds", "10", "--rates", "10", "--roads", "bumps", "rough", "--duration", "2",
        "--candidates"]
HAZARDS = ["--seeds", "1", "--duration", "3"]


def _results(path: Path, *drop: str) -> Any:
    data = json.loads(path.read_text())
    for key in ("machine", "wall_s", "command", *drop):
        data.pop(key, None)
    return data


WALL_TIME_KEYS = ("render_s", "detect_s", "run_s")  # each drive's own wall time: the machine's, not the result's


def _without_wall_time(items: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in item.items() if k not in WALL_TIME_KEYS} for item in items]


@pytest.mark.parametrize("executor", [["--ray", "auto"], ["--jobs", "2"]])
def test_ride_and_hazards_give_the_serial_results(executor: list[str], tmp_path: Path,
                                                  request: pytest.FixtureRequest) -> None:
    if "--ray" in executor:
        request.getfixturevalue("ray_cluster")  # `auto`: the cluster this process has joined
    for module, args, name in ((bench_ride, RIDE, "ride"), (bench_hazards, HAZARDS, "hazards")):
        serial, parallel = tmp_path / f"{name}_serial.json", tmp_path / f"{name}_parallel.json"
        assert module.main([*args, "--out", str(serial)]) == 0
        assert module.main([*args, *executor, "--out", str(parallel)]) == 0
        a, b = _results(serial), _results(parallel)
        key = "cells" if name == "ride" else "drives"
        a[key], b[key] = _without_wall_time(a[key]), _without_wall_time(b[key])
        assert a == b, name
        assert json.loads(parallel.read_text())["machine"]["executor"]["kind"] == ("ray" if "--ray" in executor
                                                                                 else "local")
