"""Lighting transfer from an SH probe onto Gaussians (paper section 3.5, eqs. 9-10).

Per Gaussian with unit normal ``n`` and probe radiance ``L_c(w)`` (RH real SH basis,
``numba_kernels.sh_real``; the probe is radiance arriving *from* direction ``w``):

    s_c(n) = clip_[0, t_max]( int L_c(w) S(w, n) dw / (int S(w, n) dw + eps) ),
    S(w, n) = max(0, <w, n>)^q.                                               (eqs. 9, 10)

Two implementations of the same quantity:

- :func:`transfer_scale_sh` (fast path): Funk-Hecke in the SH domain,
  numerator ``sum_lm A_l(q) L_lm Y_lm(n)``, denominator ``A_0(q) = 2 pi / (q + 1)``, with
  ``A_l = 2 pi int_0^1 t^q P_l(t) dt`` (``sh_real.cosine_lobe_band_factors``), O((d+1)^2)
  per Gaussian. This is the M -> infinity limit of the reference.
- :func:`transfer_scale_quadrature` (reference): eq. 10 literally, on a latitude-longitude
  grid of ``M = n_theta * n_phi`` directions (pole +Z; the integral does not depend on the
  frame), midpoint rule with weights ``w_j = sin(theta_j) dtheta dphi`` in steradians (they
  sum to ~4 pi), so ``eps`` means the same (steradians) in both paths.

Radiance is evaluated from the SH expansion without clamping (negative ringing lobes are
integrated as they are in both paths); the clip to [0, t_max] is applied to the ratio.
A zero-length normal gets the isotropic ratio ``L_00 Y_00 * 4 pi / (4 pi + eps)`` (mean
radiance); callers are expected to pass unit normals.

:func:`relight_sh_coefficients` turns the per-channel factor into relit 3DGS coefficients
(see its docstring for the exact coefficient-space form).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .jit_options import prange_only, read_only, threaded
from .sh_real import NORM, SH_C0, band_of_index, cosine_lobe_band_factors, degree_from_num_coeffs, sh_eval_batch
from .thread_chunks import run_chunks

_CHUNK = 256


def _check_params(q: float, t_max: float, eps: float) -> None:
    if not (math.isfinite(q) and q > -1.0):
        raise ValueError(f"cosine lobe exponent q must be finite and > -1, got {q}")
    if not (t_max >= 0.0):
        raise ValueError(f"t_max must be >= 0, got {t_max}")
    if not (math.isfinite(eps) and eps >= 0.0):
        raise ValueError(f"eps must be finite and >= 0, got {eps}")


@njit(cache=True, fastmath=False, inline="always")
def _clip(r, t_max):
    """``r`` clipped to [0, t_max]; NaN -> 0."""
    if not r > 0.0:
        return 0.0
    return t_max if r > t_max else r


@njit(cache=True, fastmath=False, **threaded())
def _scale_sh_kernel(c0, c1, normals, weighted_probes, blend, den, degree, t_max, eps, norm, out):
    """out[i] = sum_p blend[i, p] * clip(ratio of probe p) (eq. 10 per probe, blended);
    ``blend`` (1, P) applies its one row to every Gaussian. Chunks ``c0..c1-1`` of ``_CHUNK``
    Gaussians (threads: ``thread_chunks.run_chunks``). Each probe's numerator is summed over the
    coefficients in order for the whole chunk at once (the inner loop runs over the chunk's
    Gaussians: contiguous, vectorised), the same sums as one Gaussian at a time."""
    n = normals.shape[0]
    k = (degree + 1) * (degree + 1)
    n_probes = weighted_probes.shape[0]
    shared = blend.shape[0] == 1
    iso = math.sqrt(4.0 * math.pi)  # integral of L over the sphere = sqrt(4 pi) L_00
    f_iso = iso / (den * (4.0 * math.pi + eps))  # zero normal: isotropic lobe, mean radiance
    for ch in range(c0, c1):
        i0 = ch * _CHUNK
        gn = min(n, i0 + _CHUNK) - i0
        x = np.empty(gn, dtype=np.float64)
        y = np.empty(gn, dtype=np.float64)
        z = np.empty(gn, dtype=np.float64)
        ok = np.empty(gn, dtype=np.bool_)
        basis = np.empty((k, gn), dtype=np.float64)
        cm = np.empty(gn, dtype=np.float64)
        sm = np.empty(gn, dtype=np.float64)
        p1 = np.empty(gn, dtype=np.float64)
        p2 = np.empty(gn, dtype=np.float64)
        for g in range(gn):
            nx = np.float64(normals[i0 + g, 0])
            ny = np.float64(normals[i0 + g, 1])
            nz = np.float64(normals[i0 + g, 2])
            ln = math.sqrt(nx * nx + ny * ny + nz * nz)
            ok[g] = ln > 1e-12  # False also for NaN
            if ok[g]:
                x[g] = nx / ln
                y[g] = ny / ln
                z[g] = nz / ln
            else:
                x[g] = 0.0
                y[g] = 0.0
                z[g] = 1.0
        sh_eval_batch(x, y, z, degree, norm, basis, cm, sm, p1, p2)
        r0 = np.empty(gn, dtype=np.float64)
        r1 = np.empty(gn, dtype=np.float64)
        r2 = np.empty(gn, dtype=np.float64)
        tot0 = np.zeros(gn, dtype=np.float64)
        tot1 = np.zeros(gn, dtype=np.float64)
        tot2 = np.zeros(gn, dtype=np.float64)
        for p in range(n_probes):
            r0[:] = 0.0
            r1[:] = 0.0
            r2[:] = 0.0
            for a in range(k):
                w0 = weighted_probes[p, a, 0]
                w1 = weighted_probes[p, a, 1]
                w2 = weighted_probes[p, a, 2]
                for g in range(gn):
                    b = basis[a, g]
                    r0[g] += w0 * b
                    r1[g] += w1 * b
                    r2[g] += w2 * b
            for g in range(gn):
                wgt = np.float64(blend[0 if shared else i0 + g, p])
                if wgt == 0.0:
                    continue
                if ok[g]:
                    v0 = r0[g] / (den + eps)
                    v1 = r1[g] / (den + eps)
                    v2 = r2[g] / (den + eps)
                else:
                    v0 = weighted_probes[p, 0, 0] * f_iso
                    v1 = weighted_probes[p, 0, 1] * f_iso
                    v2 = weighted_probes[p, 0, 2] * f_iso
                tot0[g] += wgt * _clip(v0, t_max)
                tot1[g] += wgt * _clip(v1, t_max)
                tot2[g] += wgt * _clip(v2, t_max)
        for g in range(gn):
            out[i0 + g, 0] = tot0[g]
            out[i0 + g, 1] = tot1[g]
            out[i0 + g, 2] = tot2[g]


def transfer_scale_sh(normals: np.ndarray, probe_rh: np.ndarray, q: float = 1.0,
                      t_max: float = 8.0, eps: float = 1e-6, blend: np.ndarray | None = None) -> np.ndarray:
    """Closed-form eq. 10: per-channel lighting scale (N, 3) float32.

    normals: (N, 3) unit normals (world frame of the probe). probe_rh: (K, 3) RH-basis
    radiance coefficients of any degree 0..8, or (P, K, 3) for P probes blended per Gaussian
    with ``blend`` (N, P) weights (rows summing to 1; zeros skip a probe): the result is then
    ``sum_p blend[i, p] * s_p(n_i)``, each ``s_p`` clipped on its own. q: lobe exponent (> -1);
    t_max: upper clip; eps: denominator regulariser in steradians.
    """
    q, t_max, eps = float(q), float(t_max), float(eps)
    _check_params(q, t_max, eps)
    probe = np.asarray(probe_rh, dtype=np.float64)
    if probe.ndim == 2:
        probe = probe[None]
    if probe.ndim != 3 or probe.shape[2] != 3:
        raise ValueError(f"probe must have shape (K, 3) or (P, K, 3), got {np.shape(probe_rh)}")
    nrm = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
    if blend is None:
        if probe.shape[0] != 1:
            raise ValueError(f"{probe.shape[0]} probes need blend weights of shape (N, {probe.shape[0]})")
        w = np.ones((1, 1), np.float32)
    else:
        w = np.ascontiguousarray(blend, dtype=np.float32)
        if w.shape != (nrm.shape[0], probe.shape[0]):
            raise ValueError(f"blend must have shape ({nrm.shape[0]}, {probe.shape[0]}), got {w.shape}")
    degree = degree_from_num_coeffs(probe.shape[1])
    a_l = cosine_lobe_band_factors(q, degree)
    weighted = np.ascontiguousarray(probe * a_l[band_of_index(degree)][None, :, None])
    out = np.empty((nrm.shape[0], 3), dtype=np.float32)
    run_chunks(_scale_sh_kernel, (nrm.shape[0] + _CHUNK - 1) // _CHUNK, nrm, weighted, w, float(a_l[0]), degree,
               t_max, eps, NORM, out)
    return out


def latlong_quadrature(n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (M, 3) and weights (M,) of the reference grid (pole +Z, midpoint rule).

    ``theta_i = pi (i + 0.5) / n_theta``, ``phi_j = 2 pi (j + 0.5) / n_phi``,
    ``w = sin(theta) * (pi / n_theta) * (2 pi / n_phi)`` (steradians).
    """
    th = np.pi * (np.arange(n_theta, dtype=np.float64) + 0.5) / n_theta
    ph = 2.0 * np.pi * (np.arange(n_phi, dtype=np.float64) + 0.5) / n_phi
    t, p = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    w = (np.sin(t) * (np.pi / n_theta) * (2.0 * np.pi / n_phi)).reshape(-1)
    return dirs, w


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _scale_quadrature_kernel(normals, dirs, weights, radiance, q, t_max, eps, out):
    n = normals.shape[0]
    m = dirs.shape[0]
    for i in prange(n):
        nx = np.float64(normals[i, 0])
        ny = np.float64(normals[i, 1])
        nz = np.float64(normals[i, 2])
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 1e-12:
            nx /= ln
            ny /= ln
            nz /= ln
        num0 = 0.0
        num1 = 0.0
        num2 = 0.0
        den = 0.0
        for j in range(m):
            if ln > 1e-12:
                cs = dirs[j, 0] * nx + dirs[j, 1] * ny + dirs[j, 2] * nz
                if cs <= 0.0:
                    continue
                s = weights[j] * (cs if q == 1.0 else math.pow(cs, q))
            else:
                s = weights[j]
            num0 += s * radiance[j, 0]
            num1 += s * radiance[j, 1]
            num2 += s * radiance[j, 2]
            den += s
        for c in range(3):
            r = (num0 if c == 0 else (num1 if c == 1 else num2)) / (den + eps)
            if not r > 0.0:
                r = 0.0
            if r > t_max:
                r = t_max
            out[i, c] = r


