"""Real orthonormal spherical harmonics (Ramamoorthi-Hanrahan / Sloan basis), degree 0..8.

Basis ("RH"): for a unit direction ``(x, y, z) = (sin t cos p, sin t sin p, cos t)``

- ``Y_l0  = K_l0 P_l(z)``
- ``Y_lm  = sqrt(2) K_lm P_l^m(cos t) cos(m p)``      for m > 0
- ``Y_l-m = sqrt(2) K_lm P_l^m(cos t) sin(m p)``      for m > 0

with ``K_lm = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)`` and the associated Legendre functions
*without* the Condon-Shortley phase, so band 1 is ``(+c y, +c z, +c x)``, ``c = 0.4886...``
(Ramamoorthi & Hanrahan 2001, Sloan "Stupid SH tricks"). The basis is orthonormal on the
unit sphere (integral of ``Y_a Y_b`` over solid angle is ``delta_ab``).

Coefficient index: ``k = l*l + l + m`` (l = 0..d, m = -l..l), ``K = (d+1)^2`` per channel,
the same ordering as the 3DGS basis of ``usd_gs.sh3dgs``.

Relation to the 3DGS basis (graphdeco ``sh_utils``, shared/DESIGN.md section 1) for
d <= 3: ``Y3dgs_lm = (-1)^m Y_lm`` (the 3DGS code keeps the Condon-Shortley phase), so
converting coefficients is a per-coefficient sign flip, an involution:
``rh_to_3dgs == threedgs_to_rh``. Degrees 4..8 exist only in this RH basis (they are used
by ZH avatars); the 3DGS basis stops at degree 3.

``sh_eval_dir`` (one direction) and ``sh_eval_batch`` (G directions, structure of arrays,
SIMD-friendly: ~20 ns per direction at degree 8) are the building blocks of the other
kernels; ``eval_basis_rh`` is a numba kernel (parallel over directions);
``eval_basis_rh_numpy`` is the same recurrence written with numpy (no numba), used by
modules that must not compile anything and by tests as an independent path.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .jit_options import prange_only

MAX_DEGREE = 8

# The 3DGS basis of graphdeco-inria ``sh_utils.py`` (degree <= 3; band 1 is ``-C1 y, +C1 z, -C1 x``,
# ``Y3dgs_lm = (-1)^m Y_lm``): the constants the kernels that evaluate Gaussian colours
# (``0.5 + SH(dir)``) use; numba freezes module-level floats and tuples at compile time.
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


def num_coeffs(degree: int) -> int:
    """``(degree + 1) ** 2``."""
    return (int(degree) + 1) ** 2


def degree_from_num_coeffs(k: int) -> int:
    """Inverse of :func:`num_coeffs`; ``ValueError`` if ``k`` is not a square."""
    d = int(round(math.sqrt(k))) - 1
    if d < 0 or (d + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients per channel is not (d+1)^2 for any degree d")
    return d


def _norm_table(max_degree: int) -> np.ndarray:
    """``norm[l, m] = K_lm`` (times sqrt(2) for m > 0), float64, shape (L+1, L+1)."""
    out = np.zeros((max_degree + 1, max_degree + 1), dtype=np.float64)
    for l in range(max_degree + 1):
        for m in range(l + 1):
            k = math.sqrt((2 * l + 1) / (4.0 * math.pi) * math.factorial(l - m) / math.factorial(l + m))
            out[l, m] = k * (math.sqrt(2.0) if m > 0 else 1.0)
    return out


NORM = _norm_table(MAX_DEGREE)


def band_of_index(degree: int) -> np.ndarray:
    """(K,) int array: band l of each coefficient index."""
    return np.concatenate([np.full(2 * l + 1, l, dtype=np.int64) for l in range(degree + 1)])


def order_of_index(degree: int) -> np.ndarray:
    """(K,) int array: order m of each coefficient index."""
    return np.concatenate([np.arange(-l, l + 1, dtype=np.int64) for l in range(degree + 1)])


def _recurrence_tables(max_degree: int) -> tuple[np.ndarray, np.ndarray]:
    """``RA[l, m] = (2l - 1) / (l - m)``, ``RB[l, m] = (l + m - 1) / (l - m)`` for l >= m + 2."""
    ra = np.zeros((max_degree + 1, max_degree + 1), dtype=np.float64)
    rb = np.zeros_like(ra)
    for l in range(max_degree + 1):
        for m in range(max(0, l - 1)):
            ra[l, m] = (2.0 * l - 1.0) / (l - m)
            rb[l, m] = (l + m - 1.0) / (l - m)
    return ra, rb


_RA, _RB = _recurrence_tables(MAX_DEGREE)


@njit(cache=True, fastmath=False)
def _store(out, l, m, p, cm, sm, norm):
    base = l * l + l
    if m == 0:
        out[base] = norm[l, 0] * p
    else:
        c = norm[l, m] * p
        out[base + m] = c * cm
        out[base - m] = c * sm


@njit(cache=True, fastmath=False)
def sh_eval_dir(x, y, z, degree, norm, out):
    """RH basis at one unit direction into ``out[:(degree+1)^2]`` (float64). No allocation.

    Recurrence on the polynomial part ``Pbar_l^m(z) = P_l^m(z) / sin^m t`` times
    ``Re/Im (x + i y)^m`` (= ``sin^m t cos/sin(m p)``), stable up to degree 8:
    ``Pbar_m^m = (2m-1)!!``, ``Pbar_{m+1}^m = (2m+1) z Pbar_m^m``,
    ``Pbar_l^m = ((2l-1) z Pbar_{l-1}^m - (l+m-1) Pbar_{l-2}^m) / (l-m)``.
    """
    cm = 1.0  # Re (x+iy)^m
    sm = 0.0  # Im (x+iy)^m
    pmm = 1.0  # Pbar_m^m = (2m-1)!!
    for m in range(degree + 1):
        if m > 0:
            pmm *= 2.0 * m - 1.0
            c_new = x * cm - y * sm
            sm = x * sm + y * cm
            cm = c_new
        _store(out, m, m, pmm, cm, sm, norm)
        if m < degree:
            p2 = pmm
            p1 = z * (2.0 * m + 1.0) * pmm
            _store(out, m + 1, m, p1, cm, sm, norm)
            for l in range(m + 2, degree + 1):
                p = _RA[l, m] * z * p1 - _RB[l, m] * p2
                p2 = p1
                p1 = p
                _store(out, l, m, p, cm, sm, norm)


@njit(cache=True, fastmath=False, inline="always")
def _times_x_plus_iy(x, y, cm, sm, g_n):
    """``cm + i sm <- (x + i y) (cm + i sm)`` for each of the G directions: Re and Im of the next
    power of ``x + i y`` (the azimuthal factor of the next order m)."""
    for g in range(g_n):
        c_new = x[g] * cm[g] - y[g] * sm[g]
        sm[g] = x[g] * sm[g] + y[g] * cm[g]
        cm[g] = c_new


@njit(cache=True, fastmath=False)
def sh_eval_batch(x, y, z, degree, norm, out, cm, sm, p1, p2):
    """RH basis for G directions at once (structure of arrays): ``out[k, g]`` (float64).

    x, y, z: (G,) unit-vector components; out: (>= (degree+1)^2, G); cm, sm, p1, p2: (G,)
    float64 scratch. Same recurrence as :func:`sh_eval_dir`, with the inner loops over the G
    directions (independent, SIMD-friendly) instead of one dependency chain per direction; the
    seed ``Pbar_{m+1}^m`` is grouped as ``z ((2m+1) Pbar_m^m)``, so values may differ from
    :func:`sh_eval_dir`'s in the last bit (:func:`sh_eval_dirs` keeps its grouping).
    """
    _sh_eval_columns(x, y, z, degree, norm, out, cm, sm, p1, p2, False)


@njit(cache=True, fastmath=False)
def sh_eval_dirs(x, y, z, degree, norm, out, cm, sm, p1, p2):
    """:func:`sh_eval_dir` of G directions, bit for bit: ``out[k, g]`` (float64) is its ``out[k]``
    for direction g (the same operations in the same order), with the inner loops over the G
    directions (they vectorise); arguments as :func:`sh_eval_batch`'s."""
    _sh_eval_columns(x, y, z, degree, norm, out, cm, sm, p1, p2, True)


