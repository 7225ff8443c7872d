"""The edge term of the centre sigma: ``s * sqrt(2 tau / N)`` (core.detection's docstring).

A circular contour of N = 400 points with known radial offsets: white offsets (``tau`` = 1),
and offsets repeated over 4 neighbouring points (autocorrelation 3/4, 1/2, 1/4, then 0, so
``tau = 1 + 2 (3/4 + 1/2 + 1/4)`` = 4). The fit's residual RMS ``s`` is the offsets' spread.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.detection import center_sigma_parts

N = 400


@pytest.mark.parametrize("repeat, tau", [(1, 1.0), (4, 4.0)])
@pytest.mark.parametrize("seed", [0, 1])
def test_edge_sigma_is_that_of_n_over_tau_independent_points(repeat, tau, seed) -> None:
    rng = np.random.default_rng(seed)
    off = np.repeat(rng.normal(0.0, 0.3, N // repeat), repeat)
    th = 2 * np.pi * np.arange(N) / N
    contour = np.stack([100 + (50 + off) * np.cos(th), 100 + (50 + off) * np.sin(th)], axis=1)
    none = np.zeros((1, 1), np.uint8)
    edge, shade = center_sigma_parts(none, none, contour)
    want = np.std(off) * np.sqrt(2 * tau / N)
    assert edge == pytest.approx(want, rel=0.06), (edge, want)
    assert np.all(shade == 0)
