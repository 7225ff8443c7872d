"""core.handeye.eiv: the variance-component bookkeeping of the errors-in-variables refinement.

Each group's noise level is re-estimated from its residuals over its redundancy
``r_g = rows_g - sum of the hat-matrix diagonal over the group``. The hat matrix of a
least-squares problem has the number of unknowns as its trace, so the redundancies of all
groups add up to the rows minus the unknowns (12 for X and Y, 6 per sample's correction):
a wrong term of the hat diagonal breaks that sum.
"""
from __future__ import annotations

import pytest

from eye_in_hand.core.handeye.eiv import refine_errors_in_variables
from eye_in_hand.core.handeye.synthetic import make_problem


@pytest.mark.parametrize("corners", [True, False])
def test_redundancies_add_up_to_rows_minus_unknowns(corners: bool) -> None:
    P = make_problem(8, seed=77, noise_px=0.4, robot_noise_mm=0.5, robot_noise_deg=0.05)
    res = refine_errors_in_variables(P.X, P.Y, P.samples, P.views if corners else None,
                                     "eye_in_hand")
    n = len(P.samples)
    meas = (sum(2 * ob.object_points.shape[0] for s in P.samples for ob in s.observations)
            if corners else 6 * n)
    rows = meas + 6 * n                         # measurements, then the corrections' priors
    assert sum(res.redundancy.values()) == pytest.approx(rows - (12 + 6 * n), abs=1e-6)
    assert set(res.redundancy) == ({"px", "robot_t", "robot_r"} if corners
                                   else {"cam_r", "robot_t", "robot_r"})
    assert all(0 < r for r in res.redundancy.values()), res.redundancy
