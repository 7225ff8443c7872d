"""matrix_to_quat_xyzw is SciPy's conversion to the bit, with or without SciPy."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import _orthonormal_quat, matrix_to_quat_xyzw

ROTATIONS = Rotation.random(3000, random_state=7).as_matrix()


def _scipy(R: np.ndarray) -> np.ndarray:
    q = Rotation.from_matrix(R).as_quat()
    return -q if q[3] < 0 else q


def test_exact_rotations_are_converted_without_scipy_to_the_same_bits():
    special = [np.eye(3)] + [Rotation.from_euler(ax, a, degrees=True).as_matrix()
                             for ax in "xyz" for a in (90, 180, -90, 179.9999, 45, 1e-4)]
    for R in [*ROTATIONS, *special]:
        assert _orthonormal_quat(R) is not None        # the written-out path
        assert np.array_equal(matrix_to_quat_xyzw(R), _scipy(R))


@pytest.mark.parametrize("noise", [1e-13, 6e-13, 1e-12, 2e-12, 1e-8, 1e-7])
def test_matrices_around_scipys_tolerance_give_scipys_bits(noise):
    """Near SciPy's 1e-12 test both paths are taken; each gives SciPy's quaternion."""
    rng = np.random.default_rng(int(noise * 1e15) % 1000)
    for R in ROTATIONS[:600]:
        M = R + rng.normal(scale=noise, size=(3, 3))
        assert np.array_equal(matrix_to_quat_xyzw(M), _scipy(M))


def test_an_exact_rotation_does_not_import_scipy():
    code = ("import sys, numpy as np\n"
            "from eye_in_hand.core.transforms import matrix_to_quat_xyzw\n"
            "q = matrix_to_quat_xyzw(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], "
            "[0.0, 0.0, 1.0]]))\n"
            "assert abs(q[2] - 2 ** -0.5) < 1e-15 and abs(q[3] - 2 ** -0.5) < 1e-15, q\n"
            "print('scipy.spatial' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
