"""benchmarks/bench_node.py: what a result records of the node's parameters."""

from __future__ import annotations

import pytest

from benchmarks.bench_node import recorded_node_params
from benchmarks.preview_budget import candidates_from_node, node_rows
from roadbev_core.config import RoadbevConfig


def test_a_result_names_the_far_field_setting_it_ran_even_at_its_default() -> None:
    default = RoadbevConfig().far_field.enabled
    assert recorded_node_params({}) == {"far_field.enabled": default}
    given = {"far_field.enabled": not default, "inference_threads": 2}
    assert recorded_node_params(given) == given
    # a bare candidate takes the row recorded at the default, and one that names the other setting does not
    row = {"backend": "bm", "mode": "5hz", "latency_ms": {"p50": 80.0}, "inference_p50_ms": 60.0,
           "overhead_mean_ms": 10.0}
    rows = node_rows([{"rows": [row], "node_params": recorded_node_params({})}])
    assert candidates_from_node(["bm"], rows)[0].latency_s == pytest.approx(0.080)
    with pytest.raises(ValueError, match="no bench_node row"):
        candidates_from_node([f"other=bm:far_field.enabled={str(not default).lower()}"], rows)
