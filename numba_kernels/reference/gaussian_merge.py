"""Reference of :mod:`numba_kernels.gaussian_merge` (tests only): the same clusters and moments as
numpy expressions (``np.unique`` cells, ``np.bincount`` sums, ``np.linalg.eigh``), in float64."""

from __future__ import annotations

import numpy as np


def _area(s: np.ndarray) -> np.ndarray:
    return (s[:, 0] * s[:, 1] + s[:, 1] * s[:, 2] + s[:, 0] * s[:, 2]) / 3.0


def _rotations(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)


def merge_cells(positions, quaternions, scales, opacities, sh, cell: float):
    """``(labels (N,), centres (M, 3), covariances (M, 3, 3), opacities (M,), sh (M, K, 3))`` in float64
    (covariances instead of the kernel's quaternions and sigmas, which are its eigen-decomposition)."""
    p = np.asarray(positions, np.float32).astype(np.float64)
    lo = p.min(axis=0)
    dims = np.floor((p.max(axis=0) - lo) / cell).astype(np.int64) + 1
    idx = np.clip(np.floor((p - lo) * (1.0 / cell)).astype(np.int64), 0, dims - 1)
    lin = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
    _, labels = np.unique(lin, return_inverse=True)
    labels = labels.reshape(-1)
    m = int(labels.max()) + 1
    s = np.asarray(scales, np.float64)
    w = np.asarray(opacities, np.float64) * _area(s)
    wsum = np.bincount(labels, w, m)
    plain = wsum <= 0.0
    w = np.where(plain[labels], 1.0, w)
    wsum = np.bincount(labels, w, m)
    mu = np.stack([np.bincount(labels, w * p[:, k], m) for k in range(3)], 1) / wsum[:, None]
    r = _rotations(quaternions)
    cov_i = np.einsum("nij,nj,nkj->nik", r, s * s, r)
    d = p - mu[labels]
    second = cov_i + d[:, :, None] * d[:, None, :]
    cov = np.stack([np.bincount(labels, w * second[:, a, b], m) for a in range(3) for b in range(3)], 1)
    cov = cov.reshape(m, 3, 3) / wsum[:, None, None]
    lam = np.maximum(np.linalg.eigvalsh(cov), 1e-30)
    sig = np.sqrt(lam)
    opac = np.where(plain, 0.0, np.minimum(1.0, np.bincount(labels, np.where(plain[labels], 0.0, w), m) / _area(sig)))
    shs = np.asarray(sh, np.float64)
    out_sh = np.stack([np.bincount(labels, w * shs[:, j, c], m) for j in range(shs.shape[1]) for c in range(3)], 1)
    return labels, mu, cov, opac, out_sh.reshape(m, shs.shape[1], 3) / wsum[:, None, None]
