"""The documentation's generated parts (``docs/_ext/roadbev_docs.py``), without running Sphinx
(``make docs`` builds the whole site, warnings as errors, in CI):

- the node's parameter table has one row per parameter descriptor, with its type, default,
  range, read-only flag and description, and the parameters page shows it;
- the reference nodes' tables cover their parameters exactly;
- docstrings are read as plain text (``|x|`` is no substitution; grouped fields stay fields);
- the evaluation page names every key the evaluation writes.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from roadbev_core.config import parameter_specs

DOCS = Path(__file__).resolve().parents[2] / "docs"


@pytest.fixture(scope="module")
def ext() -> ModuleType:
    """The docs' Sphinx extension, loaded from its file (docs/_ext is not a package)."""
    spec = importlib.util.spec_from_file_location("roadbev_docs", DOCS / "_ext" / "roadbev_docs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _directive_lines(page: Path, directive: str) -> tuple[str, list[str]]:
    """The argument and content lines of the one ```{directive} fence on a MyST page."""
    found = re.findall(r"```\{" + re.escape(directive) + r"\}(.*?)\n(.*?)```", page.read_text(), re.DOTALL)
    assert len(found) == 1, f"{page.name} has {len(found)} {directive} directives"
    argument, body = found[0]
    return argument.strip(), [line for line in body.splitlines() if line.strip()]


def test_the_parameter_table_has_one_row_per_parameter_in_their_order(ext: Any) -> None:
    specs = parameter_specs()
    rows = ext.parameter_rows(specs)
    assert [row[0] for row in rows] == [spec.name for spec in specs]
    assert all(len(row) == len(ext.PARAMETER_HEADER) for row in rows)
    for spec, (_, kind, default, limits, change, description) in zip(specs, rows, strict=True):
        assert description == spec.description
        assert change == ("no (read-only)" if spec.read_only else "yes")
        assert kind == {bool: "bool", int: "integer", float: "double", str: "string"}.get(
            type(spec.default), f"double[{len(spec.default)}]" if isinstance(spec.default, list) else "?")
        assert default == ext.format_value(spec.default)
        if spec.choices:
            assert limits == "one of " + ", ".join(spec.choices)
        elif spec.low is not None or spec.high is not None:
            assert limits.startswith("[") and limits.endswith("]")
        else:
            assert limits == ""


def test_table_cells_read_as_a_params_file_writes_them(ext: Any) -> None:
    rows = {row[0]: row for row in ext.parameter_rows(parameter_specs())}
    assert rows["preview.track_offsets_m"][1:3] == ("double[2]", "[0.8, -0.8]")
    assert rows["require_imu"][1:3] == ("bool", "true")
    assert rows["speed_topic"][2] == '""'
    assert rows["sync_queue_size"][1:4] == ("integer", "10", "[1, 1000]")
    assert rows["base_height"][1:4] == ("double", "1.1", "[0.1, 10.0]")
    assert rows["image_transport"][3:5] == ("one of raw, compressed", "no (read-only)")
    assert ext.value_range(0.0, None, None) == "[0.0, inf]"


def test_the_parameters_page_shows_the_generated_table() -> None:
    argument, content = _directive_lines(DOCS / "node" / "parameters.md", "roadbev-parameters")
    assert (argument, content) == ("", [])


@pytest.mark.parametrize("page", ["preview_controller.md", "hazard_monitor.md"])
def test_a_reference_node_page_describes_exactly_its_parameters(ext: Any, page: str) -> None:
    argument, content = _directive_lines(DOCS / "node" / page, "roadbev-node-defaults")
    module, _, attribute = argument.rpartition(".")
    defaults = getattr(importlib.import_module(module), attribute)
    descriptions = dict(line.split(":", 1) for line in content)
    rows = ext.default_rows(defaults, {k.strip(): v.strip() for k, v in descriptions.items()})
    assert [row[0] for row in rows] == list(defaults)


def test_a_node_table_refuses_a_parameter_without_a_description_and_one_it_does_not_have(ext: Any) -> None:
    with pytest.raises(ValueError, match="no description of b"):
        ext.default_rows({"a": 1, "b": 2.0}, {"a": "one"})
    with pytest.raises(ValueError, match="descriptions of unknown parameters c"):
        ext.default_rows({"a": 1}, {"a": "one", "c": "none"})


def test_docstring_bars_are_text_outside_literals(ext: Any) -> None:
    lines = [
        "The largest |height| first, ``|lit|`` kept, ``x * |s -",
        "s|`` across lines::",
        "",
        "    sigma = |x|",
        "",
        "back to |prose|.",
    ]
    assert ext.escape_bars(lines) == [
        r"The largest \|height\| first, ``|lit|`` kept, ``x * |s -",
        "s|`` across lines::",
        "",
        "    sigma = |x|",
        "",
        r"back to \|prose\|.",
    ]


def test_grouped_fields_name_several_attributes_not_a_type(ext: Any) -> None:
    assert ext.join_grouped_fields([":ivar offset_m, slope_x, slope_y: the alignment", ":ivar one: x, y"]) == [
        ":ivar offset_m,slope_x,slope_y: the alignment", ":ivar one: x, y"]


def test_every_public_module_gets_an_api_section_and_no_private_one(ext: Any) -> None:
    modules = ext.public_modules("roadbev_core")
    assert {"roadbev_core", "roadbev_core.config", "roadbev_core.config.tree", "roadbev_core.ride.online"} <= set(
        modules)
    assert not [m for m in modules if "._" in m]  # no _private modules, no __main__
    for package in ("roadbev_core", "msg_bridge", "roadbev_ros", "roadbev_lab"):
        assert f".. roadbev-modules:: {package}" in (DOCS / "api" / f"{package}.rst").read_text()


def test_the_evaluation_page_names_every_key_the_evaluation_writes() -> None:
    from roadbev_lab.evaluation.arrival import ARRIVAL_KEYS
    from roadbev_lab.evaluation.frames import CONTRACT_KEYS
    from roadbev_lab.evaluation.metrics import Metrics, sigma_metrics

    page = (DOCS / "interface" / "evaluation.md").read_text()
    keys = set(CONTRACT_KEYS) | set(ARRIVAL_KEYS) | set(sigma_metrics(np.zeros(6)))
    keys |= set(Metrics(frames=0, cells=0, abs_err_cm=0.0, rmse_cm=0.0, gt_0p5cm_pct=0.0, band_abs_err_cm=[],
                        coverage_pct=0.0, labelled_cells=0).to_dict())
    missing = sorted(key for key in keys if f"`{key}`" not in page)
    assert not missing, f"docs/interface/evaluation.md does not name {missing}"
