"""Reference of :mod:`numba_kernels.zh_transfer`: the RGCA diffuse colour as a brute-force
quadrature of probe radiance times each zonal lobe over the sphere."""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from .quaternion import rotation_matrices
from .sh_real import real_sh_basis, sphere_quadrature


def zonal_function(z_rgca, axis, dirs) -> np.ndarray:
    """RGCA lobe as a function of direction: ``sum_l z_l (2l+1)/(4 pi) P_l(<a, w>)`` (M,)."""
    l = np.arange(len(z_rgca))
    return legendre.legval(np.asarray(dirs) @ np.asarray(axis), np.asarray(z_rgca) * (2 * l + 1) / (4 * np.pi))


def zh_diffuse_color(quat, albedo, zh_color, zh_mono, probe, gamma: float, n_theta: int = 20,
                     n_phi: int = 40) -> np.ndarray:
    """``gamma albedo sum_axes integral L(w) lobe(w) dw`` (N, 3) float64: one lobe per local axis a
    (column a of R(q)) with coefficients ``zh_color[:, a, :, c]`` then ``zh_mono[:, a]`` (float32),
    probe (81, 3) RH degree 8; the default quadrature integrates degree 8 x degree 8 exactly."""
    dirs, w = sphere_quadrature(n_theta, n_phi, phi_offset=0.5)
    radiance = real_sh_basis(dirs, 8) @ np.asarray(probe, np.float64)  # (M, 3)
    rot = rotation_matrices(np.asarray(quat).astype(np.float32).astype(np.float64))
    out = np.zeros((len(rot), 3))
    for k in range(len(rot)):
        for a in range(3):
            for ch in range(3):
                z = np.concatenate([zh_color[k, a, :, ch], zh_mono[k, a]]).astype(np.float32)
                out[k, ch] += np.sum(w * radiance[:, ch] * zonal_function(z.astype(np.float64), rot[k, :, a], dirs))
    return gamma * np.asarray(albedo).astype(np.float32) * out
