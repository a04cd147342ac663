"""erf_stable.erf_diff against 400-digit mpmath, including the cancellation regime."""

import math

import numpy as np
import pytest

from numba_kernels.erf_stable import erf_diff, erf_diff_nonneg
from numba_kernels.reference.erf_stable import erf_diff as _ref


@pytest.mark.parametrize("z0,z1", [(0.1, 0.7), (-2.0, 1.5), (5.0, 5.5), (-6.5, -5.9), (9.0, 12.0), (-12.0, -9.0),
                                   (3.0, 3.0 + 1e-9), (-20.0, 20.0), (0.0, 0.0), (25.0, 26.0), (-math.inf, -7.0),
                                   (-math.inf, 0.3), (4.0, math.inf), (-math.inf, math.inf)])
def test_erf_diff_relative_accuracy(z0, z1):
    ref = float(_ref(z0, z1))
    got = erf_diff(z0, z1)
    assert math.isfinite(got)
    assert abs(got - ref) <= _tol(z0, z1, ref)


def _tol(z0, z1, ref):
    """1e-13 relative, plus a few ulp of the larger tail term (the inherent conditioning when
    z0 and z1 nearly coincide)."""
    m = min(abs(z0), abs(z1)) if z0 * z1 >= 0 else 0.0
    return 1e-13 * abs(ref) + 4.5e-16 * math.erfc(m) + 1e-300


def test_naive_formula_would_fail_where_stable_one_does_not():
    # erf(6) and erf(6.5) both round to 1.0 in float64: the naive difference is 0
    assert math.erf(6.5) - math.erf(6.0) == 0.0
    ref = float(_ref(6.0, 6.5))
    assert ref > 1e-18
    assert abs(erf_diff(6.0, 6.5) - ref) <= 1e-13 * ref


def test_random_pairs_and_clamp():
    rng = np.random.default_rng(3)
    for _ in range(200):
        z0, z1 = np.sort(rng.normal(scale=6.0, size=2))
        ref = float(_ref(float(z0), float(z1)))
        got = erf_diff_nonneg(float(z0), float(z1))
        assert got >= 0.0
        assert abs(got - ref) <= _tol(float(z0), float(z1), ref)
