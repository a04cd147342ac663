"""Reference of :mod:`numba_kernels.dgsm_directional`: the exact transmittance at a directional
atlas's voxel centres, with the numpy optical depth of :mod:`numba_kernels.reference.dgsm_exact`."""

from __future__ import annotations

import numpy as np

from .dgsm_exact import optical_depth_numpy


def voxel_centres(atlas) -> np.ndarray:
    """(|P|, kmax - kmin + 1, 3) world centres of the stored voxels of a ``DirAtlas``: pixel (i, j)
    at ``c + ((i + 1/2) h - S/2) e1 + ((j + 1/2) h - S/2) e2`` (``S = W h``), bin k at
    ``tb + (k + 1/2) ds`` along ``l``."""
    e1, e2, l = atlas.basis
    half = 0.5 * atlas.h * atlas.width
    i, j = atlas.pixels // atlas.width, atlas.pixels % atlas.width
    s = atlas.tb + (np.arange(atlas.kmin, atlas.kmax + 1) + 0.5) * atlas.ds
    base = atlas.centre + ((i + 0.5) * atlas.h - half)[:, None] * e1 + ((j + 0.5) * atlas.h - half)[:, None] * e2
    return base[:, None, :] + s[None, :, None] * l


def voxel_transmittance(atlas, occ, dir_dep: int) -> np.ndarray:
    """(|P|, kmax - kmin + 1) ``exp(-tau)`` at :func:`voxel_centres`, tau over the whole line
    towards the light (``optical_depth_numpy`` in directional mode)."""
    pts = voxel_centres(atlas)
    tau = optical_depth_numpy(None, pts.reshape(-1, 3), occ, dir_dep, direction=atlas.basis[2])
    return np.exp(-tau).reshape(pts.shape[:2])
