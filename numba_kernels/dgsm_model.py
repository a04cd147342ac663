"""The absorption model of Deep Gaussian Shadow Maps (paper sec. 3.2, eqs. 1-5).

Absorption field (eq. 1): ``sigma(x) = sum_i beta_i exp(-1/2 (x - mu_i)^T A_i (x - mu_i))``
with ``A_i = Sigma_i^-1`` (precision, 1/m^2) and ``beta_i`` in 1/m. Along a ray
``r(s) = o + s d`` (``|d| = 1``, ``s`` in metres) one Gaussian contributes (eqs. 2-3)::

    int_{t0}^{t1} exp(-1/2 (a s^2 + 2 b s + c)) ds
        = sqrt(pi / (2a)) exp(-m2 / 2) [erf(z(t1)) - erf(z(t0))],
    a = d^T A d,  b = d^T A (o - mu),  c = (o - mu)^T A (o - mu),
    m2 = c - b^2 / a,  z(t) = sqrt(a/2) (t + b/a).

``m2`` is the squared Mahalanobis distance from ``mu`` to the closest point of the (infinite)
line. It is computed as ``w^T A w`` with ``w = (o - mu) - (b/a) d`` (the residual at the
closest point), not as ``c - b^2/a``, so it does not cancel when ``c`` and ``b^2/a`` are huge
(light or receiver far away in Mahalanobis units). The erf difference uses
``erf_stable.erf_diff``. Transmittance is ``exp(-tau)`` (eq. 4).

Opacity -> absorption (eq. 5 and ablation B of sec. 4.4), ``tau* = -ln(1 - alpha)``:

- ``avg``    (eq. 5, default):  ``beta = kappa tau* sqrt(tr(A)/3) / sqrt(2 pi)``
- ``simple`` (ablation B.1):    ``beta = kappa tau*``
- ``mass``   (ablation B.3/B.4): ``beta = kappa tau* / ((2 pi)^(3/2) sqrt(det Sigma))``
  ``= kappa tau* sqrt(det A) / (2 pi)^(3/2)``: the Gaussian's integral over R^3 is ``kappa tau*``.
  Ablation B.4 (``s_x s_y s_z`` instead of ``sqrt(det Sigma)``) is the same number for
  ``Sigma = R diag(s)^2 R^T``, so it is not a separate option.
- ``diag``   (direction dependent, exact calibration): ``beta = kappa tau* sqrt(a) / sqrt(2 pi)``
  with ``a = d^T A d`` of the actual ray, so a ray through the centre, integrated over the
  whole line, sees exactly ``kappa tau*`` whatever the shape (eq. 5 replaces ``a`` by the
  direction-agnostic ``tr(A)/3``).

Far pairs: when the closest approach of a ray is more than ``sqrt(M2_CUT) = 14.1`` Mahalanobis
units from a Gaussian's centre its depth on that ray, below ``4e-44 beta sqrt(2 pi / a)``, is
taken as 0 (well under float64 resolution of any transmittance that matters).

numba cache caveat: ``ray_params`` / ``segment_depth`` (and their parts ``light_offset``,
``ray_params_from``, ``depth_from_offset``) are compiled into the kernels of
``dgsm_exact``, ``dgsm_build``, ``dgsm_sample``, ``dgsm_directional`` and ``cubemap``;
numba's ``cache=True`` keys each kernel on its own file only, so after editing this file
delete ``numba_kernels/__pycache__/*.nb[ic]`` or those kernels keep the old code.

Opacity clamp: ``alpha`` is clamped to ``[0, ALPHA_MAX]`` with ``ALPHA_MAX = 1 - 1e-7``,
i.e. ``tau* <= TAU_STAR_MAX = 16.118``; ``alpha = 1`` exactly would give ``tau* = inf``.

Packed occluder layout (float64, C-contiguous, shape (N, 16)), produced by
``pack_gaussians`` / ``pack_occluders``: columns 0-2 ``mu``; 3-11 the rotation ``R``
row-major (columns of ``R`` are the local axes, world = R local); 12-14 ``1/s`` (inverse
standard deviations, so ``A = R diag(1/s^2) R^T``); 15 the amplitude ``amp`` (``beta`` for
avg/simple/mass, ``kappa tau* / sqrt(2 pi)`` for diag). The flag ``dir_dep`` (1 for ``diag``,
else 0) travels separately. Every quadratic form is evaluated in the whitened local frame
(``delta = diag(1/s) R^T d``, ``rho = diag(1/s) R^T (o - mu)``: ``a = |delta|^2``,
``b = rho . delta``, ``m2 = |rho - (b/a) delta|^2``): sums of squares, so anisotropy 1e6
(entries of ``A`` up to 1e12) does not cancel the way ``w^T A w`` in world axes would.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .erf_stable import erf_diff_nonneg
from .jit_options import threaded
from .quaternion import quat_to_rotation
from .thread_chunks import run_chunks

ALPHA_MAX = 1.0 - 1e-7
TAU_STAR_MAX = -math.log1p(-ALPHA_MAX)
MAPPINGS = ("avg", "simple", "mass", "diag")
M2_CUT = 200.0
SQRT_2PI = math.sqrt(2.0 * math.pi)
SQRT_PI_2 = math.sqrt(0.5 * math.pi)


def _check_finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = int(np.flatnonzero(bad.reshape(arr.shape[0], -1).any(axis=1))[0]) if arr.ndim else 0
        raise ValueError(f"'{name}' element {idx} is not finite (value {np.asarray(arr)[idx]})")


def check_points(name: str, pts) -> np.ndarray:
    """Return ``pts`` as a C-contiguous (M, 3) float64 array; ValueError naming the first
    non-finite element otherwise."""
    p = np.ascontiguousarray(np.asarray(pts, dtype=np.float64))
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"'{name}' must have shape (M, 3), got {p.shape}")
    _check_finite(name, p)
    return p


def check_vector(name: str, v) -> np.ndarray:
    """(3,) finite float64 vector or ValueError naming it."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"'{name}' must have 3 components, got shape {np.shape(v)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"'{name}' component {int(np.flatnonzero(~np.isfinite(a))[0])} is not finite ({a})")
    return a


