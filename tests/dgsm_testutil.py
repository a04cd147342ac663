"""Shared helpers for the DGSM tests (small generated occluder sets)."""

from __future__ import annotations

import numpy as np

from numba_kernels.dgsm_model import pack_gaussians


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quat_to_mat(q):
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def precisions(q, s):
    r = quat_to_mat(np.asarray(q, np.float64))
    return np.einsum("nij,nj,nkj->nik", r, 1.0 / np.asarray(s, np.float64) ** 2, r)


def random_occluders(rng, n, centre=(0.0, 0.0, 0.0), spread=0.3, log_s=(-4.0, -2.0), alpha=(0.2, 1.0),
                     mapping="avg", kappa=1.0):
    """Positions, quats, scales, opacities and the packed (occ, dir_dep, cov6) of n random Gaussians."""
    mu = np.asarray(centre) + rng.normal(size=(n, 3)) * spread
    q = random_rotations(rng, n)
    s = np.exp(rng.uniform(*log_s, size=(n, 3)))
    a = rng.uniform(*alpha, size=n)
    occ, dd, cov6 = pack_gaussians(mu, q, s, a, kappa, mapping)
    return mu, q, s, a, occ, dd, cov6
