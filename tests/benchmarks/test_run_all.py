"""Table I's comparison on the cells both methods estimated."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.run_all import common_cell_comparison, common_cell_markdown, flat_reference, flat_reference_line
from roadbev_core.config import GridSpec


def test_each_pair_that_ran_is_compared_on_the_cells_both_estimated_only() -> None:
    truth = np.zeros((2, 3))
    # gwcnet answers every cell, 1 cm off on the cells sgbm declines and 0.2 cm off elsewhere
    gwcnet = np.array([[0.002, 0.002, 0.01], [0.002, 0.002, 0.01]])
    sgbm = np.array([[0.004, 0.004, np.nan], [0.004, 0.004, np.nan]])
    stereo = np.full((2, 3), 0.001)
    out = common_cell_comparison({"gwcnet": [gwcnet], "sgbm": [sgbm], "stereo": [stereo]}, [truth])
    assert set(out) == {"stereo vs gwcnet", "gwcnet vs sgbm"}  # pairs with a backend that did not run are left out
    pair = out["gwcnet vs sgbm"]
    assert (pair["method"], pair["against"], pair["cells"]) == ("gwcnet", "sgbm", 4)
    assert pair["method_abs_err_cm"] == pytest.approx(0.2) and pair["against_abs_err_cm"] == pytest.approx(0.4)
    assert pair["abs_err_reduction_pct"] == pytest.approx(50.0)
    assert out["stereo vs gwcnet"]["against_abs_err_cm"] == pytest.approx((4 * 0.2 + 2 * 1.0) / 6)
    table = common_cell_markdown(out)
    assert "| gwcnet vs sgbm | 4 | 0.200 | 0.400 | 50.0 |" in table
    assert common_cell_markdown({}) == ""



def test_the_flat_road_reference_is_the_error_of_elevation_zero_on_the_labelled_cells() -> None:
    grid = GridSpec()
    truth = np.full(grid.shape, np.nan)
    truth[:10] = 0.02  # 2 cm above the reference plane on ten rows, unlabelled elsewhere
    truth[10:20] = -0.004
    reference = flat_reference([truth, truth], grid)
    assert reference["abs_err_cm"] == pytest.approx((2.0 + 0.4) / 2)
    assert reference["rmse_cm"] == pytest.approx(np.sqrt((4.0 + 0.16) / 2))
    assert reference["gt_0p5cm_pct"] == pytest.approx(50.0)
    assert "labelled cell): 1.200 cm abs. err." in flat_reference_line(reference)
    assert flat_reference_line(None) == ""
