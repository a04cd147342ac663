"""Zonal-harmonic diffuse radiance transfer for avatars with RGCA appearance (RGCA 3.2.1).

Per Gaussian k (RGCA eqs. 7-9):

    c_k = gamma * rho_k (.) sum_{l,m} L_lm (.) d_k^{lm},
    d_k^{lm} = sum_{a in (t, b, n)} z_k^{a,l} Y_lm(a_k),

with ``rho`` the albedo (3), ``L_lm`` the probe radiance (RH basis, ``numba_kernels.sh_real``),
``t, b, n`` the first, second and third columns of the Gaussian's rotation matrix R(q)
(q = (w, x, y, z), world = R @ local), ``z^{a,l}`` coloured (per channel) for l = 0..3 and
monochrome (shared by the channels) for l = 4..8.

ZH coefficient convention (RGCA eq. 8, stored as is): the rotated SH coefficients of a ZH
lobe with axis ``a`` are ``z_l Y_lm(a)``; the lobe as a function of direction w is
``f(w) = sum_l z_l (2l + 1) / (4 pi) P_l(<a, w>)`` (addition theorem). A zonal function
with SH coefficients ``c_l`` on ``Y_l0`` about +Z has ``z_l = sqrt(4 pi / (2l + 1)) c_l``
(:func:`zonal_to_rgca`). The rotation ``z_l -> z_l Y_lm(a)`` is exact (no truncation). The
result ``sum_m L_lm Y_lm(a)`` does not depend on the real-SH sign convention as long as the
probe and Y use the same one; here both are RH.

Layouts: ``zh_color`` (N, 3 axes [t, b, n], 4 bands [0..3], 3 channels); ``zh_mono``
(N, 3 axes, 5 bands [4..8]) or ``None``. Bands above the probe degree contribute nothing
(the probe has no energy there). Cost per Gaussian: 3 SH evaluations to degree d and
O(3 (d+1)^2) multiply-adds.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .jit_options import prange_only
from .quaternion import quat_to_rotation
from .sh_real import NORM, degree_from_num_coeffs, sh_eval_batch

_CHUNK = 64


def zonal_to_rgca(zonal: np.ndarray) -> np.ndarray:
    """``c_l`` (Y_l0 coefficients about the lobe axis, last axis = l) -> RGCA ``z_l``."""
    c = np.asarray(zonal, dtype=np.float64)
    l = np.arange(c.shape[-1], dtype=np.float64)
    return c * np.sqrt(4.0 * np.pi / (2.0 * l + 1.0))


def rgca_to_zonal(z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zonal_to_rgca`."""
    z = np.asarray(z, dtype=np.float64)
    l = np.arange(z.shape[-1], dtype=np.float64)
    return z / np.sqrt(4.0 * np.pi / (2.0 * l + 1.0))


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _zh_kernel(quat, albedo, zh_color, zh_mono, has_mono, probe, degree, gamma, norm, out):
    n = quat.shape[0]
    k = (degree + 1) * (degree + 1)
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for ch in prange(n_chunks):
        i0 = ch * _CHUNK
        gn = min(n, i0 + _CHUNK) - i0
        m3 = 3 * gn  # directions: axis ax of Gaussian g at index ax * gn + g
        x = np.empty(m3, dtype=np.float64)
        y = np.empty(m3, dtype=np.float64)
        z = np.empty(m3, dtype=np.float64)
        basis = np.empty((k, m3), dtype=np.float64)
        cm = np.empty(m3, dtype=np.float64)
        sm = np.empty(m3, dtype=np.float64)
        p1 = np.empty(m3, dtype=np.float64)
        p2 = np.empty(m3, dtype=np.float64)
        zw = np.zeros((3, degree + 1, 3, gn), dtype=np.float64)  # [axis, band, channel, g]
        acc = np.zeros((3, gn), dtype=np.float64)
        for g in range(gn):
            i = i0 + g
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(
                np.float64(quat[i, 0]), np.float64(quat[i, 1]), np.float64(quat[i, 2]), np.float64(quat[i, 3]))
            # columns of R(q): tangent, bitangent, normal
            x[g], y[g], z[g] = r00, r10, r20
            x[gn + g], y[gn + g], z[gn + g] = r01, r11, r21
            x[2 * gn + g], y[2 * gn + g], z[2 * gn + g] = r02, r12, r22
            for ax in range(3):
                for l in range(min(degree, 3) + 1):
                    for c in range(3):
                        zw[ax, l, c, g] = zh_color[i, ax, l, c]
                if has_mono:
                    for l in range(4, degree + 1):
                        v = np.float64(zh_mono[i, ax, l - 4])
                        for c in range(3):
                            zw[ax, l, c, g] = v
        sh_eval_batch(x, y, z, degree, norm, basis, cm, sm, p1, p2)
        # colour_c = sum_k L_kc * sum_ax z_{ax, l(k), c} Y_k(ax), accumulated over k with the
        # inner loop over Gaussians (independent, vectorisable)
        for l in range(degree + 1):
            for kk in range(l * l, (l + 1) * (l + 1)):
                for c in range(3):
                    lc = probe[kk, c]
                    for g in range(gn):
                        acc[c, g] += lc * (zw[0, l, c, g] * basis[kk, g] + zw[1, l, c, g] * basis[kk, gn + g]
                                           + zw[2, l, c, g] * basis[kk, 2 * gn + g])
        for g in range(gn):
            i = i0 + g
            for c in range(3):
                out[i, c] = gamma * np.float64(albedo[i, c]) * acc[c, g]