def transfer_scale_quadrature(normals: np.ndarray, probe_rh: np.ndarray, q: float = 1.0,
                              t_max: float = 8.0, eps: float = 1e-6,
                              n_theta: int = 64, n_phi: int = 128) -> np.ndarray:
    """Reference eq. 10 by lat-long quadrature (M = n_theta * n_phi); (N, 3) float64.

    Same arguments as :func:`transfer_scale_sh`; cost O(N M).
    """
    q, t_max, eps = float(q), float(t_max), float(eps)
    _check_params(q, t_max, eps)
    probe = np.asarray(probe_rh, dtype=np.float64)
    degree = degree_from_num_coeffs(probe.shape[0])
    dirs, w = latlong_quadrature(int(n_theta), int(n_phi))
    from .sh_real import eval_basis_rh_numpy

    radiance = np.ascontiguousarray(eval_basis_rh_numpy(dirs, degree) @ probe)  # (M, 3)
    nrm = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
    out = np.empty((nrm.shape[0], 3), dtype=np.float64)
    _scale_quadrature_kernel(nrm, dirs, w, radiance, q, t_max, eps, out)
    return out


@njit(cache=True, fastmath=False, inline="always")
def _scaled_row(sh, i, f0, f1, f2, c0, out):
    """Row ``i`` of :func:`relight_sh_coefficients`: colour factors ``f0, f1, f2`` (float64)."""
    out[i, 0, 0] = (f0 * (0.5 + c0 * np.float64(sh[i, 0, 0])) - 0.5) / c0
    out[i, 0, 1] = (f1 * (0.5 + c0 * np.float64(sh[i, 0, 1])) - 0.5) / c0
    out[i, 0, 2] = (f2 * (0.5 + c0 * np.float64(sh[i, 0, 2])) - 0.5) / c0
    for a in range(1, sh.shape[1]):
        out[i, a, 0] = f0 * np.float64(sh[i, a, 0])
        out[i, a, 1] = f1 * np.float64(sh[i, a, 1])
        out[i, a, 2] = f2 * np.float64(sh[i, a, 2])


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _relight_kernel(sh, scale, gamma, c0, out):
    n, k, _ = sh.shape
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for ch in prange(n_chunks):
        for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
            _scaled_row(sh, i, gamma * np.float64(scale[i, 0]), gamma * np.float64(scale[i, 1]),
                        gamma * np.float64(scale[i, 2]), c0, out)


