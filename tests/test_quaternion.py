"""numba_kernels/quaternion.py: the shared quaternion -> rotation helper of the kernels."""

import math

import numpy as np
import pytest

from numba_kernels.quaternion import quat_to_rotation
from numba_kernels.reference.quaternion import hamilton_rotation as _hamilton


def test_matches_hamilton_rotation_for_non_unit_quaternions():
    rng = np.random.default_rng(7)
    for q in rng.normal(size=(50, 4)) * rng.uniform(0.01, 100.0, size=(50, 1)):
        r = np.array(quat_to_rotation(*q)).reshape(3, 3)
        np.testing.assert_allclose(r, _hamilton(*q), rtol=0, atol=1e-13)
        np.testing.assert_allclose(r @ r.T, np.eye(3), rtol=0, atol=1e-13)
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)


def test_quarter_turn_about_z():
    s = math.sqrt(0.5)
    r = np.array(quat_to_rotation(s, 0.0, 0.0, s)).reshape(3, 3)  # +90 degrees about +Z: x -> y
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (np.nan, 0.0, 0.0, 0.0), (1.0, np.inf, 0.0, 0.0)])
def test_zero_or_non_finite_gives_identity(q):
    assert quat_to_rotation(*q) == (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
