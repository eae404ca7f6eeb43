"""Road hazards: what the detector finds on a perfect map, and what the tracker reports from the
fused map of rendered drives, how early.

**True road maps** (default): for every seed, a :class:`roadbev_lab.synth.RidingDrive` over a
class-B road with speed bumps, humps and potholes every ~8 m, and three smooth roads without
features (ISO 8608 A, B, C), 200 m each (10 m/s, 20 s); :func:`roadbev_core.hazards.detect_hazards`
runs on the drive's true road map cut to the corridor a fused map covers (the path's lateral span
+- 1 m). Scores: the share of features >= 3 cm in that corridor found (within 0.5 m along x;
potholes also across), their height error relative to the feature's nominal height
(``features_in_odom``), and detections that match no feature, per km of corridor: the
detector's ceiling.

**Fused map** (``--map``): for every speed, a drive is rendered (full 960 x 528 rig, camera at
``--rate``) over a class-B road with speed bumps, humps and potholes every ``--spacing`` m, plus
one smooth class-B drive without features; the pipeline (``--backend``, map on, the drive's own
drifting, noisy odometry, as ``roadbev eval --map``) builds the fused map, and
:class:`roadbev_core.hazard_tracking.HazardTracker` runs on every published map window with the
pipeline's ``base_link`` pose, as ``roadbev_ros.hazard_monitor`` does. Per feature >= 3 cm that
passes under the map's corridor (its centre within the grid's lateral range, widened by half its
width, when the front axle reaches it): reported or not (a reported track of the same kind
within 0.5 m along x, potholes also across), the distance from the front axle to its near edge
at the first report (the tracker's ``first_reported_distance_m``) and the time from that map's
stamp until the true front axle reaches the near edge (ground truth poses; the monitor's own
latency comes on top), against what the window allows (its far edge ahead of the front axle /
speed); the height error at the first report, when the feature's near edge comes within
the grid's far edge ahead of the camera (7.08 m: the report as it stands then) and at the last
update; reported tracks that match no feature, per km driven. ``--far-field`` runs the pipeline
with ``far_field.enabled`` (the map and its window reach the far-field grid's far edge);
``--latency`` charges the node's latency (image stamp to map received) on every lead time.

Run: ``.venv/bin/python -m benchmarks.bench_hazards [--seeds 3]`` (true maps, writes
``benchmarks/results/hazards.json``) or ``.venv/bin/python -m benchmarks.bench_hazards --map
[--speeds 5 10 20] [--rate 10] [--duration 12] [--smooth-duration S] [--backend B] [--far-field]
[--latency S]`` (writes
``benchmarks/results/hazards_map.json``); both take ``--jobs N`` or ``--ray ADDRESS`` (drives in parallel).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import RESULTS, add_executor_arguments, executor_from, machine_info, write_json
from roadbev_core.config import DEFAULT_BACKEND

SEED_BASE = 320_000
ROADS: dict[str, tuple[str, tuple[str, ...]]] = {
    "features": ("B", ("speed_bump", "hump", "pothole")),
    "smooth_A": ("A", ()), "smooth_B": ("B", ()), "smooth_C": ("C", ()),
}


def run_drive(kind: str, seed: int, duration: float, speed: float) -> dict[str, Any]:
    """One drive's detections against its features."""
    from roadbev_core.hazards import band, detect_hazards
    from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RidingConfig, RidingDrive, RoadConfig

    road_class, features = ROADS[kind]
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class=road_class, features=features, feature_spacing_m=8.0))
    frames = int(round(duration * 10))
    drive = RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=speed, frame_rate_hz=10.0, seed=seed,
                                                       road=road)))
    rm = drive.road_map()
    path = drive.ground_truth_poses().position
    y_lo, y_hi = float(path[:, 1].min()) - 1.0, float(path[:, 1].max()) + 1.0
    lane, centre = band(rm.elevation, rm.resolution, rm.centre, y_lo, y_hi)
    start = time.perf_counter()
    found = detect_hazards(lane, None, rm.resolution, centre)
    detect_s = time.perf_counter() - start
    x_lo = rm.centre[0] - 0.5 * rm.elevation.shape[0] * rm.resolution + 1.0
    x_hi = float(path[-1, 0]) + 1.0
    truth = [f for f in drive.features_in_odom() if x_lo < f[1] < x_hi and y_lo < f[2] < y_hi and abs(f[3]) >= 0.03]
    matched, errors = 0, []
    used: set[int] = set()
    for name, fx, fy, height in truth:
        hits = [i for i, h in enumerate(found) if abs(h.x - fx) < 0.5 and (name != "pothole" or abs(h.y - fy) < 0.5)]
        if hits:
            matched += 1
            used.update(hits)
            errors.append(abs(found[hits[0]].height_m - height) / abs(height))
    in_range = [i for i, h in enumerate(found) if x_lo < h.x < x_hi]
    false = [i for i in in_range if i not in used and not any(abs(found[i].x - f[1]) < 0.5
                                                                for f in drive.features_in_odom())]
    length_km = (x_hi - x_lo) / 1000.0
    return {"road": kind, "seed": seed, "features": len(truth), "detected": matched,
            "height_rel_err": [round(e, 4) for e in errors], "false_alarms": len(false), "length_km": length_km,
            "detect_s": round(detect_s, 2)}


