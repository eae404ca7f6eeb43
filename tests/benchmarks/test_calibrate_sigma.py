"""The sigma calibration's tuning set: drives of their own, refused when malformed."""

from __future__ import annotations

import pytest

from benchmarks.bench_arrival import SEED_BASE as BENCH_DRIVE_SEEDS
from benchmarks.bench_hazards import MAP_SEED_BASE, SEED_BASE
from benchmarks.calibrate_sigma import TUNING_DRIVES, drive_samples
from roadbev_core.config import GridSpec
from roadbev_lab.demo.drive import DRIVE_SEED


def test_the_tuning_drives_are_none_of_the_evaluation_drives() -> None:
    seeds = [int(spec.split(":")[2]) for spec in TUNING_DRIVES]
    evaluation = {DRIVE_SEED, *range(BENCH_DRIVE_SEEDS, BENCH_DRIVE_SEEDS + 100),
                  *range(SEED_BASE, SEED_BASE + 100), *range(MAP_SEED_BASE, MAP_SEED_BASE + 100)}
    assert seeds and not set(seeds) & evaluation
    assert all(300_001 <= s < 310_000 for s in seeds)  # the tuning drives' range (calibrate_datum's)


@pytest.mark.parametrize("spec", ["10:5", "ten:5:300001", "10:5:300001:1"])
def test_a_malformed_drive_is_refused_with_its_spec(spec: str) -> None:
    with pytest.raises(SystemExit, match=spec):
        drive_samples([spec], 2.0, GridSpec())


def test_no_drives_is_an_empty_set() -> None:
    assert drive_samples([], 2.0, GridSpec()) == []
