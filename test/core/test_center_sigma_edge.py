"""The edge term of the centre sigma: ``s * sqrt(2 tau / N)`` (core.detection's docstring).

A circular contour of N = 400 points with known radial offsets: white offsets (``tau`` = 1),
and offsets repeated over 4 neighbouring points (autocorrelation 3/4, 1/2, 1/4, then 0, so
``tau = 1 + 2 (3/4 + 1/2 + 1/4)`` = 4). The fit's residual RMS ``s`` is the offsets' spread.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core import detection
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


def _tau_by_fft(res: np.ndarray) -> float:
    """The correlation time from the whole circular autocorrelation (an FFT), as defined."""
    n = len(res)
    var = float(np.mean(res * res))
    spec = np.fft.rfft(res)
    ac = np.fft.irfft(spec * np.conj(spec), n) / (n * var)
    tau = 1.0
    for k in range(1, n // 4):
        if ac[k] < 0.05:
            break
        tau += 2.0 * float(ac[k])
    return tau


@pytest.mark.parametrize("repeat", [1, 2, 4, 8, 16, 40])
@pytest.mark.parametrize("n", [241, 400, 613])
def test_correlation_time_summed_directly_agrees_with_the_fft(repeat, n) -> None:
    """The first lags are summed directly, longer correlations (beyond 8 lags: repeat 16, 40)
    go to the FFT; either way tau is the FFT's to rounding."""
    rng = np.random.default_rng(repeat * 1000 + n)
    res = np.repeat(rng.normal(0.0, 0.3, n // repeat + 1), repeat)[:n]
    res = res - res.mean()
    var = float(np.mean(res * res))
    tau = detection._correlation_time(res, var)
    assert tau == pytest.approx(_tau_by_fft(res), rel=1e-12, abs=1e-12)
    if repeat >= 4:
        assert tau > 0.5 * repeat
