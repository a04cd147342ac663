"""Which points lie within a capsule: the set of points within ``radius + extra_i`` of the
segment from ``a`` to ``b`` (a ball when ``a == b``), for culling Gaussians (``extra_i`` their own
reach, e.g. a few of their sigmas) against the rays a shadow or visibility test casts.

Float64 arithmetic on float32 or float64 positions: the closest point of the segment is
``a + t u`` with ``u`` the unit direction and ``t = clip((p - a) . u, 0, |b - a|)``; a point is
inside when ``|p - a - t u|^2 <= (radius + extra)^2``. Reference: ``numba_kernels.reference.capsule``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import threaded
from .thread_chunks import run_chunks


@njit(cache=True, **threaded(), fastmath=False)
def _within(i0, i1, p, extra, a, u, length, radius, out):
    for m in range(i0, i1):
        vx = np.float64(p[m, 0]) - a[0]
        vy = np.float64(p[m, 1]) - a[1]
        vz = np.float64(p[m, 2]) - a[2]
        if length > 0.0:
            t = min(max(vx * u[0] + vy * u[1] + vz * u[2], 0.0), length)
            vx -= t * u[0]
            vy -= t * u[1]
            vz -= t * u[2]
        r = radius + extra[m]
        out[m] = vx * vx + vy * vy + vz * vz <= r * r


def within_capsule(positions, a, b, radius: float, extra=None) -> np.ndarray:
    """(N,) bool: ``positions`` (N, 3) float32 or float64 within ``radius`` + ``extra`` (N,) (None:
    0) of the segment ``a``-``b`` (3,) (module docstring)."""
    p = np.asarray(positions)
    if p.dtype not in (np.float32, np.float64):
        p = p.astype(np.float64)
    p = np.ascontiguousarray(p).reshape(-1, 3)
    n = p.shape[0]
    a64 = np.asarray(a, np.float64).reshape(3)
    axis = np.asarray(b, np.float64).reshape(3) - a64
    length = float(math.sqrt(float(axis @ axis)))
    u = axis / length if length > 0.0 else np.zeros(3)
    ex = np.zeros(n) if extra is None else np.ascontiguousarray(extra, np.float64).reshape(n)
    out = np.zeros(n, np.bool_)
    run_chunks(_within, n, p, ex, a64, u, length, float(radius), out, min_chunk=65536)
    return out