@njit(cache=True, fastmath=False)
def _sh_eval_columns(x, y, z, degree, norm, out, cm, sm, p1, p2, seed_as_dir):
    """:func:`sh_eval_batch` (``seed_as_dir`` False) or :func:`sh_eval_dirs` (True)."""
    g_n = x.shape[0]
    cm[:g_n] = 1.0
    sm[:g_n] = 0.0
    pmm = 1.0
    for m in range(degree + 1):
        if m > 0:
            pmm *= 2.0 * m - 1.0
            _times_x_plus_iy(x, y, cm, sm, g_n)
        base = m * m + m
        nm = norm[m, m] * pmm
        if m == 0:
            for g in range(g_n):
                out[base, g] = nm
        else:
            for g in range(g_n):
                out[base + m, g] = nm * cm[g]
                out[base - m, g] = nm * sm[g]
        if m < degree:
            f = (2.0 * m + 1.0) * pmm
            base = (m + 1) * (m + 1) + (m + 1)
            nl = norm[m + 1, m]
            if seed_as_dir:  # (sh_eval_dir's grouping)
                for g in range(g_n):
                    p2[g] = pmm
                    p1[g] = z[g] * (2.0 * m + 1.0) * pmm
            else:
                for g in range(g_n):
                    p2[g] = pmm
                    p1[g] = z[g] * f
            if m == 0:
                for g in range(g_n):
                    out[base, g] = nl * p1[g]
            else:
                for g in range(g_n):
                    out[base + m, g] = nl * p1[g] * cm[g]
                    out[base - m, g] = nl * p1[g] * sm[g]
            for l in range(m + 2, degree + 1):
                ra = _RA[l, m]
                rb = _RB[l, m]
                nl = norm[l, m]
                base = l * l + l
                if m == 0:
                    for g in range(g_n):
                        p = ra * z[g] * p1[g] - rb * p2[g]
                        p2[g] = p1[g]
                        p1[g] = p
                        out[base, g] = nl * p
                else:
                    for g in range(g_n):
                        p = ra * z[g] * p1[g] - rb * p2[g]
                        p2[g] = p1[g]
                        p1[g] = p
                        out[base + m, g] = nl * p * cm[g]
                        out[base - m, g] = nl * p * sm[g]


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _eval_basis_kernel(dirs, degree, norm, out):
    for i in prange(dirs.shape[0]):
        sh_eval_dir(dirs[i, 0], dirs[i, 1], dirs[i, 2], degree, norm, out[i])


