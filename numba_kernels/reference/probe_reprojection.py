"""Reference of :mod:`numba_kernels.probe_reprojection` (tests only): the formulas of its
docstring in vectorised numpy, one probe point at a time, the SH projection as a matrix
product, the z-buffer from ``direction_zbuffer`` (tested against its own reference)."""

from __future__ import annotations

import numpy as np

from ..direction_zbuffer import nearest_over_own_direction
from .sh_real import real_sh_basis


def reproject_probes(points, patch_points, normals, dirs, dist, weight, cos_c, radiance, degree: int,
                     occlusion_size: int, min_cos: float, max_ratio: float, disc: float, min_splat_cos: float,
                     same_layer: float, max_reach: int = 8) -> np.ndarray:
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    p, nrm, d = (np.asarray(a, np.float64) for a in (patch_points, normals, dirs))
    r, w, cos_c, lum = (np.asarray(a, np.float64) for a in (dist, weight, cos_c, radiance))
    out = np.empty((pts.shape[0], (degree + 1) ** 2, 3))
    for k, x in enumerate(pts):
        v = p - x
        dx = np.sqrt(np.sum(v * v, axis=1))
        ok = dx > 1e-9 * np.maximum(r, 1.0)
        dn = np.where(ok[:, None], v / np.where(ok, dx, 1.0)[:, None], d)
        cos_x = -np.sum(nrm * dn, axis=1)
        ratio = np.minimum((np.maximum(cos_x, 0.0) + min_cos) / (cos_c + min_cos), max_ratio)
        wx = w * np.where(ok, (r / np.where(ok, dx, 1.0)) ** 2 * ratio, 0.0)
        if occlusion_size:
            rad = np.where(cos_x > min_splat_cos, np.minimum(disc * np.sqrt(np.maximum(wx, 0.0)), 0.5), 0.0)
            hidden = nearest_over_own_direction(dn, dx, rad, int(occlusion_size), max_reach) * (1.0 + same_layer) < dx
            wx = np.where(hidden, 0.0, wx)
        out[k] = real_sh_basis(dn, degree).T @ (lum * wx[:, None])
    return out
