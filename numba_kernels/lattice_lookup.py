"""Trilinear lookups in a shot-long directional lattice of voxel columns (the sun atlas of
``usd_gs.shadows.static_scene.StaticSceneSunAtlas``).

The lattice: pixel ``(i, j)`` (any sign) is the ray ``c + (i + 1/2) h e1 + (j + 1/2) h e2 + s l``
with ``K`` bins at depths ``s = tb + (k + 1/2) ds`` (rows ``e1, e2, l`` of ``basis``). Its computed
columns live in a row store (``store`` (R, K) float32), found through a two-level pixel map: a
dense grid of ``block x block``-pixel blocks starting at block ``lo`` (``grid`` int32, -1 where no
block) and a pool of dense ``block x block`` row tables (``pool`` int64, -1 where no column), as
``usd_gs.shadows.lattice_index.LatticeIndex`` keeps them.

- :func:`lattice_stencils`: per point, its bilinear stencil in the lattice (corner ``(i0, j0)``,
  weights ``wx, wy``), its bin pair ``k0`` with weight ``wk``, and the store rows of the four
  corner columns (-1 where a column is not computed yet);
- :func:`lattice_interpolate`: the trilinear transmittance from those rows and the spread (largest
  minus smallest) of the eight voxels it blends.

Each is one threaded pass over the points (``thread_chunks.run_chunks``), with the arithmetic of
the numpy forms :func:`lattice_stencils_numpy` and :func:`lattice_interpolate_numpy` (the
references the tests compare them with) in the same order: the same bits.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .dgsm_directional import lattice_coords
from .jit_options import threaded
from .thread_chunks import run_chunks

#: corner order of the rows: (0, 0), (0, 1), (1, 0), (1, 1) offsets of (i0, j0)
CORNERS = ((0, 0), (0, 1), (1, 0), (1, 1))


@njit(cache=True, fastmath=False, inline="always")
def _row(i, j, shift, mask, lo0, lo1, grid, pool):
    bi, bj = (i >> shift) - lo0, (j >> shift) - lo1
    if bi < 0 or bi >= grid.shape[0] or bj < 0 or bj >= grid.shape[1]:
        return -1
    slot = grid[bi, bj]
    if slot < 0:
        return -1
    return pool[slot, i & mask, j & mask]


@njit(cache=True, **threaded(), fastmath=False)
def _stencils(m0, m1, pts, c, basis, h, tb, ds, K, shift, lo0, lo1, grid, pool, ij0, w, k0, rows):
    mask = (1 << shift) - 1
    for m in range(m0, m1):
        fx, fy, fk = lattice_coords(pts[m, 0], pts[m, 1], pts[m, 2], c, basis, 0.0, h, tb, ds)  # (centred on c)
        fk = min(max(fk, 0.0), K - 1.0)
        i0, j0 = np.int64(math.floor(fx)), np.int64(math.floor(fy))
        kk = min(np.int64(math.floor(fk)), K - 2)
        ij0[m, 0], ij0[m, 1] = i0, j0
        w[m, 0], w[m, 1], w[m, 2] = fx - i0, fy - j0, fk - kk
        k0[m] = kk
        rows[0, m] = _row(i0, j0, shift, mask, lo0, lo1, grid, pool)
        rows[1, m] = _row(i0, j0 + 1, shift, mask, lo0, lo1, grid, pool)
        rows[2, m] = _row(i0 + 1, j0, shift, mask, lo0, lo1, grid, pool)
        rows[3, m] = _row(i0 + 1, j0 + 1, shift, mask, lo0, lo1, grid, pool)


def lattice_stencils(pts, c, basis, h: float, tb: float, ds: float, K: int, lo, grid, pool):
    """Stencils and corner rows of ``pts`` (M, 3) float64 (module doc): ``(ij0 (M, 2) int64, w (M, 3)
    float64 = (wx, wy, wk), k0 (M,) int64 in 0..K-2, rows (4, M) int64 in :data:`CORNERS` order, -1
    where the column is not in the map)``. ``lo`` (2,) int64; ``pool`` (S, B, B) with B a power of
    two (the block size)."""
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    m = pts.shape[0]
    ij0, w = np.empty((m, 2), np.int64), np.empty((m, 3))
    k0, rows = np.empty(m, np.int64), np.empty((4, m), np.int64)
    shift = int(pool.shape[1]).bit_length() - 1
    run_chunks(_stencils, m, pts, np.asarray(c, np.float64), np.ascontiguousarray(basis, dtype=np.float64),
               float(h), float(tb), float(ds), int(K), shift, int(lo[0]), int(lo[1]), grid, pool,
               ij0, w, k0, rows, min_chunk=8192)
    return ij0, w, k0, rows


@njit(cache=True, **threaded(), fastmath=False)
def _interpolate(m0, m1, rows, store, k0, w, out, spread):
    for m in range(m0, m1):
        wx, wy, wk = w[m, 0], w[m, 1], w[m, 2]
        acc, lo, hi = 0.0, np.inf, -np.inf
        for n in range(4):
            w_ij = (wx if n >= 2 else 1.0 - wx) * (wy if n % 2 == 1 else 1.0 - wy)
            r = rows[n, m]
            for dk in range(2):
                v = np.float64(store[r, k0[m] + dk])
                acc += w_ij * (wk if dk else 1.0 - wk) * v
                lo = min(lo, v)
                hi = max(hi, v)
        out[m] = min(max(acc, 0.0), 1.0)
        spread[m] = hi - lo


def lattice_interpolate(rows, store, k0, w) -> tuple[np.ndarray, np.ndarray]:
    """``(T (M,) float64 clipped to [0, 1], spread (M,) float64)``: the trilinear blend of the eight
    voxels of each point (``rows`` (4, M), every one computed; ``k0``, ``w`` from
    :func:`lattice_stencils`) in ``store`` (R, K) float32, and their largest minus smallest value."""
    m = k0.shape[0]
    out, spread = np.empty(m), np.empty(m)
    run_chunks(_interpolate, m, rows, store, k0, w, out, spread, min_chunk=8192)
    return out, spread


# ------------------------------------------------------------------ numpy references
def lattice_stencils_numpy(pts, c, basis, h: float, tb: float, ds: float, K: int, lookup):
    """:func:`lattice_stencils` in numpy, the corner rows from ``lookup`` ((M, 2) pixels -> (M,) rows,
    e.g. ``LatticeIndex.lookup``)."""
    rel = np.asarray(pts, np.float64) - c

    def dot(v):
        return rel[:, 0] * v[0] + rel[:, 1] * v[1] + rel[:, 2] * v[2]

    fx = dot(basis[0]) / h - 0.5
    fy = dot(basis[1]) / h - 0.5
    fk = np.clip((dot(basis[2]) - tb) / ds - 0.5, 0.0, K - 1.0)
    i0, j0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    k0 = np.minimum(np.floor(fk).astype(np.int64), K - 2)
    rows = np.stack([lookup(np.stack([i0 + di, j0 + dj], 1)) for di, dj in CORNERS])
    return np.stack([i0, j0], 1), np.stack([fx - i0, fy - j0, fk - k0], 1), k0, rows


def lattice_interpolate_numpy(rows, store, k0, w) -> tuple[np.ndarray, np.ndarray]:
    """:func:`lattice_interpolate` in numpy."""
    wx, wy, wk = w[:, 0], w[:, 1], w[:, 2]
    out = np.zeros(k0.shape[0])
    lo, hi = np.full(k0.shape[0], np.inf), np.full(k0.shape[0], -np.inf)
    for n, (di, dj) in enumerate(CORNERS):
        w_ij = (wx if di else 1.0 - wx) * (wy if dj else 1.0 - wy)
        for dk in (0, 1):
            v = store[rows[n], k0 + dk].astype(np.float64)
            out += w_ij * (wk if dk else 1.0 - wk) * v
            lo, hi = np.minimum(lo, v), np.maximum(hi, v)
    return np.clip(out, 0.0, 1.0), hi - lo
