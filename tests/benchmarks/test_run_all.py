"""Table I's comparison on the cells both methods estimated."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.run_all import common_cell_comparison, common_cell_markdown


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

