"""Reference of :mod:`numba_kernels.dgsm_sample`'s point-light lookup: the trilinear rule of its
module docstring, one point at a time on the dense atlas, with the octahedral reference."""

from __future__ import annotations

import math

import numpy as np

from .octahedral import encode, wrap_pixel


def lookup_point(atlas, light, points) -> np.ndarray:
    """(M,) transmittance of ``atlas`` (``dgsm_build.Atlas``) at ``points`` (M, 3): bilinear over the
    4 fold-wrapped pixels around eq. 6 of ``x - light``, linear over the two bins around the
    continuous bin ``t K / t_max - 1/2`` (towards T = 1 at the light below the first centre,
    clamped beyond the last), clipped to [0, 1]."""
    table = atlas.dense().astype(np.float64)  # (W, W, K), ones outside the stored voxels
    w, K, t_max = atlas.width, atlas.K, atlas.t_max
    out = np.ones(len(points))
    for m, x in enumerate(np.asarray(points, np.float64).reshape(-1, 3)):
        v = x - np.asarray(light, np.float64)
        t = math.sqrt(float(v @ v))
        if t == 0.0:
            continue
        fx, fy = (encode(v) + 1.0) * w / 2 - 0.5
        i0, j0 = math.floor(fx), math.floor(fy)
        fk = min(t * K / t_max - 0.5, K - 1.0)
        k0 = math.floor(fk)
        wk = fk - k0 if fk >= 0.0 else 2.0 * t * K / t_max  # k0 = -1: the light itself, T = 1
        acc = 0.0
        for di in (0, 1):
            for dj in (0, 1):
                wij = (fx - i0 if di else 1 - (fx - i0)) * (fy - j0 if dj else 1 - (fy - j0))
                pi, pj = wrap_pixel(i0 + di, j0 + dj, w)
                a = 1.0 if k0 < 0 else table[pi, pj, k0]
                b = table[pi, pj, k0 + 1] if wk > 0.0 else a
                acc += wij * ((1.0 - wk) * a + wk * b)
        out[m] = min(max(acc, 0.0), 1.0)
    return out
