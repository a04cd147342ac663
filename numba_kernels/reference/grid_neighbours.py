"""Reference of :mod:`numba_kernels.grid_neighbours`: neighbourhoods from a dense distance matrix."""

from __future__ import annotations

import numpy as np


def within(points, queries, radius: float, inner: float = 0.0) -> np.ndarray:
    """(Q, M) bool: ``inner <= |p_j - q_i| <= radius`` (squared float64 distances)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    q = np.asarray(queries, np.float64).reshape(-1, 3)
    d2 = ((q[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    return (d2 <= radius * radius) & (d2 >= inner * inner)


def nearest(points, queries) -> np.ndarray:
    """(Q,) index of the nearest point to each query (dense distances; ties: the lower index)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    q = np.asarray(queries, np.float64).reshape(-1, 3)
    return np.argmin(((q[:, None, :] - p[None, :, :]) ** 2).sum(-1), axis=1)
