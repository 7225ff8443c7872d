"""min_cost_assignment: SciPy's assignment, without SciPy when each row's cheapest column is
its own and strictly cheapest."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
from scipy.optimize import linear_sum_assignment

from eye_in_hand.core.assignment import min_cost_assignment


def _same_as_scipy(cost: np.ndarray) -> bool:
    rows, cols = min_cost_assignment(cost)
    want_rows, want_cols = linear_sum_assignment(cost)
    return rows.tolist() == want_rows.tolist() and cols.tolist() == want_cols.tolist()


def test_the_pairs_are_scipys_on_random_and_tied_costs():
    rng = np.random.default_rng(11)
    for _ in range(400):
        n, m = int(rng.integers(1, 6)), int(rng.integers(1, 6))
        assert _same_as_scipy(rng.random((n, m)))
        # small integers: ties everywhere, also between whole assignments
        assert _same_as_scipy(rng.integers(0, 3, (n, m)).astype(float))


def test_a_row_with_two_cheapest_columns_goes_to_scipy():
    """Rows 0 and 1 each have a cheapest column of their own, but both tie with another
    column: two assignments cost 2, and which one is SciPy's to say."""
    cost = np.array([[1.0, 1.0, 5.0], [5.0, 1.0, 1.0]])
    assert _same_as_scipy(cost)
    assert _same_as_scipy(cost[:, ::-1].copy())


def test_the_plain_case_does_not_import_scipy():
    code = ("import sys, numpy as np\n"
            "from eye_in_hand.core.assignment import min_cost_assignment\n"
            "r, c = min_cost_assignment(np.array([[0.1, 2.0, 3.0], [4.0, 0.2, 5.0]]))\n"
            "assert r.tolist() == [0, 1] and c.tolist() == [0, 1]\n"
            "print('scipy.optimize' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
