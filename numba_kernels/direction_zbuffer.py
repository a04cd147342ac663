"""Nearest distance per direction of a set of small direction discs: a cube-map z-buffer.

Used by ``usd_gs.relight.parallax`` to test occlusion between reprojected cube-map texels: each
texel, seen from a new point, is a disc of directions (centre ``dirs[t]``, angular radius
``radius[t]`` radians, a cone of the texel's solid angle) at distance ``dist[t]``; the buffer
holds, per target texel, the smallest distance of the discs that cover the target texel's
centre direction.

Conventions: target texels are those of ``numba_kernels.cubemap_dirs`` (faces +X, -X, +Y, -Y,
+Z, -Z; ``size`` x ``size`` each; texel (f, i, j) looks along ``FACE_FRAMES[f, 0] + u FACE_FRAMES
[f, 1] + v FACE_FRAMES[f, 2]``, ``u`` from the column, ``v`` from the row). Units: distances in
the caller's units, angles in radians. Empty texels hold ``inf``.

A disc is drawn on every face it reaches (across face edges), over at most ``max_reach``
texels either side of its centre's texel on that face; discs of radius 0 are not drawn.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .cubemap_dirs import FACE_FRAMES


@njit(cache=True, fastmath=False, inline="always")
def cube_face_uv(frames, x, y, z):
    """``(face, fw, u, v)`` of direction (x, y, z) on the cube ``frames`` (``FACE_FRAMES``): the face
    of its major axis (ties toward X then Y), ``fw`` its component along that face's forward axis
    and ``u = <d, right> / fw``, ``v = <d, down> / fw`` (not clamped)."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        f = 0 if x > 0 else 1
    elif ay >= az:
        f = 2 if y > 0 else 3
    else:
        f = 4 if z > 0 else 5
    fw = x * frames[f, 0, 0] + y * frames[f, 0, 1] + z * frames[f, 0, 2]
    u = (x * frames[f, 1, 0] + y * frames[f, 1, 1] + z * frames[f, 1, 2]) / fw if fw != 0.0 else 0.0
    v = (x * frames[f, 2, 0] + y * frames[f, 2, 1] + z * frames[f, 2, 2]) / fw if fw != 0.0 else 0.0
    return f, fw, u, v


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _splat(dirs, dist, radius, frames, size, max_reach, out):
    for t in range(dirs.shape[0]):
        x, y, z = dirs[t, 0], dirs[t, 1], dirs[t, 2]
        rho = radius[t]
        if not rho > 0.0:
            continue
        cos_rho = math.cos(rho)
        tan_rho = math.tan(min(rho, 1.2))
        for f in range(6):
            fw = x * frames[f, 0, 0] + y * frames[f, 0, 1] + z * frames[f, 0, 2]
            if fw < 0.1:  # the disc (at most 0.5 rad) cannot reach this face (texels within 55 deg of its axis)
                continue
            u = (x * frames[f, 1, 0] + y * frames[f, 1, 1] + z * frames[f, 1, 2]) / fw
            v = (x * frames[f, 2, 0] + y * frames[f, 2, 1] + z * frames[f, 2, 2]) / fw
            u = min(max(u, -4.0), 4.0)
            v = min(max(v, -4.0), 4.0)
            jc = int(math.floor((u + 1.0) * 0.5 * size))
            ic = int(math.floor((v + 1.0) * 0.5 * size))
            # face-coordinate extent of the disc: at most tan(rho) (1 + u^2 + v^2); a texel spans 2 / size
            reach = int(math.ceil(tan_rho * (1.0 + u * u + v * v) * 0.5 * size))
            if reach > max_reach:
                reach = max_reach
            for i in range(max(ic - reach, 0), min(ic + reach + 1, size)):
                vv = 2.0 * (i + 0.5) / size - 1.0
                for j in range(max(jc - reach, 0), min(jc + reach + 1, size)):
                    uu = 2.0 * (j + 0.5) / size - 1.0
                    dx = frames[f, 0, 0] + uu * frames[f, 1, 0] + vv * frames[f, 2, 0]
                    dy = frames[f, 0, 1] + uu * frames[f, 1, 1] + vv * frames[f, 2, 1]
                    dz = frames[f, 0, 2] + uu * frames[f, 1, 2] + vv * frames[f, 2, 2]
                    c = (dx * x + dy * y + dz * z) / math.sqrt(dx * dx + dy * dy + dz * dz)
                    if c >= cos_rho and dist[t] < out[f, i, j]:
                        out[f, i, j] = dist[t]


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _own_texel_depth(dirs, zbuf, frames, size, out):
    for t in range(dirs.shape[0]):
        f, fw, u, v = cube_face_uv(frames, dirs[t, 0], dirs[t, 1], dirs[t, 2])
        if not fw > 0.0:
            out[t] = np.inf
            continue
        j = min(max(int(math.floor((u + 1.0) * 0.5 * size)), 0), size - 1)
        i = min(max(int(math.floor((v + 1.0) * 0.5 * size)), 0), size - 1)
        out[t] = zbuf[f, i, j]


def nearest_over_own_direction(dirs: np.ndarray, dist: np.ndarray, radius: np.ndarray, size: int,
                               max_reach: int = 8) -> np.ndarray:
    """(T,) float64: for each disc, the z-buffer of all of them (:func:`splat_min_depth`) read at
    the texel of its own centre direction (faces chosen by the major axis, ties toward X then Y,
    as ``cubemap_dirs.direction_to_face_uv``)."""
    zbuf = splat_min_depth(dirs, dist, radius, size, max_reach)
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    out = np.empty(d.shape[0])
    _own_texel_depth(d, zbuf, FACE_FRAMES, int(size), out)
    return out


def splat_min_depth(dirs: np.ndarray, dist: np.ndarray, radius: np.ndarray, size: int,
                    max_reach: int = 8) -> np.ndarray:
    """(6, size, size) float64: per target texel the smallest ``dist`` of the discs (unit
    ``dirs`` (T, 3), ``dist`` (T,), angular ``radius`` (T,) radians) covering its centre
    direction; ``inf`` where none does (module docstring)."""
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    r = np.ascontiguousarray(dist, np.float64).reshape(-1)
    rad = np.ascontiguousarray(radius, np.float64).reshape(-1)
    if not (d.shape[0] == r.shape[0] == rad.shape[0]):
        raise ValueError("dirs, dist and radius must have the same length")
    out = np.full((6, int(size), int(size)), np.inf)
    _splat(d, r, rad, FACE_FRAMES, int(size), int(max_reach), out)
    return out