def _check_degree(degree: int) -> int:
    degree = int(degree)
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_DEGREE}, got {degree}")
    return degree


def eval_basis_rh(dirs: np.ndarray, degree: int) -> np.ndarray:
    """RH real SH basis at unit directions (numba, parallel).

    dirs: (..., 3) unit vectors (not re-normalised). Returns (..., (degree+1)^2) float64.
    """
    degree = _check_degree(degree)
    d = np.asarray(dirs, dtype=np.float64)
    flat = np.ascontiguousarray(d.reshape(-1, 3))
    out = np.empty((flat.shape[0], num_coeffs(degree)), dtype=np.float64)
    _eval_basis_kernel(flat, degree, NORM, out)
    return out.reshape(d.shape[:-1] + (num_coeffs(degree),))


def eval_basis_rh_numpy(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Same as :func:`eval_basis_rh`, vectorised numpy only (no numba compile)."""
    degree = _check_degree(degree)
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = np.empty(d.shape[:-1] + (num_coeffs(degree),), dtype=np.float64)
    cm = np.ones_like(x)
    sm = np.zeros_like(x)
    pmm = 1.0
    for m in range(degree + 1):
        if m > 0:
            pmm *= 2.0 * m - 1.0
            cm, sm = x * cm - y * sm, x * sm + y * cm
        p_lm2 = np.zeros_like(x)
        p_lm1 = np.full_like(x, pmm)
        for l in range(m, degree + 1):
            if l == m:
                p = np.full_like(x, pmm)
            elif l == m + 1:
                p = z * (2.0 * m + 1.0) * pmm
            else:
                p = ((2.0 * l - 1.0) * z * p_lm1 - (l + m - 1.0) * p_lm2) / (l - m)
            if l > m:
                p_lm2, p_lm1 = p_lm1, p
            base = l * l + l
            if m == 0:
                out[..., base] = NORM[l, 0] * p
            else:
                out[..., base + m] = NORM[l, m] * p * cm
                out[..., base - m] = NORM[l, m] * p * sm
    return out


def rh_3dgs_signs(degree: int) -> np.ndarray:
    """(K,) float64 signs ``(-1)^m`` with ``Y3dgs_k = sign_k * Yrh_k``; degree <= 3."""
    if not 0 <= int(degree) <= 3:
        raise ValueError(f"the 3DGS SH basis exists for degree 0..3 only, got {degree}")
    m = order_of_index(int(degree))
    return np.where(m % 2 == 0, 1.0, -1.0)


def rh_to_3dgs(coeffs: np.ndarray) -> np.ndarray:
    """Convert SH coefficients from the RH basis to the 3DGS basis (degree <= 3).

    coeffs: (..., K, C) or (K,) with K = (d+1)^2 on axis -2 (or the only axis for 1-D input).
    The function represented is unchanged: ``sum_k a_k Yrh_k == sum_k b_k Y3dgs_k``.
    Returns float64.
    """
    a = np.asarray(coeffs, dtype=np.float64)
    if a.ndim == 1:
        return a * rh_3dgs_signs(degree_from_num_coeffs(a.shape[0]))
    return a * rh_3dgs_signs(degree_from_num_coeffs(a.shape[-2]))[:, None]


def threedgs_to_rh(coeffs: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rh_to_3dgs` (the same sign flip; degree <= 3)."""
    return rh_to_3dgs(coeffs)


def legendre_lobe_integrals(q: float, degree: int) -> np.ndarray:
    """``I_l(q) = integral_0^1 t^q P_l(t) dt`` for l = 0..degree, exact (float64), q > -1.

    Closed form from ``int_0^1 x^mu P_nu(x) dx = sqrt(pi) 2^(-mu-1) Gamma(1+mu) /
    (Gamma(1+mu/2-nu/2) Gamma(mu/2+nu/2+3/2))``: ``I_0 = 1/(q+1)``, ``I_1 = 1/(q+2)``,
    ``I_{l+2} = I_l (q - l) / (q + l + 3)``.
    """
    q = float(q)
    if not q > -1.0 or not math.isfinite(q):
        raise ValueError(f"cosine lobe exponent q must be finite and > -1, got {q}")
    out = np.zeros(int(degree) + 1, dtype=np.float64)
    out[0] = 1.0 / (q + 1.0)
    if degree >= 1:
        out[1] = 1.0 / (q + 2.0)
    for l in range(0, int(degree) - 1):
        out[l + 2] = out[l] * (q - l) / (q + l + 3.0)
    return out


def cosine_lobe_band_factors(q: float, degree: int) -> np.ndarray:
    """Funk-Hecke band factors of the lobe ``S(w, n) = max(0, <w, n>)^q``.

    Returns (degree+1,) float64 ``A_l = 2 pi I_l(q)`` such that for any band-limited
    ``L(w) = sum_lm L_lm Y_lm(w)``: ``integral L(w) S(w, n) dw = sum_lm A_l L_lm Y_lm(n)``.
    ``A_l = sqrt(4 pi / (2l+1)) g_l`` with ``g_l`` the zonal (Y_l0) coefficients of S.
    ``A_0 = 2 pi / (q+1) = integral S dw``. For q = 1: pi, 2 pi/3, pi/4, 0, -pi/24, ...
    """
    return 2.0 * math.pi * legendre_lobe_integrals(q, degree)
