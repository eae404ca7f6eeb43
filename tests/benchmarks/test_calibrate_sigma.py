"""The sigma calibration's tuning set: drives of their own, refused when malformed; the far-field tables."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.bench_arrival import SEED_BASE as BENCH_DRIVE_SEEDS
from benchmarks.bench_hazards import MAP_SEED_BASE, SEED_BASE
from benchmarks.calibrate_sigma import TUNING_DRIVES, drive_samples
from roadbev_core.config import FarFieldConfig, GridSpec
from roadbev_core.uncertainty import SigmaModel, calibration_for
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


def test_the_far_field_calibration_fits_the_footprint_and_judges_the_worst_band(tmp_path: Path) -> None:
    from benchmarks.calibrate_sigma import main

    out = tmp_path / "far.json"
    assert main(["--far-field", "--frames", "2", "--backends", "bm", "--out", str(out)]) == 0
    table = json.loads(out.read_text())
    far = FarFieldConfig().grid(GridSpec())
    assert GridSpec.from_dict(table["grid"]) == far and table["drives"] == [] and table["seeds"][0] >= 200_000
    assert table["models"]["bm"]["footprint"] > 0
    scores = table["details"]["bm"]["tuning_scores"]
    assert scores["worst_band_confident_wrong_pct"] == max(b["confident_wrong_pct"] for b in scores["bands"]
                                                           if b["sigma_cells"])
    assert [b["x_from_m"] for b in scores["bands"]] == [7.08, *range(8, 15)]


def test_a_run_that_fits_some_backends_keeps_the_record_of_the_others(tmp_path: Path) -> None:
    from benchmarks.calibrate_sigma import main

    out = tmp_path / "table.json"
    earlier = {"command": "python -m benchmarks.calibrate_sigma", "machine": {"cpu": "earlier"}, "seconds": 1.0,
               "models": {"stereo": {"base": 0.001}}, "details": {"stereo": {"factor": 1.0}}}
    out.write_text(json.dumps(earlier))
    assert main(["--far-field", "--frames", "1", "--backends", "bm", "--out", str(out)]) == 0
    table = json.loads(out.read_text())
    assert set(table["models"]) == {"stereo", "bm"} and table["models"]["stereo"] == {"base": 0.001}
    assert table["command"] == earlier["command"] and table["machine"] == earlier["machine"]
    assert table["details"]["bm"]["command"].endswith(f"--backends bm --out {out}")


def test_a_backend_given_with_options_is_fitted_with_them_under_their_key(tmp_path: Path) -> None:
    from benchmarks.calibrate_sigma import backend_specs, main

    assert backend_specs("bm:plane_parallax_px=16,block_size=9,sgbm") == [
        ("bm", {"plane_parallax_px": 16, "block_size": 9}), ("sgbm", {})]
    out = tmp_path / "table.json"
    assert main(["--far-field", "--frames", "1", "--backends", "bm:plane_parallax_px=16", "--out", str(out)]) == 0
    table = json.loads(out.read_text())
    assert set(table["models"]) == set(table["details"]) == {"bm:plane_parallax_px=16"}
    fitted = SigmaModel.from_dict(table["models"]["bm:plane_parallax_px=16"])
    far = FarFieldConfig().grid(GridSpec())
    assert calibration_for("bm", grid=far, far_path=out, options={"plane_parallax_px": 16}) == fitted