@njit(cache=True, **threaded(), fastmath=False)
def _shade_kernel(i0_, i1_, sh, lit, transmittance, sky, f, c0, out):
    for i in range(i0_, i1_):
        if lit[i]:
            k = np.float32((1.0 - f) + f * np.float64(transmittance[i]))
            s = np.float64(np.float32(k * sky[i]))  # (float32 times float32, rounded to float32)
            _scaled_row(sh, i, s, s, s, c0, out)
        else:
            for a in range(sh.shape[1]):
                out[i, a, 0] = sh[i, a, 0]
                out[i, a, 1] = sh[i, a, 1]
                out[i, a, 2] = sh[i, a, 2]


def shade_rows(sh: np.ndarray, lit: np.ndarray, transmittance: np.ndarray, sky: np.ndarray, direct_fraction: float,
               threads: bool = True) -> np.ndarray:
    """(N, K, 3) float32 SH: where ``lit`` (N,) bool, row ``i`` of ``sh`` (N, K, 3) shadowed as
    :func:`relight_sh_coefficients` with the grey factor ``float32(float32(1 - f + f T_i) * sky_i)``
    (``T`` ``transmittance`` (N,) float32, ``sky`` (N,) float32 the sky's share still seen, ``f``
    ``direct_fraction``): bit for bit ``relight_sh_coefficients(sh[lit], factor[lit])``; elsewhere
    ``sh``'s row as it is. One pass, without the gathers and the copy of the masked form.
    ``threads``: in the kernel threads, or (False) in the calling thread."""
    sh = np.ascontiguousarray(sh, dtype=np.float32)
    lit = np.ascontiguousarray(lit, dtype=np.bool_)
    t = np.ascontiguousarray(transmittance, dtype=np.float32)
    k = np.ascontiguousarray(sky, dtype=np.float32)
    n = sh.shape[0]
    if sh.ndim != 3 or sh.shape[2] != 3 or lit.shape != (n,) or t.shape != (n,) or k.shape != (n,):
        raise ValueError(f"shade_rows: sh (N, K, 3) and (N,) lit, transmittance, sky; got {sh.shape}, "
                         f"{lit.shape}, {t.shape}, {k.shape}")
    if not math.isfinite(direct_fraction):
        raise ValueError(f"direct fraction must be finite, got {direct_fraction}")
    out = np.empty_like(sh)
    run_chunks(_shade_kernel, n, read_only(sh), lit, t, k, float(direct_fraction), SH_C0, out, min_chunk=4096,
               threads=threads)
    return out


