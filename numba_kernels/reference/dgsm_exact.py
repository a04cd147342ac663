"""Reference of :mod:`numba_kernels.dgsm_exact` (tests only).

``optical_depth_numpy`` (and the kernels' names ``optical_depth_point`` / ``optical_depth_directional``):
float64 numpy, vectorised over occluders, a Python loop over points;
the stable closed form written independently of the numba kernels (``erf`` / ``erfc`` from
``math``, element by element). The per-occluder segment integral itself has its
arbitrary-precision references in :mod:`numba_kernels.reference.dgsm_model`;
``optical_depth_point_mpmath`` sums them over the occluders for one receiver of a point light.
"""

from __future__ import annotations

import math

import numpy as np

from .dgsm_model import segment_depth_mpmath

_erf = np.vectorize(math.erf, otypes=[float])
_erfc = np.vectorize(math.erfc, otypes=[float])


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
        diff = np.where(z0 >= 0, _erfc(z0) - _erfc(z1),
                        np.where(z1 <= 0, _erfc(-z1) - _erfc(-z0), _erf(z1) - _erf(z0)))
        beta = amp * np.sqrt(a) if dir_dep else amp
        out[j] = np.sum(beta * np.sqrt(np.pi / (2 * a)) * np.exp(-0.5 * m2) * np.maximum(diff, 0.0))
    return out



def optical_depth_point(light, points, occ, dir_dep: int) -> np.ndarray:
    """``dgsm_exact.optical_depth_point``: (M,) optical depth from a point ``light`` (3,)."""
    return optical_depth_numpy(np.asarray(light, dtype=np.float64), points, occ, dir_dep)


def optical_depth_directional(direction, points, occ, dir_dep: int) -> np.ndarray:
    """``dgsm_exact.optical_depth_directional``: (M,) optical depth along the whole line towards a
    directional light propagating along ``direction`` (3,) (normalised here)."""
    d = np.asarray(direction, dtype=np.float64)
    return optical_depth_numpy(None, points, occ, dir_dep, direction=d / np.linalg.norm(d))


def optical_depth_point_mpmath(light, x, occ, dir_dep: int, dps: int = 50) -> float:
    """Optical depth from a point ``light`` (3,) to ``x`` (3,): eq. 3 in ``dps``-digit mpmath per
    occluder row of ``occ``, summed (0 when ``x`` is the light)."""
    light, x = np.asarray(light, float), np.asarray(x, float)
    t = float(np.linalg.norm(x - light))
    if t == 0:
        return 0.0
    d = (x - light) / t
    return sum(segment_depth_mpmath(light, d, 0.0, t, occ[i], dir_dep, dps) for i in range(len(occ)))