def tau_star(alpha) -> np.ndarray:
    """``-ln(1 - alpha)`` with alpha clamped to ``[0, ALPHA_MAX]`` (float64)."""
    a = np.clip(np.asarray(alpha, dtype=np.float64), 0.0, ALPHA_MAX)
    return -np.log1p(-a)


def pack_occluders(mu, prec, alpha, kappa: float = 1.0, mapping: str = "avg", det_prec=None):
    """Validate and pack occluders for the kernels.

    mu: (N, 3) centres in metres; prec: (N, 3, 3) precision matrices ``Sigma^-1`` (1/m^2,
    symmetric positive definite); alpha: (N,) opacity in [0, 1]; kappa: global strength;
    mapping: one of ``MAPPINGS``; det_prec: optional (N,) ``det A`` (pass ``prod(s)^-2``
    from the scales to avoid the cancellation of a 3x3 determinant at anisotropy 1e6;
    only used by ``mass``).
    Returns ``(occ (N, 16) float64, dir_dep int)``. Raises ValueError naming the field and
    the first bad element for NaN/Inf, opacity outside [0, 1] or a non-positive diagonal.
    """
    if mapping not in MAPPINGS:
        raise ValueError(f"unknown opacity->absorption mapping {mapping!r}; expected one of {MAPPINGS}")
    if not (np.isfinite(kappa) and kappa >= 0):
        raise ValueError(f"kappa must be finite and >= 0, got {kappa}")
    mu = check_points("occluder positions", mu)
    n = mu.shape[0]
    A = np.asarray(prec, dtype=np.float64)
    if A.shape != (n, 3, 3):
        raise ValueError(f"'occluder precisions' must have shape ({n}, 3, 3), got {A.shape}")
    _check_finite("occluder precisions", A)
    alpha = np.asarray(alpha, dtype=np.float64).reshape(-1)
    if alpha.shape != (n,):
        raise ValueError(f"'occluder opacities' must have shape ({n},), got {alpha.shape}")
    _check_finite("occluder opacities", alpha)
    bad = (alpha < 0) | (alpha > 1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"'occluder opacities' element {i} is outside [0, 1] (value {alpha[i]})")
    diag = np.stack([A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]], axis=1)
    bad = ~(diag > 0).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"'occluder precisions' element {i} is not positive definite (diagonal {diag[i]})")
    ts = kappa * tau_star(alpha)
    Asym = 0.5 * (A + np.transpose(A, (0, 2, 1)))
    lam, R = np.linalg.eigh(Asym)
    if n and not (lam > 0).all():
        i = int(np.flatnonzero(~(lam > 0).all(axis=1))[0])
        raise ValueError(f"'occluder precisions' element {i} is not positive definite (eigenvalues {lam[i]})")
    if mapping == "avg":
        amp = ts * np.sqrt(diag.sum(axis=1) / 3.0) / SQRT_2PI
    elif mapping == "simple":
        amp = ts
    elif mapping == "mass":
        det = np.prod(lam, axis=1) if det_prec is None else np.asarray(det_prec, dtype=np.float64).reshape(n)
        amp = ts * np.sqrt(np.maximum(det, 0.0)) / (2.0 * np.pi) ** 1.5
    else:  # diag
        amp = ts / SQRT_2PI
    occ = np.empty((n, 16), np.float64)
    occ[:, 0:3] = mu
    occ[:, 3:12] = R.reshape(n, 9)
    occ[:, 12:15] = np.sqrt(lam)
    occ[:, 15] = amp
    return occ, int(mapping == "diag")


