"""Reference of :mod:`numba_kernels.dgsm_model`'s ``segment_depth`` (tests only; mpmath, imported
inside the functions).

- ``segment_depth_mpmath``: eq. 3 verbatim (``c - b^2/a`` and a plain erf difference) in
  50-digit arithmetic, where the cancellations that the float64 code avoids are harmless.
- ``segment_depth_quad``: adaptive quadrature (``mpmath.quad``) of the absorption field of
  eq. 1 along the ray, independent of eq. 3 altogether.

Both take one packed occluder row (``dgsm_model`` layout: ``mu``, ``R``, ``1/s``, ``amp``) and
form ``A = R diag(1/s^2) R^T`` exactly in mpmath from those float64 numbers, with the amplitude
convention of ``dgsm_model`` (``beta = amp``, or ``amp sqrt(a)`` for ``diag``).
"""

from __future__ import annotations

import math


def _mp_setup(o, d, row):
    import mpmath

    o = [mpmath.mpf(float(v)) for v in o]
    d = [mpmath.mpf(float(v)) for v in d]
    mu = [mpmath.mpf(float(v)) for v in row[0:3]]
    R = [[mpmath.mpf(float(row[3 + 3 * i + j])) for j in range(3)] for i in range(3)]
    w = [mpmath.mpf(float(row[12 + k])) ** 2 for k in range(3)]
    A = [[sum(R[i][k] * w[k] * R[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
    r = [o[i] - mu[i] for i in range(3)]
    Ad = [sum(A[i][j] * d[j] for j in range(3)) for i in range(3)]
    Ar = [sum(A[i][j] * r[j] for j in range(3)) for i in range(3)]
    a = sum(d[i] * Ad[i] for i in range(3))
    b = sum(r[i] * Ad[i] for i in range(3))
    c = sum(r[i] * Ar[i] for i in range(3))
    return a, b, c


def segment_depth_mpmath(o, d, t0, t1, row, dir_dep, dps: int = 50) -> float:
    """Eq. 3 verbatim at ``dps`` digits for packed occluder ``row`` (``t0`` may be ``-inf``)."""
    import mpmath

    with mpmath.workdps(dps):
        a, b, c = _mp_setup(o, d, row)
        beta = mpmath.mpf(float(row[15])) * (mpmath.sqrt(a) if dir_dep else 1)
        lo = mpmath.mpf(-1) if t0 == -math.inf else mpmath.erf(mpmath.sqrt(a / 2) * (mpmath.mpf(float(t0)) + b / a))
        hi = mpmath.erf(mpmath.sqrt(a / 2) * (mpmath.mpf(float(t1)) + b / a))
        val = beta * mpmath.sqrt(mpmath.pi / (2 * a)) * mpmath.exp(-(c - b * b / a) / 2) * (hi - lo)
        return float(val)


def segment_depth_quad(o, d, t0, t1, row, dir_dep, dps: int = 30) -> float:
    """``int_{t0}^{t1} beta exp(-1/2 (o + s d - mu)^T A (o + s d - mu)) ds`` by adaptive
    quadrature, split at the closest approach and +-1, 3, 8 sigma along the ray."""
    import mpmath

    with mpmath.workdps(dps):
        a, b, c = _mp_setup(o, d, row)
        beta = mpmath.mpf(float(row[15])) * (mpmath.sqrt(a) if dir_dep else 1)
        s_star = -b / a
        sig = 1 / mpmath.sqrt(a)
        lo = -mpmath.inf if t0 == -math.inf else mpmath.mpf(float(t0))
        hi = mpmath.mpf(float(t1))
        pts = [lo]
        for k in (-8, -3, -1, 0, 1, 3, 8):
            s = s_star + k * sig
            if lo < s < hi:
                pts.append(s)
        pts.append(hi)

        def f(s):
            return beta * mpmath.exp(-(a * s * s + 2 * b * s + c) / 2)

        return float(mpmath.quad(f, pts))
