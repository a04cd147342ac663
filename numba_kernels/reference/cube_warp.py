"""Reference of :mod:`numba_kernels.cube_warp` (tests only): the same steps in vectorised numpy
over all texels, the cube lookups through ``cubemap_dirs.sample_cube_faces``."""

from __future__ import annotations

import numpy as np

from ..cube_warp import ALPHA_EMPTY
from ..cubemap_dirs import FACE_FRAMES, cube_face_directions, sample_cube_faces


def warp_layer(rgb, alpha, depth, source, target, clearance: float, steps: int = 2):
    """``(rgb, alpha, depth)`` float64 of :func:`numba_kernels.cube_warp.warp_layer`."""
    rgb, alpha, depth = (np.asarray(x, np.float64) for x in (rgb, alpha, depth))
    size = alpha.shape[1]
    dirs = cube_face_directions(size)
    axis_cos = np.abs(np.einsum("fijk,fk->fij", dirs, FACE_FRAMES[:, 0]))
    planes = np.concatenate([rgb, alpha[..., None], (alpha * depth / axis_cos)[..., None]], axis=-1)
    w = dirs.reshape(-1, 3)
    off = np.asarray(target, np.float64) - np.asarray(source, np.float64)
    b, c2 = w @ off, float(off @ off)

    def distance(sample):
        a, ad = sample[:, 3], sample[:, 4]
        return np.where(a > ALPHA_EMPTY, ad / np.where(a > ALPHA_EMPTY, a, 1.0), float(clearance))

    t = distance(planes.reshape(-1, 5))
    for _ in range(steps):
        p = off + t[:, None] * w
        r = distance(sample_cube_faces(planes, p / np.linalg.norm(p, axis=1, keepdims=True)))
        t = -b + np.sqrt(np.maximum(b * b - c2 + r * r, 0.0))
    p = off + t[:, None] * w
    got = sample_cube_faces(planes, p / np.linalg.norm(p, axis=1, keepdims=True))
    out_a = got[:, 3].reshape(6, size, size)
    out_d = np.where(out_a > 0.0, t.reshape(6, size, size) * axis_cos, 0.0)
    return got[:, :3].reshape(6, size, size, 3), out_a, out_d
