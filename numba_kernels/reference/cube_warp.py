"""Reference of :mod:`numba_kernels.cube_warp` (tests only): the same steps in vectorised numpy
over all texels, the cube lookups through ``cubemap_dirs.direction_to_face_uv``."""

from __future__ import annotations

import numpy as np

from ..cube_warp import ALPHA_EMPTY
from ..cubemap_dirs import FACE_FRAMES, cube_face_directions, direction_to_face_uv


def sample_faces(planes: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Bilinear samples (M, C) of ``planes`` (6, S, S, C) at directions ``dirs`` (M, 3), clamped
    to the edge texels of the face each direction falls on."""
    size = planes.shape[1]
    face, u, v = direction_to_face_uv(dirs)
    x = np.clip((u + 1.0) * (0.5 * size) - 0.5, 0.0, size - 1.0)
    y = np.clip((v + 1.0) * (0.5 * size) - 0.5, 0.0, size - 1.0)
    j0 = np.minimum(np.floor(x).astype(np.int64), max(size - 2, 0))
    i0 = np.minimum(np.floor(y).astype(np.int64), max(size - 2, 0))
    fx, fy = (x - j0)[:, None], (y - i0)[:, None]
    j1, i1 = np.minimum(j0 + 1, size - 1), np.minimum(i0 + 1, size - 1)
    top = planes[face, i0, j0] * (1.0 - fx) + planes[face, i0, j1] * fx
    bottom = planes[face, i1, j0] * (1.0 - fx) + planes[face, i1, j1] * fx
    return top * (1.0 - fy) + bottom * fy


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
        r = distance(sample_faces(planes, p / np.linalg.norm(p, axis=1, keepdims=True)))
        t = -b + np.sqrt(np.maximum(b * b - c2 + r * r, 0.0))
    p = off + t[:, None] * w
    got = sample_faces(planes, p / np.linalg.norm(p, axis=1, keepdims=True))
    out_a = got[:, 3].reshape(6, size, size)
    out_d = np.where(out_a > 0.0, t.reshape(6, size, size) * axis_cos, 0.0)
    return got[:, :3].reshape(6, size, size, 3), out_a, out_d
