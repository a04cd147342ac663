"""Reference of :mod:`numba_kernels.direction_zbuffer` (tests only): every disc against every
texel of every cube face, with numpy."""

from __future__ import annotations

import numpy as np

from ..cubemap_dirs import cube_face_directions


def splat_min_depth(dirs, dist, radius, size: int) -> np.ndarray:
    """Slow reference of ``direction_zbuffer.splat_min_depth`` (with a ``max_reach`` that does not bind):
    every disc against every texel of every face (numpy, O(T x 6 size^2))."""
    td = cube_face_directions(int(size))
    td = td / np.linalg.norm(td, axis=-1, keepdims=True)
    out = np.full((6, size, size), np.inf)
    for t in range(len(dist)):
        if not radius[t] > 0:
            continue
        cover = td @ np.asarray(dirs[t], np.float64) >= np.cos(radius[t])
        out = np.where(cover, np.minimum(out, dist[t]), out)
    return out
