"""Reference of :mod:`numba_kernels.sky_occlusion` in numpy, from its module docstring."""

from __future__ import annotations

import numpy as np


def hidden_sky_share(centres, radii, positions, normals) -> np.ndarray:
    x = np.asarray(positions, np.float64)
    nrm = np.asarray(normals, np.float64)
    out = np.zeros(x.shape[0])
    inside = np.zeros(x.shape[0], bool)
    for c, r in zip(np.asarray(centres, np.float64), np.asarray(radii, np.float64), strict=True):
        v = c - x
        d2 = np.einsum("ij,ij->i", v, v)
        inside |= d2 <= r * r
        cos = np.abs(np.einsum("ij,ij->i", v, nrm)) / np.sqrt(np.maximum(d2, 1e-300))
        out += (r * r / np.maximum(d2, 1e-300)) * cos
    return np.clip(np.where(inside, 1.0, out), 0.0, 1.0)
