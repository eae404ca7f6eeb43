"""``roadbev figures --out DIR``: render a synthetic frame and draw the geometry and label figures.

Writes ``voxel_columns.png`` (the left image with the grid's voxel columns projected as line
segments, as the paper's Fig. 4) and ``gt_elevation.png`` (the ground-truth elevation map with a
colour bar in cm) for one synthetic sample on the real RSRD half-resolution rig.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from roadbev_cli.cli import list_item
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_lab.reports.figures import elevation_figure, voxel_columns_figure
from roadbev_lab.synth import FEATURE_NAMES, REAL_ROAD_MIDDLE, RoadConfig, make_sample

HELP = "render the geometry and label figures (voxel columns, GT elevation map)"
DEFAULT_FEATURES = ("pothole", "speed_bump", "crack")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("figures"), help="output directory (default: ./figures)")
    parser.add_argument("--seed", type=int, default=0, help="synthetic scene seed (default 0)")
    parser.add_argument("--road-class", default="C", help="ISO 8608 roughness class A..E (default C)")

    parser.add_argument(
        "--features", nargs="*", type=list_item, metavar="FEATURE", choices=FEATURE_NAMES,
        default=list(DEFAULT_FEATURES),
        help=f"road features placed in the grid, space-separated, from: {', '.join(FEATURE_NAMES)} "
             f"(default {' '.join(DEFAULT_FEATURES)}; give the flag alone for none)",
    )
    parser.add_argument("--surface", default="asphalt", choices=("asphalt", "concrete"),
                        help="pavement of the rendered scene (default asphalt)")
    parser.add_argument("--step", type=int, default=8, help="draw every STEP-th grid row and column (default 8)")


def run(args: argparse.Namespace) -> int:
    # Imported here: `roadbev --help` stays fast.

    features = tuple(args.features)
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class=str(args.road_class).upper(), features=features,
                                             surface=args.surface))
    grid = GridSpec()
    sample = make_sample(int(args.seed), camera=StereoCamera.rsrd_half(), grid=grid, road=road)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cols = voxel_columns_figure(sample.frame, grid, out / "voxel_columns.png", row_step=args.step, col_step=args.step)
    feats = ", ".join(features) or "no features"
    elev = elevation_figure(
        sample.truth.elevation,
        grid,
        out / "gt_elevation.png",
        title=f"GT elevation (seed {args.seed}, class {road.road_class}, {feats})",
    )
    print(cols)
    print(elev)
    return 0
