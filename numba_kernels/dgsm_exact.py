"""Exact DGSM transmittance at arbitrary points: float64, every occluder, no atlas.

This is the ground truth every tabulated path is measured against, and a usable fast path
for small problems (cost ``O(points x occluders)``, parallel over points).

Point light at ``o`` (metres): ``T(x) = exp(-sum_i tau_i(d, 0, |x - o|))`` with
``d = (x - o)/|x - o|``; a point at distance 0 from the light gets ``T = 1`` (empty path).
Directional light travelling along unit ``l`` (UsdLux DistantLight: its -Z axis):
``T(x) = exp(-sum_i tau_i(l, -inf, 0))`` on the ray ``x + s l`` (the whole half-line
towards the light, no light position).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .dgsm_model import check_points, check_vector, segment_depth
from .jit_options import prange_only


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _optical_depth_point(light, pts, occ, dir_dep):
    m = pts.shape[0]
    n = occ.shape[0]
    out = np.zeros(m, np.float64)
    ox, oy, oz = light[0], light[1], light[2]
    for j in prange(m):
        vx = pts[j, 0] - ox
        vy = pts[j, 1] - oy
        vz = pts[j, 2] - oz
        t = math.sqrt(vx * vx + vy * vy + vz * vz)
        if t == 0.0:
            continue
        dx, dy, dz = vx / t, vy / t, vz / t
        acc = 0.0
        for i in range(n):
            acc += segment_depth(occ, i, ox, oy, oz, dx, dy, dz, 0.0, t, dir_dep)
        out[j] = acc
    return out


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _optical_depth_directional(ldir, pts, occ, dir_dep):
    m = pts.shape[0]
    n = occ.shape[0]
    out = np.zeros(m, np.float64)
    dx, dy, dz = ldir[0], ldir[1], ldir[2]
    for j in prange(m):
        acc = 0.0
        for i in range(n):
            acc += segment_depth(occ, i, pts[j, 0], pts[j, 1], pts[j, 2], dx, dy, dz, -np.inf, 0.0, dir_dep)
        out[j] = acc
    return out


def optical_depth_point(light, points, occ, dir_dep: int) -> np.ndarray:
    """(M,) float64 optical depth from point light ``light`` (3,) to ``points`` (M, 3) through
    packed occluders ``occ`` (``dgsm_model.pack_occluders``). ValueError on non-finite input."""
    light = check_vector("light position", light)
    pts = check_points("receiver points", points)
    return _optical_depth_point(light, pts, np.ascontiguousarray(occ, dtype=np.float64), int(dir_dep))


def transmittance_point(light, points, occ, dir_dep: int) -> np.ndarray:
    """(M,) float64 exact transmittance in [0, 1] from a point light (see module doc)."""
    return np.exp(-optical_depth_point(light, points, occ, dir_dep))


def unit_direction(direction) -> np.ndarray:
    """Normalised (3,) float64 direction; ValueError for non-finite or zero length."""
    d = check_vector("light direction", direction)
    n = float(np.linalg.norm(d))
    if not n > 0:
        raise ValueError("'light direction' has zero length")
    return d / n


def optical_depth_directional(direction, points, occ, dir_dep: int) -> np.ndarray:
    """(M,) float64 optical depth for parallel light travelling along ``direction`` (3,)."""
    d = unit_direction(direction)
    pts = check_points("receiver points", points)
    return _optical_depth_directional(d, pts, np.ascontiguousarray(occ, dtype=np.float64), int(dir_dep))


def transmittance_directional(direction, points, occ, dir_dep: int) -> np.ndarray:
    """(M,) float64 exact transmittance for a directional light (see module doc)."""
    return np.exp(-optical_depth_directional(direction, points, occ, dir_dep))
