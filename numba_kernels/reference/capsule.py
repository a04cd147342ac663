"""Reference of :mod:`numba_kernels.capsule` in numpy, from its module docstring."""

from __future__ import annotations

import numpy as np


def within_capsule(positions, a, b, radius: float, extra=None) -> np.ndarray:
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    a = np.asarray(a, np.float64)
    axis = np.asarray(b, np.float64) - a
    length = np.sqrt(axis @ axis)
    v = p - a
    if length > 0:
        u = axis / length
        t = np.clip(v @ u, 0.0, length)
        v = v - t[:, None] * u
    r = radius + (np.zeros(len(p)) if extra is None else np.asarray(extra, np.float64))
    return np.sum(v * v, axis=1) <= r * r


def within_capsule_scaled(positions, a, b, radius: float, scales, factor: float) -> np.ndarray:
    reach = np.float32(factor) * np.asarray(scales, np.float32).max(axis=1)
    return within_capsule(positions, a, b, radius, reach)
