"""Spherical harmonics in the 3DGS basis (graphdeco-inria ``sh_utils.py``), degree 0..3.

Convention (shared/DESIGN.md section 1): a Gaussian's colour seen along unit direction
``d = (x, y, z)`` (from the camera toward the Gaussian, world space) is
``0.5 + sum_k c_k * Y_k(d)`` where coefficient index ``k`` runs over
``(l, m)`` in the order l=0; l=1: m=-1,0,1; l=2: m=-2..2; l=3: m=-3..3, and the
signs of the basis functions are those of the 3DGS code (band 1 is
``-C1*y, +C1*z, -C1*x``). This is *not* the Sloan / Ramamoorthi-Hanrahan sign
convention; code that mixes them must convert explicitly.

Also: exact per-band rotation (or reflection) of 3DGS SH coefficients, computed by a
least-squares fit on sample directions, which is exact for band-limited functions.
"""

from __future__ import annotations

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
      -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
      0.3731763325901154, -0.4570457994644658, 1.445305721320277,
      -0.5900435899266435)

MAX_DEGREE = 3


def num_coeffs(degree: int) -> int:
    """Number of SH coefficients per channel, ``(degree + 1) ** 2``."""
    return (int(degree) + 1) ** 2


def degree_from_num_coeffs(k: int) -> int:
    """Inverse of :func:`num_coeffs`; raises ``ValueError`` if ``k`` is not a square."""
    d = int(round(np.sqrt(k))) - 1
    if d < 0 or (d + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients per channel is not (d+1)^2 for any degree d")
    return d


def eval_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """3DGS real SH basis at unit directions.

    dirs: (..., 3) unit vectors (float32 or float64). Returns (..., (degree+1)^2) float64.
    """
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_DEGREE}, got {degree}")
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = np.empty(d.shape[:-1] + (num_coeffs(degree),), dtype=np.float64)
    out[..., 0] = C0
    if degree >= 1:
        out[..., 1] = -C1 * y
        out[..., 2] = C1 * z
        out[..., 3] = -C1 * x
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out[..., 4] = C2[0] * xy
        out[..., 5] = C2[1] * yz
        out[..., 6] = C2[2] * (2.0 * zz - xx - yy)
        out[..., 7] = C2[3] * xz
        out[..., 8] = C2[4] * (xx - yy)
    if degree >= 3:
        out[..., 9] = C3[0] * y * (3 * xx - yy)
        out[..., 10] = C3[1] * xy * z
        out[..., 11] = C3[2] * y * (4 * zz - xx - yy)
        out[..., 12] = C3[3] * z * (2 * zz - 3 * xx - 3 * yy)
        out[..., 13] = C3[4] * x * (4 * zz - xx - yy)
        out[..., 14] = C3[5] * z * (xx - yy)
        out[..., 15] = C3[6] * x * (xx - 3 * yy)
    return out


def eval_color(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """RGB colour ``0.5 + SH(dir)`` (unclamped) for each Gaussian.

    sh: (N, K, 3) coefficients in the 3DGS basis; dirs: (N, 3) or (3,) unit directions.
    Returns (N, 3) float64.
    """
    sh = np.asarray(sh)
    degree = degree_from_num_coeffs(sh.shape[1])
    basis = eval_basis(np.broadcast_to(dirs, (sh.shape[0], 3)), degree)
    return 0.5 + np.einsum("nk,nkc->nc", basis, sh.astype(np.float64))


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def rotation_matrices_per_band(q: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per-band matrices that carry 3DGS SH coefficients through an orthogonal map.

    q: (3, 3) orthogonal matrix (rotation or reflection) acting on column vectors,
    world = q @ local. Returns ``[D_0, ..., D_degree]`` with ``D_l`` of shape
    (2l+1, 2l+1) such that new band-l coefficients are ``D_l @ old`` and the new
    expansion at world direction ``w`` equals the old one at ``q.T @ w``.
    Exact up to float64 round-off (each band is closed under rotation).
    """
    q = np.asarray(q, dtype=np.float64)
    dirs = _fibonacci_sphere(64)
    y_world = eval_basis(dirs, degree)
    y_local = eval_basis(dirs @ q, degree)  # row w -> (q^T w)^T = w^T q
    mats = []
    for band in range(degree + 1):
        s = slice(band * band, (band + 1) * (band + 1))
        mats.append(np.linalg.lstsq(y_world[:, s], y_local[:, s], rcond=None)[0])
    return mats


def rotate_coefficients(sh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Apply an orthogonal map ``q`` (3x3, column-vector convention) to SH coefficients.

    sh: (N, K, 3) float32 in the 3DGS basis. Returns a new float32 array; band 0 is
    unchanged. See :func:`rotation_matrices_per_band`.
    """
    sh = np.asarray(sh)
    degree = degree_from_num_coeffs(sh.shape[1])
    out = sh.copy()
    if degree == 0 or np.array_equal(np.asarray(q, np.float64), np.eye(3)):
        return out  # (the identity: every band's matrix is the identity)
    n = sh.shape[0]
    for band, mat in enumerate(rotation_matrices_per_band(q, degree)):
        if band == 0:
            continue
        s = slice(band * band, (band + 1) * (band + 1))
        k = mat.shape[0]
        # one (k, k) @ (k, 3N) product per band (BLAS), not N small ones
        x = np.ascontiguousarray(sh[:, s, :].transpose(1, 0, 2), dtype=np.float64).reshape(k, 3 * n)
        out[:, s, :] = (mat @ x).reshape(k, n, 3).transpose(1, 0, 2)
    return out