@njit(cache=True, fastmath=False, inline="always")
def light_offset(occ, i, ox, oy, oz):
    """Occluder i's whitened offset of the ray origin ``o``: ``rho = diag(1/s) R^T (o - mu)``, the
    part of :func:`ray_params` that does not depend on the direction (a kernel that casts many rays
    from one origin computes it once per occluder: the same values)."""
    rx = ox - occ[i, 0]
    ry = oy - occ[i, 1]
    rz = oz - occ[i, 2]
    p0 = (occ[i, 3] * rx + occ[i, 6] * ry + occ[i, 9] * rz) * occ[i, 12]
    p1 = (occ[i, 4] * rx + occ[i, 7] * ry + occ[i, 10] * rz) * occ[i, 13]
    p2 = (occ[i, 5] * rx + occ[i, 8] * ry + occ[i, 11] * rz) * occ[i, 14]
    return p0, p1, p2


@njit(cache=True, fastmath=False, inline="always")
def ray_params_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep):
    """:func:`ray_params` from the occluder's :func:`light_offset` ``(p0, p1, p2)``."""
    # whitened local coordinates: delta = diag(1/s) R^T d, rho = diag(1/s) R^T r
    i0 = occ[i, 12]
    i1 = occ[i, 13]
    i2 = occ[i, 14]
    d0 = (occ[i, 3] * dx + occ[i, 6] * dy + occ[i, 9] * dz) * i0
    d1 = (occ[i, 4] * dx + occ[i, 7] * dy + occ[i, 10] * dz) * i1
    d2 = (occ[i, 5] * dx + occ[i, 8] * dy + occ[i, 11] * dz) * i2
    a = d0 * d0 + d1 * d1 + d2 * d2
    if not (a > 0.0):
        return 0.0, 0.0, 1.0
    b = p0 * d0 + p1 * d1 + p2 * d2
    s_star = -b / a
    w0 = p0 + s_star * d0
    w1 = p1 + s_star * d1
    w2 = p2 + s_star * d2
    m2 = w0 * w0 + w1 * w1 + w2 * w2
    if m2 > M2_CUT:  # exp(-m2/2) < 4e-44: skip (also avoids libm's slow underflow path)
        return 0.0, s_star, 1.0
    amp = occ[i, 15]
    if dir_dep:
        pref = amp * SQRT_PI_2
    else:
        pref = amp * math.sqrt(0.5 * math.pi / a)
    return pref * math.exp(-0.5 * m2), s_star, math.sqrt(0.5 * a)


@njit(cache=True, fastmath=False, inline="always")
def ray_params(occ, i, ox, oy, oz, dx, dy, dz, dir_dep):
    """Per (ray, occluder) constants: returns ``(scale, s_star, sq)`` such that the optical
    depth between ``t0 <= t1`` is ``scale * erf_diff(sq (t0 - s_star), sq (t1 - s_star))``.
    ``scale = beta sqrt(pi/(2a)) exp(-m2/2)`` (0 when it underflows), ``s_star = -b/a`` is the
    closest-approach parameter and ``sq = sqrt(a/2)``."""
    p0, p1, p2 = light_offset(occ, i, ox, oy, oz)
    return ray_params_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep)