MAP_SEED_BASE = 330_000
MAP_KINDS = {"speed_bump": "bump", "hump": "bump", "pothole": "pothole"}
# The fused map is the node's default configuration's unless --backend names another.
MAP_BACKEND = DEFAULT_BACKEND


def _feature_extent(feature: Any) -> tuple[float, float]:
    """Half extent of a synthetic feature along the road and across it (m)."""
    if hasattr(feature, "length") and hasattr(feature, "width"):
        return 0.5 * float(feature.length), 0.5 * float(feature.width)
    r = max(float(getattr(feature, "radius_x", 0.0)), float(getattr(feature, "radius_y", 0.0)))
    return r, r


def _odometry_to_truth(x: float, y: float, stamp_ns: int, odometry: list[Any], gt: Any) -> tuple[float, float]:
    """A point of the odometry's frame in the true ``odom`` frame, through ``base_link`` at ``stamp_ns``."""
    from roadbev_core.geometry import quaternion_to_rotation
    from roadbev_core.vehicle import planar_yaw
    from roadbev_lab.evaluation.arrival import carried_through_car

    t = np.array([p.stamp_ns for p in odometry], np.float64)
    held = np.array([np.interp(stamp_ns, t, [getattr(p, k) for p in odometry]) for k in ("x", "y", "yaw")])
    k = int(np.clip(np.searchsorted(gt.stamp_ns, stamp_ns), 0, len(gt.stamp_ns) - 1))
    true = np.array([gt.position[k, 0], gt.position[k, 1], planar_yaw(quaternion_to_rotation(*gt.orientation_xyzw[k]))])
    tx, ty = carried_through_car(np.asarray(x, np.float64), np.asarray(y, np.float64), held, true)
    return float(tx), float(ty)