def zh_diffuse_color(orientations: np.ndarray, albedo: np.ndarray, zh_color: np.ndarray,
                     zh_mono: np.ndarray | None, probe_rh: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """Diffuse RGB (N, 3) float32 of RGCA eq. 7 with the ZH transfer of eq. 9.

    orientations (N, 4) (w, x, y, z); albedo (N, 3); zh_color (N, 3, 4, 3); zh_mono (N, 3, 5)
    or None; probe_rh (K, 3) RH radiance coefficients, degree 0..8; gamma: global intensity.
    Output is linear radiance-weighted colour, not clamped.
    """
    quat = np.ascontiguousarray(orientations, dtype=np.float32).reshape(-1, 4)
    n = quat.shape[0]
    albedo = np.ascontiguousarray(albedo, dtype=np.float32)
    zh_color = np.ascontiguousarray(zh_color, dtype=np.float32)
    if albedo.shape != (n, 3):
        raise ValueError(f"albedo must have shape ({n}, 3), got {albedo.shape}")
    if zh_color.shape != (n, 3, 4, 3):
        raise ValueError(f"zh_color must have shape ({n}, 3, 4, 3), got {zh_color.shape}")
    has_mono = zh_mono is not None
    if has_mono:
        zh_mono = np.ascontiguousarray(zh_mono, dtype=np.float32)
        if zh_mono.shape != (n, 3, 5):
            raise ValueError(f"zh_mono must have shape ({n}, 3, 5), got {zh_mono.shape}")
    else:
        zh_mono = np.zeros((1, 3, 5), dtype=np.float32)
    probe = np.ascontiguousarray(probe_rh, dtype=np.float64)
    if probe.ndim != 2 or probe.shape[1] != 3:
        raise ValueError(f"probe must have shape (K, 3), got {probe.shape}")
    degree = degree_from_num_coeffs(probe.shape[0])
    if degree > 8:
        raise ValueError(f"probe degree {degree} > 8")
    if not math.isfinite(gamma):
        raise ValueError(f"gamma must be finite, got {gamma}")
    out = np.empty((n, 3), dtype=np.float32)
    _zh_kernel(quat, albedo, zh_color, zh_mono, has_mono, probe, degree, float(gamma), NORM, out)
    return out
