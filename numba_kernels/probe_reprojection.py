"""Parallax-corrected SH probes from one cube render's surface patches (the kernel of
``usd_gs.relight.parallax.reprojected_probes``; the maths is in that module's docstring).

Per probe point ``x`` (the points in threads, ``thread_chunks.run_chunks``): every live texel ``t``
(a patch at ``P_t`` with unit normal ``n_t`` facing the render's centre, distance ``r_t`` and
solid angle times coverage ``w_t`` there, |cos| ``cos_t`` between normal and ray, linear
radiance ``L_t``) is seen from ``x`` in direction ``d'_t`` at distance ``D_t`` with weight
``w'_t = w_t (r_t / D_t)^2 min((max(-n_t.d'_t, 0) + min_cos) / (cos_t + min_cos), max_ratio)``;
with the occlusion test (``occl_size`` > 0) texels hidden behind a nearer reprojected disc get
weight 0 (discs of angular radius ``min(disc sqrt(w'_t), 0.5)``, none below ``min_splat_cos``,
drawn into a cube z-buffer: ``numba_kernels.direction_zbuffer``; hidden when the buffer at the
texel's own direction is nearer than ``D_t / (1 + same_layer)``); the probe is
``a_lm = sum_t L_t Y_lm(d'_t) w'_t`` in the RH real basis of ``numba_kernels.sh_real``.
A point within ``1e-9 max(r_t, 1)`` of a patch keeps the texel's own direction and gets weight 0
from it. Units: metres, steradians; float64 throughout. Reference:
``numba_kernels.reference.probe_reprojection``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .cubemap_dirs import FACE_FRAMES
from .direction_zbuffer import _own_texel_depth, _splat
from .jit_options import threaded
from .sh_real import NORM, sh_eval_dirs
from .thread_chunks import run_chunks


@njit(**threaded(), cache=True, fastmath=False)
def _reproject(k0, k1, points, p, nrm, d, r, w, cos_c, lum, degree, norm, occl_size, max_reach, frames, min_cos,
               max_ratio, disc, min_splat_cos, same_layer, out):
    nt = p.shape[0]
    nb = (degree + 1) * (degree + 1)
    # the basis of every texel's direction at once (sh_eval_dirs: sh_eval_dir's values bit for bit)
    basis = np.empty((nb, nt))
    dx, dy, dz = np.empty(nt), np.empty(nt), np.empty(nt)
    cm, sm, q1, q2 = np.empty(nt), np.empty(nt), np.empty(nt), np.empty(nt)
    lw = np.empty((3, nt))
    for k in range(k0, k1):
        x0, x1, x2 = points[k, 0], points[k, 1], points[k, 2]
        dn = np.empty((nt, 3))
        dist = np.empty(nt)
        wx = np.empty(nt)
        rad = np.zeros(nt)
        for t in range(nt):
            v0, v1, v2 = p[t, 0] - x0, p[t, 1] - x1, p[t, 2] - x2
            dd = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            dist[t] = dd
            ok = dd > 1e-9 * max(r[t], 1.0)
            if ok:
                dn[t, 0], dn[t, 1], dn[t, 2] = v0 / dd, v1 / dd, v2 / dd
            else:
                dn[t, 0], dn[t, 1], dn[t, 2] = d[t, 0], d[t, 1], d[t, 2]
            dx[t], dy[t], dz[t] = dn[t, 0], dn[t, 1], dn[t, 2]
            cos_x = -(nrm[t, 0] * dn[t, 0] + nrm[t, 1] * dn[t, 1] + nrm[t, 2] * dn[t, 2])
            ratio = min((max(cos_x, 0.0) + min_cos) / (cos_c[t] + min_cos), max_ratio)
            wx[t] = w[t] * ((r[t] / dd) ** 2 * ratio) if ok else 0.0
            if occl_size > 0 and cos_x > min_splat_cos:
                rad[t] = min(disc * math.sqrt(max(wx[t], 0.0)), 0.5)
        if occl_size > 0:
            zbuf = np.full((6, occl_size, occl_size), np.inf)
            _splat(dn, dist, rad, frames, occl_size, max_reach, zbuf)
            own = np.empty(nt)
            _own_texel_depth(dn, zbuf, frames, occl_size, own)
            for t in range(nt):
                if own[t] * (1.0 + same_layer) < dist[t]:
                    wx[t] = 0.0
        sh_eval_dirs(dx, dy, dz, degree, norm, basis, cm, sm, q1, q2)
        for t in range(nt):
            lw[0, t], lw[1, t], lw[2, t] = lum[t, 0] * wx[t], lum[t, 1] * wx[t], lum[t, 2] * wx[t]
        # each coefficient's sum over the texels in texel order (the order of a texel-major loop)
        for b in range(nb):
            a0 = a1 = a2 = 0.0
            for t in range(nt):
                if wx[t] != 0.0:
                    a0 += basis[b, t] * lw[0, t]
                    a1 += basis[b, t] * lw[1, t]
                    a2 += basis[b, t] * lw[2, t]
            out[k, b, 0], out[k, b, 1], out[k, b, 2] = a0, a1, a2


def reproject_probes(points, patch_points, normals, dirs, dist, weight, cos_c, radiance, degree: int,
                     occlusion_size: int, min_cos: float, max_ratio: float, disc: float, min_splat_cos: float,
                     same_layer: float, max_reach: int = 8) -> np.ndarray:
    """(K, (degree+1)^2, 3) float64 RH SH probes at ``points`` (K, 3) from the live texels:
    ``patch_points`` (T, 3), ``normals`` (T, 3), ``dirs`` (T, 3) (unit, from the render's centre),
    ``dist`` (T,), ``weight`` (T,) > 0, ``cos_c`` (T,), ``radiance`` (T, 3) (module docstring);
    ``occlusion_size`` 0: no occlusion test."""
    def f64(a, shape):
        return np.ascontiguousarray(a, np.float64).reshape(shape)

    pts = f64(points, (-1, 3))
    t = np.asarray(dist).reshape(-1).shape[0]
    degree = int(degree)
    out = np.zeros((pts.shape[0], (degree + 1) ** 2, 3))
    if pts.shape[0] == 0 or t == 0:
        return out
    run_chunks(_reproject, pts.shape[0], pts, f64(patch_points, (t, 3)), f64(normals, (t, 3)), f64(dirs, (t, 3)),
               f64(dist, (t,)), f64(weight, (t,)), f64(cos_c, (t,)), f64(radiance, (t, 3)), degree, NORM,
               int(occlusion_size), int(max_reach), FACE_FRAMES, float(min_cos), float(max_ratio), float(disc),
               float(min_splat_cos), float(same_layer), out,
               chunks_per_thread=1)
    return out
