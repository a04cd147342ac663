"""Which Gaussians a viewpoint sees: a depth test against the cube render from that point.

Used by the lighting-consistency metrics (``usd_gs.evaluation.lighting_metrics``): the scene neighbourhood
an avatar "sees" is the part of it not hidden behind other scene surfaces (the far side and
underside of a prop, a floor under a table). Those hidden Gaussians face away from the avatar,
so the "face the avatar" sign rule of their pseudo-normals is wrong exactly there.

Method: the Gaussians are rendered on the six cube faces around ``point`` with the splat
rasteriser (``usd_gs.render.rasterize.render_cube_faces``, expected view depth ``sum(z w) / sum(w)``
per texel, of the splats' *centres*); Gaussian ``i`` is visible when its own view depth along
its face's axis is at most ``depth * (1 + rel_tol) + abs_tol + size_tol * max_scale_i`` at its
texel (the size term: on a surface seen at an angle, the nearest splat over a texel, which
dominates its depth, has its centre up to about two sigma closer than the surface there;
``numba_kernels.cubemap_dirs`` mapping), or when the texel is nearly empty (alpha < 0.5:
nothing in front to hide it). Units: those of the positions (scene units); ``abs_tol`` is
given in them too. Accuracy (``tests/test_metrics_lighting.py``, a floor under a ball against
the analytic ray-sphere test): 97 % agree, every disagreement within 4 degrees (95 % within
2.5, two texels at 64^2) of the ball's silhouette, where the splats' tails and the texels blur the edge.
"""

from __future__ import annotations

import numpy as np

from numba_kernels.cubemap_dirs import FACE_FRAMES, direction_to_face_uv
from usd_gs.gaussians import GaussianSet
from usd_gs.render.rasterize import render_cube_faces


def visible_from(gaussians: GaussianSet, point, size: int = 64, rel_tol: float = 0.05,
                 abs_tol: float = 0.03, size_tol: float = 3.0) -> np.ndarray:
    """(N,) bool: Gaussian i is not hidden from ``point`` (3,) by the others (module docstring).

    size: cube-face resolution in texels (64: ~1.4 degrees per texel). Gaussians within
    ``abs_tol`` of the point count as visible.
    """

    n = gaussians.count
    if n == 0:
        return np.zeros(0, bool)
    p = np.asarray(point, np.float64).reshape(3)
    d = gaussians.positions.astype(np.float64) - p
    dist = np.linalg.norm(d, axis=1)
    near = dist <= abs_tol
    d[near] = (0.0, 0.0, 1.0)
    face, u, v = direction_to_face_uv(d)
    z = np.einsum("ij,ij->i", d, FACE_FRAMES[face, 0])  # view depth along the face's axis
    _, alpha, depth = render_cube_faces(gaussians, p, int(size))
    j = np.clip(((u + 1.0) * size / 2.0 - 0.5).round().astype(np.int64), 0, size - 1)
    i = np.clip(((v + 1.0) * size / 2.0 - 0.5).round().astype(np.int64), 0, size - 1)
    front = depth[face, i, j].astype(np.float64)
    empty = alpha[face, i, j] < 0.5
    tol = abs_tol + size_tol * gaussians.scales.astype(np.float64).max(axis=1)
    return near | empty | (z <= front * (1.0 + rel_tol) + tol)

