"""A cube render of far content seen from another point: the far layer of a probe render
(``usd_gs.relight.far_field``) moved from the point it was rendered from to the probe's centre.

Cube faces as in :mod:`numba_kernels.cubemap_dirs` (``+X, -X, +Y, -Y, +Z, -Z``; texel (i, j) of face
f looks along ``forward + u right + v down``, ``u = 2 (j + 1/2) / S - 1``, ``v`` likewise from i).
Input: premultiplied ``rgb`` (6, S, S, 3), ``alpha`` (6, S, S) and the alpha-normalised expected
``depth`` along each face's forward axis (6, S, S), as the rasteriser returns them, rendered from
``source``. Each texel of the output (seen from ``target``) looks along its unit direction ``w`` and
takes the far point ``P = target + t w`` that the source saw in direction ``P - source`` at distance
``r``: ``t`` from ``|target - source + t w| = r``, two fixed-point steps from ``t = r(w)``, with ``r``
the source's alpha-weighted distance (depth over the texel's axis cosine) sampled bilinearly
(``clearance`` where the source saw next to nothing, alpha <= :data:`ALPHA_EMPTY`: there the
weighted mean of the distances would follow weights of 1e-16 from the bilinear blend). The output
texel takes the source's rgb and alpha at ``P``'s direction (bilinear, clamped to the edge texels of
the face the direction falls on) and depth ``t`` along its own face's axis (0 where alpha is 0).

Exact for far content at the distance its texel holds; a texel blending content at distances
``r1 < r2`` puts it off by up to ``|target - source| (1/r1 - 1/r2)`` radians; the bilinear
resampling blurs by up to a texel. Units: the caller's (metres). Reference:
``numba_kernels.reference.cube_warp``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .cubemap_dirs import FACE_FRAMES
from .direction_zbuffer import cube_face_uv

#: sampled alpha at or below which the far distance there is taken as the clearance (module docstring)
ALPHA_EMPTY = 1e-6


@njit(cache=True, fastmath=False)
def _face_xy(frames, size, dx, dy, dz):
    """(face, x, y): the face a direction falls on (``direction_zbuffer.cube_face_uv``) and its
    continuous texel coordinates, clamped to the face's texel centres."""
    f, _, u, v = cube_face_uv(frames, dx, dy, dz)
    x = min(max((u + 1.0) * (0.5 * size) - 0.5, 0.0), size - 1.0)
    y = min(max((v + 1.0) * (0.5 * size) - 0.5, 0.0), size - 1.0)
    return f, x, y


@njit(cache=True, fastmath=False)
def _sample(planes, frames, dx, dy, dz, out):
    """Bilinear sample of ``planes`` (6, S, S, C) at direction (dx, dy, dz) into ``out`` (C,)."""
    size = planes.shape[1]
    f, x, y = _face_xy(frames, size, dx, dy, dz)
    j0 = min(int(math.floor(x)), max(size - 2, 0))
    i0 = min(int(math.floor(y)), max(size - 2, 0))
    fx, fy = x - j0, y - i0
    j1, i1 = min(j0 + 1, size - 1), min(i0 + 1, size - 1)
    for c in range(planes.shape[3]):
        top = planes[f, i0, j0, c] * (1.0 - fx) + planes[f, i0, j1, c] * fx
        bottom = planes[f, i1, j0, c] * (1.0 - fx) + planes[f, i1, j1, c] * fx
        out[c] = top * (1.0 - fy) + bottom * fy


@njit(cache=True, fastmath=False)
def _distance(s, clearance):
    return s[4] / s[3] if s[3] > ALPHA_EMPTY else clearance


@njit(cache=True, fastmath=False, nogil=True)
def _warp(rgb, alpha, depth, source, target, clearance, steps, frames, out_rgb, out_a, out_d):
    size = alpha.shape[1]
    planes = np.empty((6, size, size, 5))
    ws = np.empty((6, size, size, 4))  # unit direction, axis cosine
    for f in range(6):
        for i in range(size):
            v = 2.0 * (i + 0.5) / size - 1.0
            for j in range(size):
                u = 2.0 * (j + 0.5) / size - 1.0
                d0 = frames[f, 0, 0] + u * frames[f, 1, 0] + v * frames[f, 2, 0]
                d1 = frames[f, 0, 1] + u * frames[f, 1, 1] + v * frames[f, 2, 1]
                d2 = frames[f, 0, 2] + u * frames[f, 1, 2] + v * frames[f, 2, 2]
                n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                ws[f, i, j, 0], ws[f, i, j, 1], ws[f, i, j, 2], ws[f, i, j, 3] = d0 / n, d1 / n, d2 / n, 1.0 / n
                a = np.float64(alpha[f, i, j])
                for c in range(3):
                    planes[f, i, j, c] = rgb[f, i, j, c]
                planes[f, i, j, 3] = a
                planes[f, i, j, 4] = a * np.float64(depth[f, i, j]) * n
    o0, o1, o2 = target[0] - source[0], target[1] - source[1], target[2] - source[2]
    c2 = o0 * o0 + o1 * o1 + o2 * o2
    s = np.empty(5)
    for f in range(6):
        for i in range(size):
            for j in range(size):
                w0, w1, w2 = ws[f, i, j, 0], ws[f, i, j, 1], ws[f, i, j, 2]
                b = w0 * o0 + w1 * o1 + w2 * o2
                t = _distance(planes[f, i, j], clearance)
                for step in range(steps + 1):  # (the last sample is the output's)
                    p0, p1, p2 = o0 + t * w0, o1 + t * w1, o2 + t * w2
                    pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
                    _sample(planes, frames, p0 / pn, p1 / pn, p2 / pn, s)
                    if step < steps:
                        r = _distance(s, clearance)
                        t = -b + math.sqrt(max(b * b - c2 + r * r, 0.0))
                for c in range(3):
                    out_rgb[f, i, j, c] = s[c]
                out_a[f, i, j] = s[3]
                out_d[f, i, j] = t * ws[f, i, j, 3] if s[3] > 0.0 else 0.0


def warp_layer(rgb, alpha, depth, source, target, clearance: float, steps: int = 2):
    """``(rgb (6, S, S, 3), alpha (6, S, S), depth (6, S, S))`` float32: the cube render (module
    docstring) rendered from ``source`` (3,) as seen from ``target`` (3,); ``clearance`` (> 0): the
    distance assumed where the source saw nothing; ``steps`` fixed-point steps."""
    rgb = np.ascontiguousarray(rgb, np.float32)
    alpha = np.ascontiguousarray(alpha, np.float32)
    depth = np.ascontiguousarray(depth, np.float32)
    size = alpha.shape[1]
    if rgb.shape != (6, size, size, 3) or alpha.shape != (6, size, size) or depth.shape != alpha.shape:
        raise ValueError(f"cube warp: faces of shapes {rgb.shape}, {alpha.shape}, {depth.shape}; "
                         "expected (6, S, S, 3), (6, S, S), (6, S, S)")
    out_rgb = np.empty_like(rgb)
    out_a = np.empty_like(alpha)
    out_d = np.empty_like(depth)
    _warp(rgb, alpha, depth, np.asarray(source, np.float64).reshape(3), np.asarray(target, np.float64).reshape(3),
          float(clearance), int(steps), FACE_FRAMES, out_rgb, out_a, out_d)
    return out_rgb, out_a, out_d