def run_map_drive(speed: float, rate: float, duration: float, seed: int, spacing: float, backend: str,
                  features: bool, far_field: bool = False, latency_s: float = 0.0) -> dict[str, Any]:
    """Render one drive, build its fused map with ``backend`` (and the far field), track hazards
    on every window, score the reports against the drive's features (lead times less ``latency_s``)."""
    from roadbev_core.config import FarFieldConfig, RoadbevConfig
    from roadbev_core.geometry import quaternion_to_rotation
    from roadbev_core.hazard_tracking import HazardTracker, TrackerSettings
    from roadbev_core.pipeline import Pipeline, check_config
    from roadbev_lab.evaluation.frames import evaluate
    from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RidingConfig, RidingDrive, RoadConfig
    from roadbev_lab.synth.riding import planar_odometry

    features_on = ("speed_bump", "hump", "pothole") if features else ()
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class="B", features=features_on, feature_spacing_m=spacing))
    frames = max(2, int(round(duration * rate)))
    drive = RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=speed, frame_rate_hz=rate, seed=seed,
                                                       road=road), tail_s=1.5))
    grid = drive.config.grid
    config = check_config(RoadbevConfig.from_params({**grid.to_dict(), "backend": backend, "map.enabled": True,
                                                     "far_field.enabled": far_field}))
    reach_x = FarFieldConfig().grid(grid).x_max if far_field else grid.x_max  # the map's window ahead of the camera
    pipeline = Pipeline(config, configure_process=False)
    pipeline.set_camera_mount(*drive.base_to_camera)
    tracker = HazardTracker(TrackerSettings(vehicle=config.vehicle))
    track_ms: list[float] = []
    heights: dict[int, list[tuple[int, float]]] = {}  # track id -> (map stamp, reported height) per window

    def on_output(out: Any) -> None:
        if out.map is None:
            return
        t0 = time.perf_counter()
        report = tracker.update(out.map, out.base_pose)
        track_ms.append(1e3 * (time.perf_counter() - t0))
        for t in report.hazards:
            heights.setdefault(t.id, []).append((report.stamp_ns, t.height_m))

    start = time.perf_counter()
    odometry = planar_odometry(drive.odometry())
    evaluate(pipeline, drive, odometry=odometry, on_output=on_output)
    run_s = time.perf_counter() - start
    gt = drive.ground_truth_poses()
    tracks = [t for t in [*tracker.retired, *tracker.tracks] if t.confirmed]
    # the map lives in the drifting odometry's frame, the features in the true one: each track's
    # position is carried over through base_link at its last detection
    for t in tracks:
        t.x, t.y = _odometry_to_truth(t.x, t.y, t.last_seen_ns, odometry, gt)
    # ground truth: the front axle along the drive
    R = np.array([quaternion_to_rotation(*q) for q in gt.orientation_xyzw])  # [K, 3, 3]
    wheelbase = config.vehicle.wheelbase_m
    front = gt.position[:, :2] + wheelbase * R[:, :2, 0]  # [K, 2]
    heading = R[:, :2, 0] / np.linalg.norm(R[:, :2, 0], axis=1, keepdims=True)
    stamps = gt.stamp_ns.astype(np.int64)
    last_frame_ns = int(drive.frame_stamps_ns[-1])
    cam_x = float(drive.base_to_camera[0][0])
    reach_m = cam_x + reach_x - wheelbase  # the window's far edge ahead of the front axle
    latency_ns = int(round(latency_s * 1e9))
    scored: list[dict[str, Any]] = []
    matched_ids: set[int] = set()
    for (name, fx, fy, height), feat in zip(drive.features_in_odom(), drive.scene.features, strict=True):
        half_x, half_y = _feature_extent(feat)
        ahead = (fx - front[:, 0]) * heading[:, 0] + (fy - front[:, 1]) * heading[:, 1] - half_x  # [K]
        reached = np.flatnonzero(ahead <= 0.0)
        if reached.size == 0 or reached[0] == 0:
            continue  # not reached during the drive, or under the car from the start
        k = int(reached[0])
        arrival_ns = int(stamps[k])
        if arrival_ns > last_frame_ns + int(1.0 * 1e9):
            continue  # reached after the camera stopped (no map of it in time)
        lateral = -(fx - gt.position[k, 0]) * heading[k, 1] + (fy - gt.position[k, 1]) * heading[k, 0]
        cam_y = float(drive.base_to_camera[0][1])
        in_corridor = cam_y + grid.y_min - half_y <= lateral <= cam_y + grid.y_max + half_y
        kind = MAP_KINDS.get(name)
        hits = [t for t in tracks if kind is not None and t.kind == kind and abs(t.x - fx) < 0.5 + half_x
                and (name != "pothole" or abs(t.y - fy) < 0.5 + half_y)]
        matched_ids.update(t.id for t in hits)
        if abs(height) < 0.03 or kind is None or not in_corridor:
            continue
        row: dict[str, Any] = {"name": name, "x": round(fx, 2), "y": round(fy, 2), "height_m": round(height, 4),
                               "lateral_m": round(float(lateral), 2), "reported": bool(hits)}
        if hits:
            t = min(hits, key=lambda h: h.first_reported_ns or 0)
            # the report as it stands when the near edge comes within the grid's far edge of the camera
            near = np.flatnonzero(ahead <= grid.x_max - (wheelbase - cam_x))
            near_ns = int(stamps[near[0]]) if near.size else arrival_ns
            history = heights.get(t.id, [])
            then = [h for stamp, h in history if stamp + latency_ns <= near_ns] or [h for _, h in history[:1]]
            row.update(first_reported_distance_m=round(t.first_reported_distance_m, 3),
                       lead_s=round((arrival_ns - int(t.first_reported_ns or 0) - latency_ns) * 1e-9, 3),
                       first_height_rel_err=round(abs(t.first_reported_height_m - height) / abs(height), 4),
                       height_at_near_rel_err=round(abs(then[-1] - height) / abs(height), 4) if then else None,
                       height_est_m=round(t.height_m, 4),
                       height_rel_err=round(abs(t.height_m - height) / abs(height), 4),
                       detections=t.detections)
        scored.append(row)
    false = [t for t in tracks if t.id not in matched_ids]
    travelled_km = float(np.sum(np.linalg.norm(np.diff(gt.position[:, :2], axis=0), axis=1))) / 1000.0
    return {"speed_mps": speed, "rate_hz": rate, "seed": seed, "features_on_road": features, "frames": frames,
            "far_field": far_field, "latency_s": latency_s,
            "window_reach_m": round(reach_m, 3), "window_lead_s": round(reach_m / speed - latency_s, 3),
            "features": scored, "false_alarms": len(false),
            "false_alarm_tracks": [{"kind": t.kind, "x": round(t.x, 2), "y": round(t.y, 2),
                                    "height_m": round(t.height_m, 4), "detections": t.detections} for t in false],
            "km": round(travelled_km, 4), "run_s": round(run_s, 1),
            "tracker_ms_p50": round(float(np.median(track_ms)), 2) if track_ms else None}


