"""Transmittance of receiver points for many directional lights at once (sun-direction search).

For each propagation direction ``l_d`` (D, 3), unit) and point ``x_j`` (M, 3) the exact
directional DGSM transmittance of ``dgsm_exact``:
``T[j, d] = exp(-sum_i tau_i(l_d; -inf, 0))`` on the ray ``x_j + s l_d`` (the half-line towards
the light), with the packed occluders of ``dgsm_model`` (eqs. 1-5), summed only over the
occluders whose ``k_sigma`` footprint on the plane orthogonal to ``l_d`` (the ellipse of the
projected covariance) covers the point: the occluders are bucketed per direction into a square
grid of ``cell``-sized cells over the points' projected bounding box by the ``k_sigma
sqrt(lambda_max)`` circle around that ellipse, as ``dgsm_directional`` culls. The dropped
terms are below ``exp(-k_sigma^2 / 2)`` of an occluder's
peak; a sum that passes :data:`TAU_OPAQUE` stops there (``T < 1e-9``). One call runs every
direction (parallel over directions), so there is one thread-pool round trip per batch rather
than per direction. Lengths in metres; returns float32 in [0, 1].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .dgsm_model import segment_depth
from .jit_options import prange_only

MAX_GRID = 1024
#: optical depth past which a ray counts as blocked: the sum stops there (T < 1e-9)
TAU_OPAQUE = 20.7


@njit(cache=True, fastmath=False)
def _basis(dx, dy, dz):
    if abs(dx) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    # e1 = h x l, e2 = l x e1
    ax, ay, az = hy * dz - hz * dy, hz * dx - hx * dz, hx * dy - hy * dx
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / n, ay / n, az / n
    bx, by, bz = dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax
    return ax, ay, az, bx, by, bz


@njit(cache=True, fastmath=False)
def _one_direction(d, occ, dir_dep, cov6, pts, k_sigma, cell, out_col):
    n = occ.shape[0]
    m = pts.shape[0]
    dn = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    dx, dy, dz = d[0] / dn, d[1] / dn, d[2] / dn
    ax, ay, az, bx, by, bz = _basis(dx, dy, dz)
    pu = np.empty(m)
    pv = np.empty(m)
    for j in range(m):
        pu[j] = pts[j, 0] * ax + pts[j, 1] * ay + pts[j, 2] * az
        pv[j] = pts[j, 0] * bx + pts[j, 1] * by + pts[j, 2] * bz
    u0, u1, v0, v1 = pu.min(), pu.max(), pv.min(), pv.max()
    k2 = k_sigma * k_sigma
    h = max(cell, max(u1 - u0, v1 - v0) / MAX_GRID, 1e-9)
    gw = int((u1 - u0) / h) + 1
    gh = int((v1 - v0) / h) + 1
    # occluder footprints: centre and radius on the grid plane
    cu = np.empty(n)
    cv = np.empty(n)
    rad = np.empty(n)
    con = np.empty((n, 3))  # the projected k_sigma ellipse's conic (pixel test)
    lo_i = np.empty(n, np.int64)
    hi_i = np.empty(n, np.int64)
    lo_j = np.empty(n, np.int64)
    hi_j = np.empty(n, np.int64)
    count = np.zeros(gw * gh + 1, np.int64)
    for i in range(n):
        mx, my, mz = occ[i, 0], occ[i, 1], occ[i, 2]
        cu[i] = mx * ax + my * ay + mz * az
        cv[i] = mx * bx + my * by + mz * bz
        c = cov6[i]
        # projected 2x2 covariance [e1 e2]^T Sigma [e1 e2]
        s_a0 = c[0] * ax + c[1] * ay + c[2] * az
        s_a1 = c[1] * ax + c[3] * ay + c[4] * az
        s_a2 = c[2] * ax + c[4] * ay + c[5] * az
        s_b0 = c[0] * bx + c[1] * by + c[2] * bz
        s_b1 = c[1] * bx + c[3] * by + c[4] * bz
        s_b2 = c[2] * bx + c[4] * by + c[5] * bz
        paa = ax * s_a0 + ay * s_a1 + az * s_a2
        pbb = bx * s_b0 + by * s_b1 + bz * s_b2
        pab = ax * s_b0 + ay * s_b1 + az * s_b2
        tr = 0.5 * (paa + pbb)
        det = paa * pbb - pab * pab
        lam = tr + math.sqrt(max(tr * tr - det, 0.0))
        r = k_sigma * math.sqrt(max(lam, 0.0))
        rad[i] = r
        if det > 1e-300 and r > 0.0:
            con[i, 0], con[i, 1], con[i, 2] = pbb / det, -pab / det, paa / det
        else:
            con[i, 0] = con[i, 2] = k_sigma * k_sigma / max(r * r, 1e-300)
            con[i, 1] = 0.0
        a0 = int(math.floor((cu[i] - r - u0) / h))
        a1 = int(math.floor((cu[i] + r - u0) / h))
        b0 = int(math.floor((cv[i] - r - v0) / h))
        b1 = int(math.floor((cv[i] + r - v0) / h))
        a0, a1 = max(a0, 0), min(a1, gw - 1)
        b0, b1 = max(b0, 0), min(b1, gh - 1)
        lo_i[i], hi_i[i], lo_j[i], hi_j[i] = a0, a1, b0, b1
        if a0 > a1 or b0 > b1:
            continue
        for q in range(b0, b1 + 1):
            for p in range(a0, a1 + 1):
                count[q * gw + p + 1] += 1
    for k in range(gw * gh):
        count[k + 1] += count[k]
    items = np.empty(count[gw * gh], np.int64)
    fill = count[:-1].copy()
    for i in range(n):
        a0, a1, b0, b1 = lo_i[i], hi_i[i], lo_j[i], hi_j[i]
        if a0 > a1 or b0 > b1:
            continue
        for q in range(b0, b1 + 1):
            for p in range(a0, a1 + 1):
                k = q * gw + p
                items[fill[k]] = i
                fill[k] += 1
    for j in range(m):
        p = min(int((pu[j] - u0) / h), gw - 1)
        q = min(int((pv[j] - v0) / h), gh - 1)
        k = q * gw + p
        acc = 0.0
        for t in range(count[k], count[k + 1]):
            i = items[t]
            du = pu[j] - cu[i]
            dv = pv[j] - cv[i]
            if con[i, 0] * du * du + 2.0 * con[i, 1] * du * dv + con[i, 2] * dv * dv > k2:
                continue
            acc += segment_depth(occ, i, pts[j, 0], pts[j, 1], pts[j, 2], dx, dy, dz, -np.inf, 0.0, dir_dep)
            if acc > TAU_OPAQUE:
                break
        out_col[j] = math.exp(-acc)


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _all_directions(dirs, occ, dir_dep, cov6, pts, k_sigma, cell, out):
    for d in prange(dirs.shape[0]):
        col = np.empty(pts.shape[0])
        _one_direction(dirs[d], occ, dir_dep, cov6, pts, k_sigma, cell, col)
        for j in range(pts.shape[0]):
            out[j, d] = col[j]


def transmittance_directions(dirs, occ, dir_dep: int, cov6, points, k_sigma: float = 3.0,
                             cell: float = 0.05) -> np.ndarray:
    """(M, D) float32 transmittance of ``points`` (M, 3) for the propagation directions
    ``dirs`` (D, 3) (normalised here); ``occ``, ``dir_dep``, ``cov6`` from
    ``dgsm_model.pack_gaussians``; ``cell``: bucket size in metres (module docstring)."""
    dirs = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    out = np.ones((pts.shape[0], dirs.shape[0]), np.float32)
    if occ.shape[0] == 0 or pts.shape[0] == 0 or dirs.shape[0] == 0:
        return out
    if not (np.isfinite(dirs).all() and (np.linalg.norm(dirs, axis=1) > 0).all()):
        raise ValueError("directions must be finite and non-zero")
    _all_directions(dirs, np.ascontiguousarray(occ, np.float64), int(dir_dep),
                    np.ascontiguousarray(cov6, np.float64), pts, float(k_sigma), float(cell), out)
    return out
