"""The typed config tree and the params-file reader: names, types, ranges, the whole, cost limits."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from roadbev_core.config import (
    MAX_GRID_VOXELS,
    GridSpec,
    ParamError,
    RoadbevConfig,
    check_image_size,
    load_params_file,
    parameter_specs,
    parse_assignments,
    split_backend_spec,
)
from roadbev_core.config.grid import ConfigError

REPO = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def test_wildcard_first_then_node_section_and_other_sections_are_reported(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
/**:
  ros__parameters:
    base_height: 1.5
    resolution: 0.06
other_node:
  ros__parameters:
    base_height: 9.0
/roadbev:
  ros__parameters:
    base_height: 1.3
    preview:
      tyre_width_m: 0.25
""",
    )
    loaded = load_params_file(path)
    assert loaded.values == {"base_height": 1.3, "resolution": 0.06, "preview.tyre_width_m": 0.25}
    assert loaded.other_sections == ("other_node",) and "other_node" in (loaded.note() or "")
    assert load_params_file(path, node_name="other_node").values["base_height"] == 9.0
    assert load_params_file(path, node_name="/vehicle/roadbev").values["base_height"] == 1.3


@pytest.mark.parametrize(
    "text, reason",
    [("roadbev: [1, 2\n", "not valid YAML"), ("- 1\n", "must map"), ("roadbev:\n  x: 1\n", "ros__parameters"),
     ("other:\n  ros__parameters: {a: 1}\n", "no section for node 'roadbev'")],
)
def test_bad_params_files(tmp_path: Path, text: str, reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        load_params_file(write(tmp_path, text))
    with pytest.raises(ParamError, match="cannot read"):
        load_params_file(tmp_path / "missing.yaml")


def test_empty_file_gives_no_parameters(tmp_path: Path) -> None:
    assert load_params_file(write(tmp_path, "")).values == {}


def test_shipped_params_file_is_generated_from_the_tree() -> None:
    from roadbev_core.config.tree import params_yaml

    assert (REPO / "config" / "roadbev.params.yaml").read_text() == params_yaml(), (
        "regenerate: python -m roadbev_core.config > config/roadbev.params.yaml")


def test_shipped_params_file_lists_every_parameter_at_its_default() -> None:
    values = load_params_file(REPO / "config" / "roadbev.params.yaml").values
    defaults = RoadbevConfig().to_params()
    assert set(values) == set(defaults), "config/roadbev.params.yaml and the config tree differ"
    for name, value in values.items():
        assert value == pytest.approx(defaults[name]), f"shipped {name} differs from the declared default"
    assert RoadbevConfig.from_params(values) == RoadbevConfig.from_params({})


def test_every_parameter_has_a_description_a_valid_default_and_one_name() -> None:
    names = [s.name for s in parameter_specs()]
    assert len(names) == len(set(names))
    for spec in parameter_specs():
        assert spec.description
        spec.check(spec.default)
    assert {"base_height", "x_min", "resolution", "class_resolution", "vehicle.wheelbase_m"} <= set(names)
    backend = next(s for s in parameter_specs() if s.name == "backend")
    # from the backend registry
    assert backend.choices == ("adabins", "bev_sweep", "bm", "ensemble", "gwcnet", "mono", "sgbm", "stereo")


def test_round_trip_and_typed_sections() -> None:
    config = RoadbevConfig.from_params({"base_height": 1.3, "sync_slop_s": 0, "backend": "bev_sweep",
                                        "bev_sweep.patch_cells": 5, "imu_to_camera_rpy_deg": [0, 1, 2]})
    assert config.grid == GridSpec(base_height=1.3)
    assert config.sync.slop_s == 0.0 and isinstance(config.sync.slop_s, float)
    assert config.imu.imu_to_camera_rpy_deg == (0.0, 1.0, 2.0)
    assert config.backend.options_of() == {"patch_cells": 5}
    assert RoadbevConfig.from_params(config.to_params()) == config
    learned = RoadbevConfig.from_params({"backend": "stereo", "checkpoint": "x.pt", "stereo.runtime": "torch"})
    assert learned.backend.options_of() == {"runtime": "torch", "checkpoint": "x.pt"}
    assert learned.backend.options_of("bm") == {}
    # the checkpoint parameter goes to the learned backends only
    assert RoadbevConfig.from_params({"backend": "bm", "checkpoint": "x.pt"}).backend.options_of() == {}


def test_a_backend_named_by_its_module_path_takes_its_options_without_being_imported() -> None:
    config = RoadbevConfig.from_params({"backend": "no_such_pkg.road:create", "no_such_pkg.road:create.scale": 2,
                                        "bm.block_size": 9})
    assert config.backend.options_of() == {"scale": 2}
    assert config.backend.options_of("bm") == {"block_size": 9}
    assert RoadbevConfig.from_params(config.to_params()) == config
    with pytest.raises(ParamError, match=r"unknown parameter 'no_such_pkg\.road\.scale'"):
        RoadbevConfig.from_params({"no_such_pkg.road.scale": 2})


def test_the_config_leaves_what_only_a_component_judges_to_the_component() -> None:
    # the wheel tracks on the grid are checked by roadbev_core.pipeline.check_config, with the preview
    config = RoadbevConfig.from_params({"preview.tyre_width_m": 0.0})
    assert config.preview.tyre_width_m == 0.0


@pytest.mark.parametrize(
    "params, reason",
    [
        ({"base_hieght": 1.2}, "unknown parameter 'base_hieght' \\(did you mean 'base_height'\\?\\)"),
        ({"bev_swep.patch_cells": 5}, "unknown parameter 'bev_swep.patch_cells'"),
        ({"backend": "magic"}, "must be one of"),
        ({"sync_slop_s": -0.1}, "below its minimum"),
        ({"sync_queue_size": 5000}, "above its maximum"),
        ({"sync_queue_size": 2.5}, "integer"),
        ({"imu_max_age_s": float("nan")}, "finite"),
        ({"require_imu": 1}, "true or false"),
        ({"base_height": "high"}, "must be a number"),
        ({"imu_to_camera_rpy_deg": [0.0, 1.0]}, "needs 3"),
        ({"imu_to_camera_rpy_deg": [0.0, "a", 1.0]}, "list of finite"),
        ({"resolution": 0.07}, "whole number"),
        ({"z_max": 2.0}, "below the camera"),
        ({"backend": "not a path:"}, "backend must be one of adabins, bev_sweep, bm, ensemble, gwcnet, mono, sgbm, "
                                     "stereo; "
                                     "got 'not a path:'"),
        ({"bm": 5}, "unknown parameter 'bm'"),
        ({"pkg.mod": 5}, "unknown parameter 'pkg.mod'"),
    ],
)
def test_nonsense_is_refused_with_the_parameters_name(params: dict[str, Any], reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        RoadbevConfig.from_params(params)


def test_costly_settings_are_refused_before_anything_is_allocated() -> None:
    with pytest.raises(ParamError, match="voxels, more than the limit"):
        RoadbevConfig.from_params({"resolution": 0.001, "x_max": 200.0})  # crashed the node before
    with pytest.raises(ParamError, match="voxels, more than the limit"):
        RoadbevConfig.from_params({"resolution": 0.001})  # took bev_sweep past 8 GB before
    with pytest.raises(ParamError, match="stamp combinations per message"):
        RoadbevConfig.from_params({"sync_slop_s": 1.0, "sync_queue_size": 1000})  # froze the executor before
    # each alone is fine: a deep queue with a tight slop, a wide slop with a short queue
    RoadbevConfig.from_params({"sync_slop_s": 0.02, "sync_queue_size": 1000})
    RoadbevConfig.from_params({"sync_slop_s": 1.0, "sync_queue_size": 50})
    default = GridSpec()
    assert default.n_rows * default.n_cols * default.n_classes < MAX_GRID_VOXELS
    with pytest.raises(ConfigError, match="larger than the limit"):
        check_image_size(8000, 8000)
    check_image_size(1920, 1080)


def test_the_far_field_is_on_by_default_a_coarser_grid_beyond_the_grid() -> None:
    on = RoadbevConfig()
    assert on.far_field.enabled and on.far_grid == RoadbevConfig.from_params({"far_field.enabled": True}).far_grid
    assert RoadbevConfig.from_params({"far_field.enabled": False}).far_grid is None
    far = on.far_grid
    assert far is not None and far.shape == (66, 16) and far.resolution == 0.12
    assert (far.x_min, far.x_max) == (on.grid.x_max, 15.0) and (far.y_min, far.y_max) == (on.grid.y_min, on.grid.y_max)
    assert (far.z_min, far.z_max, far.base_height) == (-0.5, 0.5, on.grid.base_height)
    assert on.far_field.topic == "/roadbev/elevation_far"
    assert RoadbevConfig.from_params(on.to_params()) == on
    # the grid moves, the far field follows it
    moved = on.with_params({"x_max": 7.2, "base_height": 1.3})
    assert moved.far_grid == GridSpec(x_min=7.2, x_max=15.0, resolution=0.12, z_min=-0.5, z_max=0.5, base_height=1.3)
    # off, far-field settings that would not make a grid are not judged (nothing changes for the grid alone)
    assert RoadbevConfig.from_params({"x_max": 7.11, "far_field.enabled": False}).far_grid is None


@pytest.mark.parametrize(
    "params, window",
    [
        # a far edge or a cell that does not cut the window into whole cells: the far edge moves out
        ({"far_field.resolution": 0.1}, (7.08, 15.08, -0.96, 1.04)),
        ({"x_min": 2.1, "x_max": 3.06}, (3.06, 15.06, -0.92, 1.0)),
        ({"far_field.x_max": 12.1}, (7.08, 12.12, -0.92, 1.0)),
        ({"x_max": 7.11}, (7.11, 15.03, -0.92, 1.0)),
        # a grid as wide as no whole number of far cells: both sides move out by half the remainder
        ({"y_min": -0.9, "y_max": 0.96}, (7.08, 15.0, -0.93, 0.99)),
    ],
)
def test_the_far_field_follows_any_grid_in_whole_cells(params: dict[str, Any],
                                                       window: tuple[float, float, float, float]) -> None:
    config = RoadbevConfig.from_params({"far_field.enabled": True, **params})
    far = config.far_grid
    assert far is not None and (far.x_min, far.x_max, far.y_min, far.y_max) == pytest.approx(window, abs=1e-9)
    assert far.x_min == config.grid.x_max  # edge to edge with the grid
    assert far.x_max >= config.far_field.x_max and far.x_max - config.far_field.x_max < far.resolution
    assert far.y_min <= config.grid.y_min and far.y_max >= config.grid.y_max
    assert 0.5 * (far.y_min + far.y_max) == pytest.approx(0.5 * (config.grid.y_min + config.grid.y_max))
    assert config.far_field.off_reason(config.grid) == ""


def test_a_window_of_whole_cells_keeps_its_edges_to_the_bit() -> None:
    far = RoadbevConfig.from_params({"far_field.enabled": True}).far_grid
    assert far is not None and (far.x_min, far.x_max, far.y_min, far.y_max) == (7.08, 15.0, -0.92, 1.0)


def test_a_grid_that_reaches_the_far_edge_leaves_the_far_field_nothing_and_says_so() -> None:
    for params in ({"far_field.x_max": 7.0}, {"far_field.x_max": 7.08}, {"x_min": 2.1, "x_max": 20.1}):
        config = RoadbevConfig.from_params({"far_field.enabled": True, **params})  # accepted, not refused
        assert config.far_grid is None
        assert config.far_field.off_reason(config.grid).startswith("the grid already reaches far_field.x_max")
        with pytest.raises(ConfigError, match="already reaches"):
            config.far_field.grid(config.grid)
    assert RoadbevConfig().far_field.off_reason(GridSpec()) == ""  # the default grid leaves it 7.08-15 m


@pytest.mark.parametrize(
    "params, reason",
    [
        ({"far_field.z_max": 1.5}, "below the camera"),
        ({"far_field.z_max": 0.505}, "far-field parameters do not form a valid grid: vertical z"),
        ({"x_max": 7.12}, "grid parameters do not form a valid grid: longitudinal x"),
        ({"far_field.resolution": 0.01, "far_field.x_max": 100.0}, "the far-field grid .* voxels, more than the limit"),
    ],
)
def test_far_field_settings_that_do_not_make_a_grid_are_refused_with_their_names(params: dict[str, Any],
                                                                                reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        RoadbevConfig.from_params({"far_field.enabled": True, **params})


def test_with_params_changes_and_revalidates() -> None:
    config = RoadbevConfig()
    changed = config.with_params({"backend": "bm"})
    assert changed.backend.name == "bm" and changed.grid == config.grid
    with pytest.raises(ParamError):
        changed.with_params({"resolution": 0.001})


def test_command_line_assignments_parse_json_values_and_fall_back_to_text() -> None:
    assert parse_assignments(["zncc_subsamples=2", "zncc_full_resolution=true", "sampling=integer"], "-o") == {
        "zncc_subsamples": 2, "zncc_full_resolution": True, "sampling": "integer"}
    with pytest.raises(ParamError, match="--model-option takes NAME=VALUE"):
        parse_assignments(["zncc_subsamples"], "--model-option")


def test_a_backend_spec_is_a_name_with_options_and_a_plugin_path_is_a_name() -> None:
    assert split_backend_spec("bm") == ("bm", {})
    assert split_backend_spec("bm:plane_parallax_px=16,mode=3way") == ("bm", {"plane_parallax_px": 16, "mode": "3way"})
    assert split_backend_spec("my_pkg.roads:make_backend") == ("my_pkg.roads:make_backend", {})
    assert split_backend_spec("my_pkg.roads:make_backend:depth=2") == ("my_pkg.roads:make_backend", {"depth": 2})
    assert split_backend_spec("ensemble:pace_backend=bm:plane_parallax_px=16,far_field.enabled=true") == (
        "ensemble", {"pace_backend": "bm:plane_parallax_px=16", "far_field.enabled": True})
    with pytest.raises(ParamError, match="pace_backend takes NAME=VALUE, got 'mode'"):
        split_backend_spec("bm:plane_parallax_px=16,mode", "pace_backend")


def test_a_params_file_that_is_not_utf8_is_one_line(tmp_path: Path) -> None:
    from roadbev_core.config import ParamError, load_params_file

    path = tmp_path / "latin1.yaml"
    path.write_bytes("roadbev:\n  ros__parameters:\n    frame_id: stra\xdfe\n".encode("latin-1"))
    with pytest.raises(ParamError, match=r"is not UTF-8 text \(byte \d+: invalid"):
        load_params_file(path)
