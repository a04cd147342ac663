"""SH environment probe from cube-face renders: weighted ridge least squares (paper eq. 7).

Given N samples with unit directions ``D`` (N, 3), radiance ``Y`` (N, 3) (linear RGB, the
values the rasteriser writes into the cube faces) and per-sample solid angles ``w`` (N,)
in steradians, the probe coefficients ``A`` (K, 3), K = (d+1)^2, in the **RH** real SH basis
(``numba_kernels.sh_real``) solve

    (B^T W B + lam I) A = B^T W Y,     B[n, k] = Y_k(D_n),  W = diag(w).

With exact texel solid angles ``B^T W B`` is close to the identity (a quadrature of the
orthonormality integral), so ``lam`` is a relative shrinkage (``A ~ A_proj / (1 + lam)``).

Two paths:

- :func:`normal_equations` (numba, parallel over chunks of samples) builds
  ``B^T W B`` and ``B^T W Y`` without storing B; :func:`fit_sh_lstsq` solves them. Use it for
  arbitrary direction sets and weights (masks).
- :class:`CubeProbeFitter` precomputes, once per (face size, degree, lam), the fit operator
  ``P = (B^T W B + lam I)^-1 B^T W`` (K, 6*S*S); a fit is then one matrix product ``P @ Y``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .cubemap_dirs import cube_face_directions, cube_face_solid_angles
from .jit_options import prange_only
from .sh_real import MAX_DEGREE, NORM, num_coeffs, sh_eval_dir

_CHUNK = 1024


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _normal_equations_kernel(dirs, weights, values, degree, norm, gram_parts, rhs_parts):
    n = dirs.shape[0]
    k = (degree + 1) * (degree + 1)
    nc = values.shape[1]
    n_chunks = gram_parts.shape[0]
    for c in prange(n_chunks):
        b = np.empty(k, dtype=np.float64)
        g = gram_parts[c]
        r = rhs_parts[c]
        start = c * _CHUNK
        stop = min(n, start + _CHUNK)
        for i in range(start, stop):
            wi = weights[i]
            if wi == 0.0:
                continue
            sh_eval_dir(dirs[i, 0], dirs[i, 1], dirs[i, 2], degree, norm, b)
            for a in range(k):
                wba = wi * b[a]
                for bb in range(a, k):
                    g[a, bb] += wba * b[bb]
                for ch in range(nc):
                    r[a, ch] += wba * values[i, ch]


def normal_equations(dirs: np.ndarray, weights: np.ndarray, values: np.ndarray, degree: int):
    """``(B^T W B, B^T W Y)`` in float64 for the RH basis of ``degree``.

    dirs (N, 3) unit vectors, weights (N,) >= 0 (steradians), values (N, C).
    Returns gram (K, K) symmetric and rhs (K, C).
    """
    if not 0 <= int(degree) <= MAX_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_DEGREE}, got {degree}")
    dirs = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    weights = np.ascontiguousarray(weights, dtype=np.float64).reshape(-1)
    values = np.ascontiguousarray(values, dtype=np.float64).reshape(dirs.shape[0], -1)
    if weights.shape[0] != dirs.shape[0]:
        raise ValueError(f"{weights.shape[0]} weights for {dirs.shape[0]} directions")
    k = num_coeffs(degree)
    n_chunks = max(1, -(-dirs.shape[0] // _CHUNK))
    gram_parts = np.zeros((n_chunks, k, k), dtype=np.float64)
    rhs_parts = np.zeros((n_chunks, k, values.shape[1]), dtype=np.float64)
    _normal_equations_kernel(dirs, weights, values, int(degree), NORM, gram_parts, rhs_parts)
    gram = gram_parts.sum(axis=0)
    gram = np.triu(gram) + np.triu(gram, 1).T
    return gram, rhs_parts.sum(axis=0)


def fit_sh_lstsq(dirs, weights, values, degree: int, lam: float = 1e-3) -> np.ndarray:
    """Eq. 7 for arbitrary samples: (K, C) float64 RH coefficients."""
    if not lam >= 0.0:
        raise ValueError(f"ridge lambda must be >= 0, got {lam}")
    gram, rhs = normal_equations(dirs, weights, values, degree)
    gram[np.diag_indices_from(gram)] += lam
    return np.linalg.solve(gram, rhs)


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _apply_operator(op, y, out):
    """``out = op @ y`` for op (K, N) float64 and y (N, C) float32/64, float64 accumulation."""
    k, n = op.shape
    nc = y.shape[1]
    for a in prange(k):
        for c in range(nc):
            out[a, c] = 0.0
        for i in range(n):
            w = op[a, i]
            for c in range(nc):
                out[a, c] += w * y[i, c]


class CubeProbeFitter:
    """Cached eq. 7 solver for cube faces of one size.

    ``fit(faces)`` with faces (6, size, size, C) (cube convention of
    ``numba_kernels.cubemap_dirs``) returns (K, C) float64 RH coefficients. Set-up cost
    (building the operator) is paid once per instance.
    """

    def __init__(self, size: int, degree: int = 3, lam: float = 1e-3):
        if not 0 <= int(degree) <= MAX_DEGREE:
            raise ValueError(f"SH degree must be 0..{MAX_DEGREE}, got {degree}")
        if not lam >= 0.0:
            raise ValueError(f"ridge lambda must be >= 0, got {lam}")
        self.size = int(size)
        self.degree = int(degree)
        self.lam = float(lam)
        dirs = cube_face_directions(self.size).reshape(-1, 3)
        w = cube_face_solid_angles(self.size).reshape(-1)
        from .sh_real import eval_basis_rh

        basis = eval_basis_rh(dirs, self.degree)  # (N, K)
        gram, _ = normal_equations(dirs, w, np.zeros((dirs.shape[0], 1)), self.degree)
        gram[np.diag_indices_from(gram)] += self.lam
        self.operator = np.ascontiguousarray(np.linalg.solve(gram, (basis * w[:, None]).T))  # (K, N)

    def fit(self, faces: np.ndarray) -> np.ndarray:
        f = np.asarray(faces)
        if f.shape[:3] != (6, self.size, self.size):
            raise ValueError(f"cube faces must have shape (6, {self.size}, {self.size}, C), got {f.shape}")
        y = np.ascontiguousarray(f.reshape(6 * self.size * self.size, -1))
        if y.dtype != np.float32:
            y = y.astype(np.float64, copy=False)
        out = np.empty((self.operator.shape[0], y.shape[1]), dtype=np.float64)
        _apply_operator(self.operator, y, out)
        return out
