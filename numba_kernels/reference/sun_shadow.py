"""Reference of :mod:`numba_kernels.sun_shadow` (tests only): every occluder, no culling, the
independent numpy closed form of :mod:`numba_kernels.reference.dgsm_exact` per direction."""

from __future__ import annotations

import numpy as np

from .dgsm_exact import optical_depth_numpy


def transmittance_directions_numpy(dirs, occ, dir_dep: int, points) -> np.ndarray:
    """(M, D) float64 ``exp(-tau)`` of ``points`` for each propagation direction of ``dirs``."""
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    cols = [np.exp(-optical_depth_numpy(None, points, occ, dir_dep, direction=d / np.linalg.norm(d))) for d in dirs]
    return np.stack(cols, axis=1) if cols else np.ones((len(points), 0))
