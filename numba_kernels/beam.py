"""Points against a light's beam through a sphere, and sample points moved toward a light.

:func:`beam_gap_depth`: for points ``x`` and the beam of a light through the sphere (``c``, ``r``),
``gap`` is the distance from the point to the beam (<= 0 inside) and ``depth`` how far past the
sphere's near side the point lies along the light (>= 0 beyond it):

- a point light at ``lp`` (``dc = |c - lp| > r``; the caller handles a light inside the sphere):
  with ``v = x - lp``, ``dist = |v|``, ``along = v . u`` (``u`` the unit axis toward ``c``),
  ``perp = sqrt(max(dist^2 - along^2, 0))``, ``sin_h = r / dc`` and ``cos_h = sqrt(1 - sin_h^2)``:
  ``gap = dist`` where ``along cos_h + perp sin_h < 0`` (behind the apex), else
  ``perp cos_h - along sin_h``; ``depth = dist - (dc - r)``;
- a directional light travelling along the unit ``u``: with ``v = x - c``, ``along = v . u``,
  ``gap = sqrt(max(|v|^2 - along^2, 0)) - r`` and ``depth = along + r``.

:func:`offset_toward_point`: ``p + bias * (lp - p) / max(|lp - p|, 1e-12)`` per point.

Float64 arithmetic on float32 or float64 positions, each sum of three products taken left to right;
points are addressed through ``rows`` (empty: every point) so that no gathered copy is made.
Reference: ``numba_kernels.reference.beam`` (:func:`offset_toward_point` equal bit for bit, the
beam to rounding: numpy's matrix product may add three products in another order).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import float_rows, threaded
from .thread_chunks import run_chunks


@njit(cache=True, **threaded(), fastmath=False)
def _beam_rows(i0, i1, x, rows, point, a, u, r, dc, sin_h, cos_h, gap, depth):
    use_rows = rows.shape[0] > 0
    for k in range(i0, i1):
        m = rows[k] if use_rows else k
        vx = np.float64(x[m, 0]) - a[0]
        vy = np.float64(x[m, 1]) - a[1]
        vz = np.float64(x[m, 2]) - a[2]
        vv = vx * vx + vy * vy + vz * vz
        along = vx * u[0] + vy * u[1] + vz * u[2]
        if point:
            dist = math.sqrt(vv)
            perp = math.sqrt(max(dist * dist - along * along, 0.0))
            if along * cos_h + perp * sin_h < 0.0:
                gap[k] = dist
            else:
                gap[k] = perp * cos_h - along * sin_h
            depth[k] = dist - (dc - r)
        else:
            gap[k] = math.sqrt(max(vv - along * along, 0.0)) - r
            depth[k] = along + r


def beam_gap_depth(positions, rows, point: bool, a, u, r: float, dc: float = 0.0, sin_h: float = 0.0,
                   cos_h: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(gap, depth)`` (M,) float64 of ``positions[rows]`` ((N, 3) float32 or float64; ``rows`` (M,)
    int64, None or empty: every point) against a light's beam (module docstring). ``point``: a
    point light at ``a`` (3,) whose unit axis ``u`` (3,) points at the sphere's centre ``dc`` away,
    ``sin_h`` and ``cos_h`` the half-angle's sine and cosine; else a directional light travelling
    along the unit ``u``, ``a`` the sphere's centre. ``r``: the sphere's radius."""
    x = float_rows(positions)
    idx = np.zeros(0, np.int64) if rows is None else np.ascontiguousarray(rows, np.int64).reshape(-1)
    m = idx.shape[0] if rows is not None else x.shape[0]
    gap = np.empty(m)
    depth = np.empty(m)
    if rows is not None and m == 0:
        return gap, depth
    run_chunks(_beam_rows, m, x, idx, bool(point), np.asarray(a, np.float64).reshape(3),
               np.asarray(u, np.float64).reshape(3), float(r), float(dc), float(sin_h), float(cos_h), gap, depth,
               min_chunk=16384)
    return gap, depth


@njit(cache=True, **threaded(), fastmath=False)
def _offset_rows(i0, i1, pts, lp, bias):
    for m in range(i0, i1):
        tx = lp[0] - pts[m, 0]
        ty = lp[1] - pts[m, 1]
        tz = lp[2] - pts[m, 2]
        n = max(math.sqrt(tx * tx + ty * ty + tz * tz), 1e-12)
        pts[m, 0] = pts[m, 0] + bias * (tx / n)
        pts[m, 1] = pts[m, 1] + bias * (ty / n)
        pts[m, 2] = pts[m, 2] + bias * (tz / n)


def offset_toward_point(points: np.ndarray, light_position, bias: float) -> np.ndarray:
    """Move ``points`` (M, 3) float64 C-contiguous, in place, ``bias`` (scene units) toward the
    point ``light_position`` (3,) (module docstring); returns ``points``."""
    if points.dtype != np.float64 or not points.flags.c_contiguous or points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"offset_toward_point: points must be C-contiguous float64 (M, 3), got {points.dtype} "
                         f"{points.shape}")
    run_chunks(_offset_rows, points.shape[0], points, np.asarray(light_position, np.float64).reshape(3), float(bias),
               min_chunk=16384)
    return points