def relight_sh_coefficients(sh: np.ndarray, scale: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """Relit 3DGS SH coefficients for ``c'(dir) = gamma * s_c * c(dir)`` (float32, (N, K, 3)).

    The 3DGS colour is ``c(dir) = 0.5 + sum_k sh_k Y_k(dir)`` (``usd_gs.sh3dgs``), so scaling
    the colour (not ``colour - 0.5``) by ``f_c = gamma * s_c`` gives
    ``sh'_0 = (f (0.5 + C0 sh_0) - 0.5) / C0`` and ``sh'_k = f sh_k`` for k >= 1: every band
    is scaled, view dependence survives. The paper's ``max(0, .)`` is the renderer's usual
    clamp of the evaluated colour; it cannot be expressed on coefficients and is not applied.
    """
    sh = np.ascontiguousarray(sh, dtype=np.float32)
    scale = np.ascontiguousarray(scale, dtype=np.float32)
    if sh.ndim != 3 or sh.shape[2] != 3 or scale.shape != (sh.shape[0], 3):
        raise ValueError(f"sh must be (N, K, 3) and scale (N, 3); got {sh.shape} and {scale.shape}")
    if not math.isfinite(gamma):
        raise ValueError(f"gamma must be finite, got {gamma}")
    out = np.empty_like(sh)
    _relight_kernel(read_only(sh), scale, float(gamma), SH_C0, out)
    return out
