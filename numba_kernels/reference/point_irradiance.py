"""Reference of :mod:`numba_kernels.point_irradiance` in numpy, from its module docstring."""

from __future__ import annotations

import numpy as np


def point_irradiance(positions, normals, light_position, intensity):
    x = np.asarray(positions, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    d = np.asarray(light_position, np.float64) - x
    r2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    cos = np.einsum("ij,ij->i", n, d) / np.sqrt(r2)
    return (np.maximum(cos, 0.0) / r2)[:, None] * np.asarray(intensity, np.float64)[None, :]
