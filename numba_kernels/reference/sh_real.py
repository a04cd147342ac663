"""Reference of :mod:`numba_kernels.sh_real`: the real SH basis built from scipy's complex
spherical harmonics (an implementation independent of the kernels' Legendre recurrence), and
the 3DGS basis and Gaussian colour derived from it (``Y3dgs_lm = (-1)^m Y_lm``, degree <= 3).
"""

from __future__ import annotations

import math

import numpy as np


def real_sh_basis(dirs, degree: int) -> np.ndarray:
    """RH real SH (M, (degree+1)^2) float64 at unit directions (M, 3), from scipy's complex SH
    (which include the Condon-Shortley phase, removed here)."""
    from scipy.special import sph_harm_y

    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    cols = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            if m == 0:
                cols.append(y.real)
            elif m > 0:
                cols.append(math.sqrt(2) * (-1) ** m * y.real)
            else:
                cols.append(math.sqrt(2) * (-1) ** m * y.imag)
    return np.stack(cols, axis=1)


def threedgs_basis(dirs, degree: int) -> np.ndarray:
    """3DGS basis (M, (degree+1)^2) float64 (degree <= 3): the RH basis times ``(-1)^m``."""
    m = np.concatenate([np.arange(-l, l + 1) for l in range(degree + 1)])
    return real_sh_basis(dirs, degree) * np.where(m % 2 == 0, 1.0, -1.0)


def threedgs_color(sh, dirs) -> np.ndarray:
    """Unclamped colour ``0.5 + SH(dir)`` (N, 3) float64 of Gaussians with 3DGS coefficients
    ``sh`` (N, K, 3) seen along unit ``dirs`` (N, 3) or (3,)."""
    sh = np.asarray(sh, dtype=np.float64)
    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    basis = threedgs_basis(np.broadcast_to(np.asarray(dirs, np.float64), (sh.shape[0], 3)), degree)
    return 0.5 + np.einsum("nk,nkc->nc", basis, sh)


def sphere_quadrature(n_theta: int, n_phi: int, phi_offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre in cos(theta) x ``n_phi`` uniform phi (``2 pi (k + phi_offset) / n_phi``):
    unit directions (n_theta n_phi, 3) and solid-angle weights; exact for polynomials of degree
    < min(2 n_theta, n_phi) on the sphere."""
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    phi = 2 * np.pi * (np.arange(n_phi) + phi_offset) / n_phi
    z, p = np.meshgrid(x, phi, indexing="ij")
    r = np.sqrt(1 - z * z)
    dirs = np.stack([r * np.cos(p), r * np.sin(p), z], -1).reshape(-1, 3)
    return dirs, np.repeat(wx * 2 * np.pi / n_phi, n_phi)