@njit(cache=True, fastmath=False)
def segment_depth(occ, i, ox, oy, oz, dx, dy, dz, t0, t1, dir_dep):
    """Optical depth of occluder ``i`` along ``o + s d`` for ``s`` in ``[t0, t1]`` (eq. 3,
    stable form). ``t0`` may be ``-inf`` (directional light)."""
    scale, s_star, sq = ray_params(occ, i, ox, oy, oz, dx, dy, dz, dir_dep)
    if scale == 0.0:
        return 0.0
    return scale * erf_diff_nonneg(sq * (t0 - s_star), sq * (t1 - s_star))


#: |z| beyond which erf(z) = +-1 to double precision (erfc(6) = 2.2e-17)
Z_SATURATED = 6.0


@njit(cache=True, fastmath=False, inline="always")
def depth_from_light(occ, i, ox, oy, oz, dx, dy, dz, t1, dir_dep):
    """``segment_depth`` from the light (``t0 = 0``) to ``t1``, with one erfc or none in the
    common cases: when the light lies before occluder i's saturated support along the ray
    (``z0 <= -Z_SATURATED``) the depth is ``scale * erfc(-z1)`` (``scale * 2`` once ``z1`` saturates
    too), and when ``t1`` lies before the support or the light past it the depth is 0. Each
    shortcut drops less than ``scale * 2.2e-17``."""
    p0, p1, p2 = light_offset(occ, i, ox, oy, oz)
    return depth_from_offset(occ, i, p0, p1, p2, dx, dy, dz, t1, dir_dep)


@njit(cache=True, fastmath=False, inline="always")
def depth_from_offset(occ, i, p0, p1, p2, dx, dy, dz, t1, dir_dep):
    """:func:`depth_from_light` from the occluder's :func:`light_offset` ``(p0, p1, p2)``."""
    scale, s_star, sq = ray_params_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep)
    if scale == 0.0:
        return 0.0
    z0 = -sq * s_star
    z1 = sq * (t1 - s_star)
    if z1 <= -Z_SATURATED or z0 >= Z_SATURATED:
        return 0.0
    if z0 <= -Z_SATURATED:
        return 2.0 * scale if z1 >= Z_SATURATED else scale * math.erfc(-z1)
    return scale * erf_diff_nonneg(z0, z1)


# the same function as an ordinary call, for the rarely taken loops of a kernel: each inlined call
# site is another copy of the body to type and optimise (compile time)
depth_from_light_call = njit(cache=True, fastmath=False)(depth_from_light.py_func)

MAPPING_CODES = {"avg": 0, "simple": 1, "mass": 2, "diag": 3}


@njit(cache=True, **threaded(), fastmath=False)
def _pack_gaussians(i0_, i1_, pos, quat, scales, alpha, kappa, code, occ, cov6):
    two_pi_15 = (2.0 * math.pi) ** 1.5
    for n in range(i0_, i1_):
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(
            float(quat[n, 0]), float(quat[n, 1]), float(quat[n, 2]), float(quat[n, 3]))
        s0 = float(scales[n, 0]) ** 2
        s1 = float(scales[n, 1]) ** 2
        s2 = float(scales[n, 2]) ** 2
        i0, i1, i2 = 1.0 / s0, 1.0 / s1, 1.0 / s2
        # packed: mu, R row-major, 1/s; Sigma = R diag(s^2) R^T for culling
        occ[n, 0] = pos[n, 0]
        occ[n, 1] = pos[n, 1]
        occ[n, 2] = pos[n, 2]
        occ[n, 3], occ[n, 4], occ[n, 5] = r00, r01, r02
        occ[n, 6], occ[n, 7], occ[n, 8] = r10, r11, r12
        occ[n, 9], occ[n, 10], occ[n, 11] = r20, r21, r22
        occ[n, 12] = 1.0 / float(scales[n, 0])
        occ[n, 13] = 1.0 / float(scales[n, 1])
        occ[n, 14] = 1.0 / float(scales[n, 2])
        cov6[n, 0] = r00 * r00 * s0 + r01 * r01 * s1 + r02 * r02 * s2
        cov6[n, 1] = r00 * r10 * s0 + r01 * r11 * s1 + r02 * r12 * s2
        cov6[n, 2] = r00 * r20 * s0 + r01 * r21 * s1 + r02 * r22 * s2
        cov6[n, 3] = r10 * r10 * s0 + r11 * r11 * s1 + r12 * r12 * s2
        cov6[n, 4] = r10 * r20 * s0 + r11 * r21 * s1 + r12 * r22 * s2
        cov6[n, 5] = r20 * r20 * s0 + r21 * r21 * s1 + r22 * r22 * s2
        a = min(max(float(alpha[n]), 0.0), ALPHA_MAX)
        ts = kappa * -math.log1p(-a)
        if code == 0:
            amp = ts * math.sqrt((i0 + i1 + i2) / 3.0) / SQRT_2PI
        elif code == 1:
            amp = ts
        elif code == 2:
            amp = ts * math.sqrt(i0 * i1 * i2) / two_pi_15
        else:
            amp = ts / SQRT_2PI
        occ[n, 15] = amp


