"""Reference of :mod:`numba_kernels.erf_stable`: ``erf(z1) - erf(z0)`` in 400-digit mpmath
(imported inside the function), where the cancellation the kernel avoids is harmless."""

from __future__ import annotations

import math


def erf_diff(z0: float, z1: float):
    """``erf(z1) - erf(z0)`` as an ``mpmath.mpf`` (``z0``, ``z1`` may be +-inf)."""
    import mpmath

    def erf(z):
        return mpmath.mpf(-1) if z == -math.inf else (mpmath.mpf(1) if z == math.inf else mpmath.erf(mpmath.mpf(z)))

    with mpmath.workdps(400):
        return erf(z1) - erf(z0)
