"""Slow, obviously-correct references for the DGSM optical depth (tests only).

- ``optical_depth_numpy``: float64 numpy/scipy, vectorised over occluders, a Python loop over
  points; the stable closed form written independently of the numba kernels.
- ``segment_depth_mpmath``: eq. 3 verbatim (``c - b^2/a`` and a plain erf difference) in
  50-digit arithmetic, where the cancellations that the float64 code avoids are harmless.
- ``segment_depth_quad``: adaptive quadrature (``mpmath.quad``) of the absorption field of
  eq. 1 along the ray, independent of eq. 3 altogether.

The mpmath functions take one packed occluder row (``dgsm_model`` layout: ``mu``, ``R``,
``1/s``, ``amp``) and form ``A = R diag(1/s^2) R^T`` exactly in mpmath from those float64
numbers, with the amplitude convention of ``dgsm_model`` (``beta = amp``, or ``amp sqrt(a)``
for ``diag``).
"""

from __future__ import annotations

import math

import mpmath
import numpy as np
from scipy import special


def optical_depth_numpy(origin_or_none, points, occ, dir_dep: int, direction=None) -> np.ndarray:
    """Optical depth at ``points`` (M, 3) from packed ``occ`` (N, 10).

    Point light: ``origin_or_none`` = light position (3,), integrate ``s`` in ``[0, |x - o|]``.
    Directional: ``origin_or_none=None`` and ``direction`` (3,) unit: integrate the ray
    ``x + s l`` over ``s`` in ``(-inf, 0]``.
    """
    pts = np.asarray(points, dtype=np.float64)
    mu = occ[:, 0:3]
    R = occ[:, 3:12].reshape(-1, 3, 3)
    inv_s = occ[:, 12:15]
    amp = occ[:, 15]
    out = np.zeros(len(pts))
    for j, x in enumerate(pts):
        if origin_or_none is None:
            o = x
            d = np.asarray(direction, dtype=np.float64)
            t0, t1 = -np.inf, 0.0
        else:
            o = np.asarray(origin_or_none, dtype=np.float64)
            v = x - o
            t1 = float(np.linalg.norm(v))
            if t1 == 0.0:
                continue
            d = v / t1
            t0 = 0.0
        r = o - mu
        delta = np.einsum("nji,j->ni", R, d) * inv_s  # diag(1/s) R^T d
        rho = np.einsum("nji,nj->ni", R, r) * inv_s
        a = np.sum(delta * delta, axis=1)
        b = np.sum(rho * delta, axis=1)
        s_star = -b / a
        m2 = np.sum((rho + s_star[:, None] * delta) ** 2, axis=1)
        z0 = np.sqrt(a / 2) * (t0 - s_star)
        z1 = np.sqrt(a / 2) * (t1 - s_star)
        diff = np.where(z0 >= 0, special.erfc(z0) - special.erfc(z1),
                        np.where(z1 <= 0, special.erfc(-z1) - special.erfc(-z0), special.erf(z1) - special.erf(z0)))
        beta = amp * np.sqrt(a) if dir_dep else amp
        out[j] = np.sum(beta * np.sqrt(np.pi / (2 * a)) * np.exp(-0.5 * m2) * np.maximum(diff, 0.0))
    return out


def _mp_setup(o, d, row):
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
