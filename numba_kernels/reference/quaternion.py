"""Reference of :mod:`numba_kernels.quaternion`: ``R v = q v q*`` with the Hamilton product."""

from __future__ import annotations

import math

import numpy as np


def _mul(a, b):
    return np.array([a[0] * b[0] - a[1:] @ b[1:], *(a[0] * b[1:] + b[0] * a[1:] + np.cross(a[1:], b[1:]))])


def hamilton_rotation(w, x, y, z) -> np.ndarray:
    """(3, 3) float64 rotation of ``(w, x, y, z)`` normalised (identity for a zero or non-finite
    quaternion); column k is ``q e_k q*``."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        return np.eye(3)
    q = np.array([w, x, y, z], dtype=np.float64) / n
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    return np.stack([_mul(_mul(q, np.r_[0.0, e]), conj)[1:] for e in np.eye(3)], axis=1)


def rotation_matrices(quats) -> np.ndarray:
    """(N, 3, 3) float64 rotations of quaternions (N, 4) ``(w, x, y, z)``, one at a time."""
    q = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    return np.stack([hamilton_rotation(*row) for row in q]) if len(q) else np.zeros((0, 3, 3))