def pack_gaussians(positions, quaternions, scales, opacities, kappa: float = 1.0, mapping: str = "avg", out=None):
    """Fast packing straight from 3DGS parameters (one parallel pass, no 3x3 inverses).

    positions (N, 3) m; quaternions (N, 4) (w, x, y, z), normalised here (zero -> identity);
    scales (N, 3) sigma in m (> 0); opacities (N,) in [0, 1]. Same output and mappings as
    ``pack_occluders`` (``mass`` uses ``det A = prod(s)^-2`` exactly), plus ``cov6`` (N, 6)
    covariances (xx, xy, xz, yy, yz, zz) for culling. Returns ``(occ, dir_dep, cov6)``;
    ValueError naming the field and first bad element for NaN/Inf, scales <= 0 or
    opacities outside [0, 1]. ``out``: ``(occ, cov6)`` float64 C-contiguous arrays of these shapes
    to write into (a caller packing a moving caster every frame: a fresh buffer costs its page
    faults, more than the packing itself), else new ones.
    """
    if mapping not in MAPPINGS:
        raise ValueError(f"unknown opacity->absorption mapping {mapping!r}; expected one of {MAPPINGS}")
    if not (np.isfinite(kappa) and kappa >= 0):
        raise ValueError(f"kappa must be finite and >= 0, got {kappa}")
    # one float64 specialisation of the kernel (float32 storage is widened here; N x 11 values)
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    quat = np.ascontiguousarray(quaternions, dtype=np.float64)
    sc = np.ascontiguousarray(scales, dtype=np.float64)
    op = np.ascontiguousarray(opacities, dtype=np.float64).reshape(-1)
    n = pos.shape[0]
    for name, arr, tail in (("positions", pos, (3,)), ("orientations", quat, (4,)), ("scales", sc, (3,)),
                            ("opacities", op, ())):
        if arr.shape != (n, *tail):
            raise ValueError(f"'{name}' must have shape {(n, *tail)}, got {arr.shape}")
        if not np.isfinite(arr).all():
            _check_finite(name, arr)
    if n and not (sc > 0).all():
        i = int(np.flatnonzero(~(sc > 0).all(axis=1))[0])
        raise ValueError(f"'scales' element {i} is not > 0 (value {sc[i]})")
    if n and not ((op >= 0) & (op <= 1)).all():
        i = int(np.flatnonzero(~((op >= 0) & (op <= 1)))[0])
        raise ValueError(f"'opacities' element {i} is outside [0, 1] (value {op[i]})")
    ok = (out is not None and all(isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous
                                  for a in out) and out[0].shape == (n, 16) and out[1].shape == (n, 6))
    occ, cov6 = out if ok else (np.empty((n, 16), np.float64), np.empty((n, 6), np.float64))
    run_chunks(_pack_gaussians, pos.shape[0], pos, quat, sc, op, float(kappa), MAPPING_CODES[mapping], occ, cov6,
               min_chunk=1024)
    return occ, int(mapping == "diag"), cov6
