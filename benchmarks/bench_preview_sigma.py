"""Is the preview's sigma honest where it matters: behind speed bumps, at the wheels' arrival?

The uncertainty issue's last target: *on the demo drive, no preview sample behind a bump is off by
more than 2 cm while its sigma is below 1 cm*. The demo's drive (:func:`roadbev_lab.demo.drive.
drive_config`, seed 330000: 10 m/s, camera at 10 Hz, ISO class C with a speed bump and a pothole
every ~5 m) is rendered once; each backend runs through the pipeline with the map off (per-frame
previews, ``roadbev_road``) and on (contact-plane previews from the fused map), as ``roadbev eval
--no-map`` / ``--map`` do. The samples scored are the ones a controller acts on: at every 3 cm of
each front wheel's path, the latest message stamped at least the lead time (0.1 s) before the
wheel gets there (:func:`roadbev_lab.evaluation.arrival.arrival_points`), with the sigma that same message
gave there. Errors are against the true counterpart of the reference each message declares.

*Behind a bump* is the strip from a speed bump's (or hump's) centre to 2 m past it along the road
(the drive runs along ``odom`` x): the crest's far side and the road it hides from the camera.
A sample is *confidently wrong* when its error exceeds 2 cm while its sigma is below 1 cm (the
target: none behind a bump); the JSON also gives the share of samples outside 3 sigma.

Run: ``.venv/bin/python -m benchmarks.bench_preview_sigma [--backends bev_sweep stereo mono]``;
writes ``benchmarks/results/preview_sigma.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, cast

import numpy as np

from benchmarks.bench_arrival import drive_truth, evaluate_on_drive
from benchmarks.common import RESULTS, available_backends, machine_info, write_json

BEHIND_M = 2.0  # the strip behind a bump's centre that is scored as "behind the bump"
WRONG_M = 0.02  # off by more than this ...
SURE_M = 0.01  # ... while the sigma is below this: confidently wrong
BUMPS = ("speed_bump", "hump")


def behind_bumps(xy: np.ndarray, bumps_x: np.ndarray, behind_m: float = BEHIND_M) -> np.ndarray:
    """[P] bool: path points [P, 2] (odom) within ``(0, behind_m]`` past a bump centre's x [B]."""
    if bumps_x.size == 0:
        return np.zeros(len(xy), bool)
    dx = xy[:, 0:1] - bumps_x[None, :]  # [P, B]
    return cast("np.ndarray", np.any((dx > 0.0) & (dx <= behind_m), axis=1))


def score_points(error: np.ndarray, sigma: np.ndarray, where: np.ndarray) -> dict[str, Any]:
    """Counts and shares over the points ``where`` [P] that have an error and a sigma."""
    ok = where & np.isfinite(error) & np.isfinite(sigma)
    e, s = np.abs(error[ok]), sigma[ok]
    sure = s < SURE_M
    wrong = sure & (e > WRONG_M)
    n = int(ok.sum())
    return {
        "samples": n,
        "confident_wrong": int(wrong.sum()),
        "confident_wrong_pct": 100.0 * float(wrong.sum()) / n if n else float("nan"),
        "outside_3sigma_pct": 100.0 * float(np.mean(e > 3.0 * s)) if n else float("nan"),
        "abs_err_cm": 100.0 * float(e.mean()) if n else float("nan"),
        "mean_sigma_cm": 100.0 * float(s.mean()) if n else float("nan"),
        "max_err_cm_sigma_below_1cm": 100.0 * float(e[sure].max()) if sure.any() else float("nan"),
    }


def run(backends: list[str], lead: float) -> dict[str, Any]:
    """Render the demo drive and score every backend with the map off and on."""
    from roadbev_lab.demo.drive import DRIVE_SEED, drive_config
    from roadbev_lab.evaluation.arrival import arrival_points, per_frame_previews
    from roadbev_lab.synth import RidingDrive

    drive = RidingDrive(drive_config())
    start = time.perf_counter()
    samples = list(drive)
    render_s = time.perf_counter() - start
    truth, road_map, settings, odometry, _ = drive_truth(drive, lead)
    bumps_x = np.array([x for name, x, _, _ in drive.features_in_odom() if name in BUMPS])
    out: dict[str, Any] = {"seed": DRIVE_SEED, "frames": len(samples), "render_s": round(render_s, 1),
                           "bumps": int(bumps_x.size), "backends": {}}
    for name in backends:
        rows: dict[str, Any] = {}
        for fused in (False, True):
            result = evaluate_on_drive(drive, samples, name, fused, odometry)
            stamps = [int(r["stamp_ns"]) for r in result.per_frame]
            points = arrival_points(per_frame_previews(result.outputs or []), truth, road_map, settings,
                                    frame_stamps_ns=stamps)
            error = np.concatenate([p.error for p in points])
            sigma = np.concatenate([p.preview_sigma for p in points])
            behind = np.concatenate([behind_bumps(p.path.xy, bumps_x) for p in points])
            row = {"behind_bumps": score_points(error, sigma, behind),
                   "all": score_points(error, sigma, np.ones(error.shape, bool))}
            b = row["behind_bumps"]
            print(f"  {name:9s} map {'on ' if fused else 'off'}: behind bumps {b['samples']} samples, "
                  f"{b['confident_wrong']} off > 2 cm at sigma < 1 cm, max {b['max_err_cm_sigma_below_1cm']:.2f} cm "
                  f"at sigma < 1 cm; all samples {row['all']['confident_wrong_pct']:.2f} %",
                  file=sys.stderr, flush=True)
            rows["map_on" if fused else "map_off"] = row
        out["backends"][name] = rows
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_preview_sigma",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--backends", nargs="+", default=["bev_sweep", "stereo", "mono"])
    parser.add_argument("--lead-time", type=float, default=0.1)
    parser.add_argument("--out", default=str(RESULTS / "preview_sigma.json"))
    args = parser.parse_args(argv)
    status = available_backends(args.backends)
    backends = [b for b in args.backends if not status.get(b)]
    for b in args.backends:
        if status.get(b):
            print(f"skipping {b}: {status[b]}", file=sys.stderr)
    info = machine_info()
    start = time.perf_counter()
    result = run(backends, args.lead_time)
    data = {
        "what": "preview samples at the front wheels' arrival on the demo drive: confidently wrong "
                f"(|error| > {100 * WRONG_M:g} cm at sigma < {100 * SURE_M:g} cm) behind speed bumps "
                f"(bump centre to {BEHIND_M:g} m past it) and over all samples, map off and on",
        "command": "python -m benchmarks.bench_preview_sigma " + " ".join(argv if argv is not None else sys.argv[1:]),
        "lead_time_s": args.lead_time,
        "machine": info,
        "wall_s": 0.0,
        **result,
    }
    data["wall_s"] = round(time.perf_counter() - start, 1)
    write_json(Path(args.out), data)
    print(f"wrote {args.out} in {data['wall_s']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
