"""Cancellation-free differences of the error function (float64, numba nopython).

``erf(z1) - erf(z0)`` loses every significant digit when ``z0`` and ``z1`` have the same
sign and large magnitude (both erf values round to +-1). Writing the difference through
the complementary function keeps full relative precision there:

- ``z0, z1 >= 0``:  erf(z1) - erf(z0) = erfc(z0) - erfc(z1)
- ``z0, z1 <= 0``:  erf(z1) - erf(z0) = erfc(-z1) - erfc(-z0)
- mixed signs:      erf(z1) - erf(z0) directly (the result is >= erf(|z|) > 0, no cancellation)

Only ``math.erf`` / ``math.erfc`` (libm, ~1 ulp) are used; there is no approximated fast
path, so the error of ``erf_diff`` is at most a few ulp of the larger term used (``erfc(min |z|)`` for
same-sign arguments, 1 otherwise): relative error ~1e-15 unless ``z0`` and ``z1`` nearly
coincide (then the inherent conditioning of the difference applies), and values below
~1e-300 underflow to 0 for |z| > 26.5.
Infinite arguments are allowed (erf(+-inf) = +-1, erfc(inf) = 0); NaN is never produced
from non-NaN input.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, fastmath=False)
def erf_diff(z0: float, z1: float) -> float:
    """``erf(z1) - erf(z0)`` in float64 without catastrophic cancellation (see module doc)."""
    if z0 >= 0.0 and z1 >= 0.0:
        return math.erfc(z0) - math.erfc(z1)
    if z0 <= 0.0 and z1 <= 0.0:
        return math.erfc(-z1) - math.erfc(-z0)
    return math.erf(z1) - math.erf(z0)


@njit(cache=True, fastmath=False)
def erf_diff_nonneg(z0: float, z1: float) -> float:
    """``erf_diff(z0, z1)`` for ``z0 <= z1``, clamped at 0 (erf is monotone, so any
    negative value is rounding noise of order 1e-16)."""
    v = erf_diff(z0, z1)
    return v if v > 0.0 else 0.0
