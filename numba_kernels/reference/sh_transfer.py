"""Reference of :mod:`numba_kernels.sh_transfer`: eq. 10 written out with numpy on a given
quadrature, and the relit SH coefficients by their formula."""

from __future__ import annotations

import math

import numpy as np

from .sh_real import real_sh_basis


def transfer_scale_quadrature(normals, probe_rh, q: float, t_max: float, eps: float, dirs, weights) -> np.ndarray:
    """``clip(sum_w L(w) max(0, <n, w>)^q dw / (sum_w max(0, <n, w>)^q dw + eps), 0, t_max)`` (N, 3)
    for unit normals (N, 3), an RH probe (K, 3) and quadrature directions (M, 3) / weights (M,)."""
    probe_rh = np.asarray(probe_rh, np.float64)
    degree = int(round(math.sqrt(probe_rh.shape[0]))) - 1
    radiance = real_sh_basis(dirs, degree) @ probe_rh  # (M, 3)
    s = np.maximum(0.0, np.asarray(normals, np.float64) @ np.asarray(dirs, np.float64).T) ** q  # (N, M)
    ref = (s * weights) @ radiance / ((s * weights).sum(axis=1, keepdims=True) + eps)
    return np.clip(ref, 0.0, t_max)


def relight_sh_coefficients(sh, scale, gamma: float = 1.0) -> np.ndarray:
    """``sh'_0 = (f (0.5 + C0 sh_0) - 0.5) / C0``, ``sh'_k = f sh_k`` (k >= 1), ``f = gamma scale``,
    ``C0 = 1 / (2 sqrt(pi))``: (N, K, 3) float64 from sh (N, K, 3) and scale (N, 3)."""
    c0 = 0.5 / math.sqrt(math.pi)
    f = gamma * np.asarray(scale, np.float64)[:, None, :]
    out = f * np.asarray(sh, np.float64)
    out[:, 0] = (f[:, 0] * (0.5 + c0 * np.asarray(sh, np.float64)[:, 0]) - 0.5) / c0
    return out
