"""Params YAML loading, grid parameters and the node's parameter table."""

from __future__ import annotations

from pathlib import Path

import pytest

from roadbev_core.config import GridSpec
from roadbev_ros.params import (
    PARAMETERS,
    ParamError,
    defaults,
    grid_from_params,
    load_params_file,
    validate,
    validate_one,
)

REPO = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def test_wildcard_first_then_node_section(tmp_path: Path) -> None:
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
    params = load_params_file(path)
    assert params == {"base_height": 1.3, "resolution": 0.06, "preview.tyre_width_m": 0.25}
    assert load_params_file(path, node_name="other_node")["base_height"] == 9.0
    assert load_params_file(path, node_name="/vehicle/roadbev")["base_height"] == 1.3


def test_grid_from_params_overrides_the_base_grid() -> None:
    grid = grid_from_params({"base_height": 1.4, "x_max": 10.08, "backend": "bm"})
    assert grid == GridSpec(base_height=1.4, x_max=10.08)
    base = GridSpec(resolution=0.06)
    assert grid_from_params({}, base) is base or grid_from_params({}, base) == base


@pytest.mark.parametrize(
    "params, reason",
    [
        ({"resolution": 0.07}, "whole number"),
        ({"base_height": "high"}, "must be a number"),
        ({"x_min": True}, "must be a number"),
        ({"z_max": 2.0}, "below the camera"),
    ],
)
def test_grid_from_params_rejects_bad_grids(params: dict, reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        grid_from_params(params)


@pytest.mark.parametrize(
    "text, reason",
    [("roadbev: [1, 2\n", "not valid YAML"), ("- 1\n", "must map"), ("roadbev:\n  x: 1\n", "ros__parameters")],
)
def test_bad_params_files(tmp_path: Path, text: str, reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        load_params_file(write(tmp_path, text))
    with pytest.raises(ParamError, match="cannot read"):
        load_params_file(tmp_path / "missing.yaml")


def test_empty_or_foreign_file_gives_no_parameters(tmp_path: Path) -> None:
    assert load_params_file(write(tmp_path, "")) == {}
    assert load_params_file(write(tmp_path, "other:\n  ros__parameters: {a: 1}\n")) == {}


def test_shipped_params_file_is_valid_and_matches_defaults() -> None:
    params = load_params_file(REPO / "config" / "roadbev.params.yaml")
    assert validate(params) == {**defaults(), **params}
    for name, value in params.items():
        assert value == defaults()[name], f"shipped {name} differs from the declared default"


def test_every_parameter_has_a_description_and_a_valid_default() -> None:
    names = [s.name for s in PARAMETERS]
    assert len(names) == len(set(names))
    for spec in PARAMETERS:
        assert spec.description
        assert validate_one(spec.name, spec.default) == spec.default
    assert {"base_height", "x_min", "resolution", "class_resolution"} <= set(names)


@pytest.mark.parametrize(
    "name, value, reason",
    [
        ("backend", "magic", "must be one of"),
        ("sync_slop_s", -0.1, "below its minimum"),
        ("sync_queue_size", 5000, "above its maximum"),
        ("sync_queue_size", 2.5, "integer"),
        ("imu_max_age_s", float("nan"), "finite"),
        ("require_imu", 1, "true or false"),
        ("imu_to_camera_rpy_deg", [0.0, 1.0], "needs 3"),
        ("imu_to_camera_rpy_deg", [0.0, "a", 1.0], "list of finite"),
        ("no_such_param", 1, "unknown parameter"),
    ],
)
def test_validate_one_rejects_nonsense(name: str, value: object, reason: str) -> None:
    with pytest.raises(ParamError, match=reason):
        validate_one(name, value)


def test_validate_checks_the_grid_as_a_whole_and_coerces() -> None:
    out = validate({"sync_slop_s": 0, "resolution": 0.06})
    assert out["sync_slop_s"] == 0.0 and isinstance(out["sync_slop_s"], float)
    with pytest.raises(ParamError, match="valid grid"):
        validate({"x_min": 7.0, "x_max": 7.08})
    assert "foreign" not in validate({"foreign": 1}, strict=False)
    with pytest.raises(ParamError, match="unknown"):
        validate({"foreign": 1})


def test_command_line_assignments_parse_json_values_and_fall_back_to_text() -> None:
    from roadbev_ros.params import ParamError, parse_assignments

    assert parse_assignments(["zncc_subsamples=2", "zncc_full_resolution=true", "sampling=integer"], "-o") == {
        "zncc_subsamples": 2, "zncc_full_resolution": True, "sampling": "integer"}
    with pytest.raises(ParamError, match="--model-option takes NAME=VALUE"):
        parse_assignments(["zncc_subsamples"], "--model-option")
