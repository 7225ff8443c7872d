"""core.handeye.calibrate: the outlier rule's absolute floors, the jackknife spread.

A sample is rejected only when its leave-one-out board deviation is beyond
``outlier_threshold`` times the median *and* beyond an absolute floor (``outlier_floor_mm``
or ``outlier_floor_deg``): on very clean data a sample 0.6 mm off (7 medians) is
many medians away but still a good sample.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.handeye import HandEyeSample, calibrate_hand_eye
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import from_rotvec


def _clean_with_one_offset():
    P = make_problem(12, seed=91, noise_px=0.01)
    samples = list(P.samples)
    s = samples[3]
    samples[3] = HandEyeSample(s.name, s.base_T_ee @ from_rotvec([0.0, 0.0, 0.0],
                                                                  [6e-4, 0.0, 0.0]),
                               s.cam_T_board, s.observations)
    return samples, s.name


def test_a_deviation_under_both_floors_is_kept() -> None:
    samples, name = _clean_with_one_offset()
    res = calibrate_hand_eye(samples, refine=False, leave_one_out=False)
    assert res.rejected == [] and name in res.sample_names


def test_the_same_deviation_over_a_lower_floor_is_rejected() -> None:
    samples, name = _clean_with_one_offset()
    res = calibrate_hand_eye(samples, refine=False, leave_one_out=False,
                             outlier_floor_mm=0.3, outlier_floor_deg=0.1)
    assert [r.name for r in res.rejected] == [name], res.rejected


def test_jackknife_sigma_is_the_trace_of_the_jackknife_covariance() -> None:
    """A closed form's ``std_mm`` is the jackknife spread of its leave-one-out translations,
    ``sqrt((n - 1) / n * sum |t_i - mean|^2)``: the root of the trace of the translation block
    of its (jackknife) covariance."""
    P = make_problem(10, seed=93, noise_px=0.5)
    res = calibrate_hand_eye(P.samples, refine=False)
    closed = [m for m in ("tsai", "park", "daniilidis") if m in res.methods]
    assert closed, sorted(res.methods)
    for name in closed:
        mr = res.methods[name]
        want = 1000.0 * np.sqrt(np.trace(mr.covariance[:3, :3]))
        assert mr.std_mm == pytest.approx(want, rel=1e-9), name
        assert 0.01 < mr.std_mm < 20.0, (name, mr.std_mm)


def test_written_robot_noise_takes_each_component_from_its_estimate() -> None:
    """hand_eye.yaml's robot_pose_noise: the rotation is the errors-in-variables estimate of
    the rotation noise; the translation the larger of its translation estimate and the
    held-out scatter (None here: no leave-one-out)."""
    P = make_problem(10, seed=94, noise_px=0.3, robot_noise_mm=0.5, robot_noise_deg=0.1)
    res = calibrate_hand_eye(P.samples, leave_one_out=False)
    ref = res.refinement
    assert ref is not None and res.held_out_sigma_m is None
    assert res.robot_pose_noise == {"translation_sigma_m": ref.robot_translation_sigma_m,
                                    "rotation_sigma_rad": ref.robot_rotation_sigma_rad}
    assert ref.robot_rotation_sigma_rad != pytest.approx(ref.robot_translation_sigma_m, rel=0.2)


def test_a_rotation_only_outlier_is_rejected() -> None:
    """The outlier score is the larger of the millimetre and the degree deviations (each over
    its median): a board pose turned 1 degree about the board's own origin moves no position
    but is rejected for its rotation."""
    P = make_problem(12, seed=91, noise_px=0.01)
    samples = list(P.samples)
    s = samples[5]
    samples[5] = HandEyeSample(s.name, s.base_T_ee,
                               s.cam_T_board @ from_rotvec([0.0, np.radians(1.0), 0.0]),
                               s.observations)
    res = calibrate_hand_eye(samples, refine=False, leave_one_out=False)
    assert [r.name for r in res.rejected] == [s.name], res.rejected
    assert "deg" in res.rejected[0].reason
