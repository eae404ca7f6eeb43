"""Many bags evaluated: each bag's result as ``roadbev eval`` gives it, pooled from sums; a corrupt
bag, a killed worker, an interrupted run, duplicates; the serial loop and Ray agree."""

from __future__ import annotations

import os
import shutil
import signal
from pathlib import Path
from typing import Any

import pytest

from roadbev_core.config import GridSpec, RoadbevConfig, StereoCamera
from roadbev_lab.evaluation.frames import without_timing
from roadbev_lab.evaluation.offline import eval_record, evaluate_bag
from roadbev_lab.fleet.executors import Executor, LocalPool, RayPool, SerialPool
from roadbev_lab.fleet.runner import DONE, DUPLICATE, FAILED, STORED, BagOutcome, run_bags
from roadbev_lab.fleet.store import ResultStore, config_digest
from roadbev_lab.fleet.summary import eval_report, eval_summary
from roadbev_lab.fleet.tasks import BagJob, BagResult, EvalSettings, run_job

CAMERA = StereoCamera.rsrd_half().scaled(0.5)
GRID = GridSpec().scaled(2)
SETTINGS = EvalSettings(RoadbevConfig.from_params({"backend": "bm", "inference_threads": 1}))
DIGEST = config_digest({"test": "bm"})


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three two-frame evaluation bags of different roads."""
    from roadbev_lab.evaluation.evalbag import write_eval_bag
    from roadbev_lab.synth import DriveConfig, RoadConfig, SyntheticDrive

    folder = tmp_path_factory.mktemp("fleet")
    out = []
    for seed in (1, 2, 3):
        road = RoadConfig(road_class="B", features=("speed_bump",), noise_sigma=1.0)
        path = folder / f"drive{seed}.mcap"
        write_eval_bag(path, SyntheticDrive(DriveConfig(frames=2, seed=seed, road=road, camera=CAMERA, grid=GRID)))
        out.append(path)
    return out


def _run(bags: list[Path], store: ResultStore, executor: Executor | None = None, **kwargs: Any) -> dict[str, Any]:
    with executor or SerialPool() as pool:
        outcomes = run_bags(bags, SETTINGS, DIGEST, pool, store, **kwargs)
    return eval_summary(outcomes, store, {"backend": "bm", "executor": pool.describe()})


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return without_timing(a) == without_timing(b)


def test_each_bag_is_its_one_bag_result_and_the_pool_is_all_frames(bags: list[Path], tmp_path: Path) -> None:
    summary = _run(bags, ResultStore(tmp_path / "store"))
    assert summary["counts"] == {"bags": 3, DONE: 3, STORED: 0, FAILED: 0, DUPLICATE: 0}
    for bag, entry in zip(bags, summary["bags"], strict=True):
        alone = eval_record(evaluate_bag(bag, SETTINGS.config), bag)
        assert entry["status"] == DONE and _same(entry["result"], alone)
    results = [b["result"] for b in summary["bags"]]
    pooled = summary["pooled"]
    assert pooled["frames"] == sum(r["frames"] for r in results) == 6 and pooled["bags"] == 3
    assert pooled["cells"] == sum(r["cells"] for r in results)
    # a mean of all cells: the bags' sums added, not their means averaged
    abs_sum = sum(r["abs_err_cm"] * r["cells"] for r in results)
    assert pooled["abs_err_cm"] == pytest.approx(abs_sum / pooled["cells"], rel=1e-12)
    assert pooled["abs_err_cm"] != pytest.approx(sum(r["abs_err_cm"] for r in results) / 3, rel=1e-9)
    assert min(r["median_abs_err_cm"] for r in results) <= pooled["median_abs_err_cm"] <= max(
        r["median_abs_err_cm"] for r in results)
    assert pooled["sigma_cells"] == sum(r["sigma_cells"] for r in results)
    assert "| **pooled, 3 bag(s)** | 6 |" in eval_report(summary)
    # drive bags add the pooled preview at arrival, its sigma scored against its error
    arrival = {"lead_time_s": 0.1, "points": 4250, "abs_err_cm": 0.315, "coverage_pct": 100.0,
               "within_1sigma_pct": 96.1, "within_2sigma_pct": 99.2, "mean_sigma_cm": 1.488}
    with_drives = {**summary, "pooled": {**pooled, "preview_at_arrival": arrival}}
    assert ("Pooled preview at arrival (lead 0.1 s, 4250 points): abs. error 0.315 cm, coverage 100.0 %, "
            "within 1 / 2 sigma 96.1 / 99.2 %, mean sigma 1.488 cm.") in eval_report(with_drives)


def test_the_pool_of_one_bag_is_that_bag(bags: list[Path], tmp_path: Path) -> None:
    summary = _run(bags[:1], ResultStore(tmp_path / "store"))
    record, pooled = summary["bags"][0]["result"], summary["pooled"]
    assert {k: v for k, v in record.items() if k in pooled and k != "losses"} == {
        k: v for k, v in pooled.items() if k in record and k != "losses"}


def test_a_rerun_skips_the_bags_done_and_no_resume_runs_them_again(bags: list[Path], tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "store")
    first = _run(bags, store)
    again = _run(bags, store)
    assert [b["status"] for b in again["bags"]] == [STORED] * 3
    assert again["pooled"] == first["pooled"]  # read back bit for bit, timing included
    fresh = _run(bags, store, resume=False)
    assert [b["status"] for b in fresh["bags"]] == [DONE] * 3 and _same(fresh["pooled"], first["pooled"])


def test_a_corrupt_bag_is_reported_and_the_others_are_pooled_without_it(bags: list[Path], tmp_path: Path) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"\x00garbage" * 50)
    store = ResultStore(tmp_path / "store")
    summary = _run([bags[0], broken, bags[1]], store)
    entry = summary["bags"][1]
    assert entry["status"] == FAILED and "broken.mcap" in entry["error"] and "result" not in entry
    assert not store.has(entry["key"])  # not stored: the next run tries it again
    good = _run([bags[0], bags[1]], ResultStore(tmp_path / "good"))
    assert _same(summary["pooled"], good["pooled"])
    assert f"- {broken}: failed: " in eval_report(summary)


def test_a_duplicate_is_run_and_pooled_once(bags: list[Path], tmp_path: Path) -> None:
    copy = tmp_path / "copy.mcap"
    shutil.copy(bags[0], copy)
    summary = _run([bags[0], copy], ResultStore(tmp_path / "store"))
    assert [b["status"] for b in summary["bags"]] == [DONE, DUPLICATE]
    assert str(bags[0]) in summary["bags"][1]["error"] and summary["pooled"]["bags"] == 1


def _killed_once(job: BagJob) -> BagResult:
    """:func:`run_job`, but the worker running the second bag is killed the first time."""
    marker = job.bag.with_suffix(".killed")
    if job.bag.name == "drive2.mcap" and not marker.exists():
        marker.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return run_job(job)


def test_a_worker_killed_mid_task_loses_nothing_and_counts_nothing_twice(bags: list[Path], tmp_path: Path) -> None:
    local = [shutil.copy(b, tmp_path / b.name) for b in bags]  # the markers go beside them
    paths = [Path(p) for p in local]
    reference = _run(paths, ResultStore(tmp_path / "ref"))
    store = ResultStore(tmp_path / "store")
    with LocalPool(2) as pool:
        outcomes = run_bags(paths, SETTINGS, DIGEST, pool, store, task=_killed_once)
    summary = eval_summary(outcomes, store, {})
    assert (tmp_path / "drive2.killed").exists()
    assert [o.status for o in outcomes] == [DONE] * 3
    assert summary["pooled"]["frames"] == 6 and _same(summary["pooled"], reference["pooled"])


def test_an_interrupted_run_resumes_where_it_stopped(bags: list[Path], tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "store")

    def interrupt(outcome: BagOutcome) -> None:
        raise KeyboardInterrupt  # Ctrl-C after the first bag

    with pytest.raises(KeyboardInterrupt), SerialPool() as pool:
        run_bags(bags, SETTINGS, DIGEST, pool, store, progress=interrupt)
    assert sum(1 for _ in store.root.rglob("*.npz")) == 1 and not list(store.root.rglob("*.tmp"))
    resumed = _run(bags, store)
    assert [b["status"] for b in resumed["bags"]] == [STORED, DONE, DONE]
    assert _same(resumed["pooled"], _run(bags, ResultStore(tmp_path / "ref"))["pooled"])


def test_ray_gives_the_serial_loops_results(bags: list[Path], tmp_path: Path, ray_cluster: Any) -> None:
    serial = _run(bags, ResultStore(tmp_path / "serial"))
    on_ray = _run(bags, ResultStore(tmp_path / "ray"), RayPool())
    assert on_ray["run"]["executor"]["kind"] == "ray" and on_ray["counts"][DONE] == 3
    for a, b in zip(serial["bags"], on_ray["bags"], strict=True):
        assert _same(a["result"], b["result"])
    assert _same(serial["pooled"], on_ray["pooled"])