def summarise_map(drives: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per speed: features, reported share, lead times and distances, height errors, false alarms per km."""
    out = []
    for speed in sorted({d["speed_mps"] for d in drives}):
        ds = [d for d in drives if d["speed_mps"] == speed]
        feats = [f for d in ds for f in d["features"]]
        rep = [f for f in feats if f["reported"]]
        leads = [f["lead_s"] for f in rep]
        errs = [f["height_rel_err"] for f in rep]
        first_errs = [f["first_height_rel_err"] for f in rep if "first_height_rel_err" in f]
        near_errs = [f["height_at_near_rel_err"] for f in rep if f.get("height_at_near_rel_err") is not None]
        with_features = [d for d in ds if d["features_on_road"]]
        smooth = [d for d in ds if not d["features_on_road"]]
        row: dict[str, Any] = {
            "speed_mps": speed, "features": len(feats), "reported": len(rep),
            "reported_pct": 100.0 * len(rep) / max(1, len(feats)),
            "reported_1s_ahead_pct": 100.0 * sum(v >= 1.0 for v in leads) / max(1, len(feats)),
            "reported_0.6s_ahead_pct": 100.0 * sum(v >= 0.6 for v in leads) / max(1, len(feats)),
            "window_lead_s": ds[0]["window_lead_s"],
            "lead_s_median": float(np.median(leads)) if leads else None,
            "lead_s_min": float(np.min(leads)) if leads else None,
            "first_reported_distance_m_median": float(np.median([f["first_reported_distance_m"] for f in rep]))
            if rep else None,
            "height_rel_err_mean": float(np.mean(errs)) if errs else None,
            "first_height_rel_err_mean": float(np.mean(first_errs)) if first_errs else None,
            "height_at_near_rel_err_mean": float(np.mean(near_errs)) if near_errs else None,
            "height_within_15pct": float(np.mean(np.array(errs) <= 0.15)) if errs else None,
            "false_alarms_per_km_feature_roads": sum(d["false_alarms"] for d in with_features)
            / max(1e-9, sum(d["km"] for d in with_features)) if with_features else None,
            "false_alarms_smooth": sum(d["false_alarms"] for d in smooth) if smooth else None,
            "smooth_km": sum(d["km"] for d in smooth) if smooth else None,
        }
        out.append(row)
    return out


def smooth_duration(args: argparse.Namespace) -> float:
    """Seconds of the smooth drives (``--smooth-duration``, default ``--duration``): false alarms
    per km need a longer drive than the features do."""
    return float(args.duration if args.smooth_duration is None else args.smooth_duration)


def _map_job(job: tuple[float, float, float, int, float, str, bool, bool, float]) -> dict[str, Any]:
    """:func:`run_map_drive` of one drive, with its lines on stderr."""
    speed, rate, duration, seed, spacing, backend, features, far_field, latency_s = job
    print(f"rendered drive {speed:g} m/s {'features' if features else 'smooth'} seed {seed}, "
          f"{duration:g} s at {rate:g} Hz", file=sys.stderr, flush=True)
    d = run_map_drive(speed, rate, duration, seed, spacing, backend, features, far_field, latency_s)
    rep = [f for f in d["features"] if f["reported"]]
    print(f"  {len(rep)}/{len(d['features'])} features reported, leads "
          f"{sorted(f['lead_s'] for f in rep)} s (window {d['window_lead_s']} s), "
          f"{d['false_alarms']} false alarms over {d['km'] * 1000:.0f} m", file=sys.stderr, flush=True)
    return d


def _drive_job(job: tuple[str, int, float, float]) -> dict[str, Any]:
    """:func:`run_drive` of one drive, with its line on stderr."""
    d = run_drive(*job)
    print(f"  {d['road']:9s} seed {d['seed']}: {d['detected']}/{d['features']} features, "
          f"{d['false_alarms']} false alarms over {d['length_km'] * 1000:.0f} m", file=sys.stderr, flush=True)
    return d


def main_map(args: argparse.Namespace, argv: list[str] | None, parser: argparse.ArgumentParser) -> int:
    """The fused-map benchmark (``--map``)."""
    info = machine_info()
    start = time.perf_counter()
    jobs = []
    for i, speed in enumerate(args.speeds):
        for features in (True, False) if speed in args.smooth_speeds else (True,):
            seed = MAP_SEED_BASE + 100 * i + (0 if features else 50)
            duration = args.duration if features else smooth_duration(args)
            jobs.append((speed, args.rate, duration, seed, args.spacing, args.backend, features, args.far_field,
                         args.latency))
    with executor_from(args, parser) as pool:  # drives are independent and deterministic: the same results anywhere
        drives = pool.map(_map_job, jobs)
        info["executor"] = pool.describe()
    data = {"what": "hazards tracked on the fused map of rendered drives (bench_hazards --map; see its docstring)",
            "command": "python -m benchmarks.bench_hazards " + " ".join(argv if argv is not None else sys.argv[1:]),
            "backend": args.backend, "far_field": args.far_field, "latency_s": args.latency, "machine": info,
            "wall_s": round(time.perf_counter() - start, 1),
            "summary": summarise_map(drives), "drives": drives}
    out = Path(args.out or RESULTS / "hazards_map.json")
    write_json(out, data)
    print(f"wrote {out}: {data['summary']}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--duration", type=float, default=None,
                        help="seconds per drive (default 20 on true maps, 12 with --map)")
    parser.add_argument("--speed", type=float, default=10.0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--map", action="store_true", help="on the fused map of rendered drives")
    parser.add_argument("--speeds", type=float, nargs="+", default=[5.0, 10.0, 20.0], help="--map: speeds")
    parser.add_argument("--smooth-speeds", type=float, nargs="*", default=[20.0],
                        help="--map: speeds that also get a smooth drive without features")
    parser.add_argument("--smooth-duration", type=float, default=None,
                        help="--map: seconds per smooth drive (default --duration)")
    parser.add_argument("--rate", type=float, default=10.0, help="--map: camera rate (Hz)")
    parser.add_argument("--spacing", type=float, default=6.0, help="--map: feature spacing (m)")
    parser.add_argument("--backend", default=MAP_BACKEND, help=f"--map: the backend (default {MAP_BACKEND})")
    parser.add_argument("--far-field", action="store_true",
                        help="--map: far_field.enabled (the map reaches the far-field grid's far edge)")
    parser.add_argument("--latency", type=float, default=0.0,
                        help="--map: the node's latency (s, image stamp to map received), charged on every lead")
    add_executor_arguments(parser, "drives run")
    args = parser.parse_args(argv)
    if args.smooth_duration is not None and not args.smooth_duration > 0:
        parser.error(f"--smooth-duration must be > 0 s, got {args.smooth_duration}")
    if args.map:
        args.duration = 12.0 if args.duration is None else args.duration
        return main_map(args, argv, parser)
    args.duration = 20.0 if args.duration is None else args.duration
    args.out = args.out or str(RESULTS / "hazards.json")
    info = machine_info()
    start = time.perf_counter()
    jobs = [(kind, SEED_BASE + 100 * k + s, args.duration, args.speed) for k, kind in enumerate(ROADS)
            for s in range(args.seeds)]
    with executor_from(args, parser) as pool:  # drives are independent and deterministic: the same results anywhere
        drives = pool.map(_drive_job, jobs)
        info["executor"] = pool.describe()
    feats = [d for d in drives if d["road"] == "features"]
    smooth = [d for d in drives if d["road"] != "features"]
    errs = [e for d in feats for e in d["height_rel_err"]]
    summary = {
        "detection_rate": sum(d["detected"] for d in feats) / max(1, sum(d["features"] for d in feats)),
        "features": sum(d["features"] for d in feats),
        "height_rel_err_mean": float(np.mean(errs)) if errs else None,
        "height_rel_err_max": float(np.max(errs)) if errs else None,
        "height_within_15pct": float(np.mean(np.array(errs) <= 0.15)) if errs else None,
        "false_alarms_per_km_smooth": sum(d["false_alarms"] for d in smooth) / sum(d["length_km"] for d in smooth),
        "false_alarms_per_km_feature_roads": sum(d["false_alarms"] for d in feats) / sum(d["length_km"] for d in feats),
        "smooth_km": sum(d["length_km"] for d in smooth),
    }
    data = {"what": "hazard detection on the true road maps of drives (the detector's ceiling)",
            "command": "python -m benchmarks.bench_hazards " + " ".join(argv if argv is not None else sys.argv[1:]),
            "machine": info, "wall_s": round(time.perf_counter() - start, 1), "summary": summary, "drives": drives}
    write_json(Path(args.out), data)
    print(f"wrote {args.out}: {summary}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
