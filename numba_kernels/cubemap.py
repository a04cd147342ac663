"""Cube-map direction atlas: the alternative of ablation C (sec. 4.4), point lights only.

Faces ``f = 2a + (0 if the major component is positive else 1)`` for major axis ``a`` (0 x,
1 y, 2 z). With the other two axes ``(b, c) = ((a+1) % 3, (a+2) % 3)``, a direction ``d``
has face coordinates ``s = d_b / |d_a|``, ``t = d_c / |d_a|`` in ``[-1, 1]``; decoding sets
``d_a = +-1, d_b = s, d_c = t`` and normalises. Each face has F x F pixels with centres at
``s = (2i + 1)/F - 1``; flat pixel id ``f F^2 + i F + j``.

Filtering is per face with clamp-to-edge (the usual non-seamless cube-map sampling): the
bilinear stencil never crosses a face edge, which is the seam the paper's octahedral atlas
avoids. Culling: 8x8 tiles per face; each tile's bounding cone (centre direction, angle to
its farthest corner pixel plus half a pixel diagonal) is tested against every occluder's cone
(``dgsm_build.bin_tiles`` cones) - O(active tiles x occluders), fine for an ablation. The
accumulation kernel is ``dgsm_build._accumulate_point`` (same bins, bin skipping, EPS_PAIR).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .dgsm_build import TILE, Atlas, _accumulate_point, _footprints, atlas_buffers, far_distance, t_max_for
from .dgsm_model import check_points, check_vector
from .jit_options import prange_only
from .thread_chunks import run_chunks


@njit(cache=True, fastmath=False)
def cube_encode(x, y, z):
    """Direction -> (face, s, t)."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        m, f = ax, (0 if x >= 0.0 else 1)
        b, c = y, z
    elif ay >= az:
        m, f = ay, (2 if y >= 0.0 else 3)
        b, c = z, x
    else:
        m, f = az, (4 if z >= 0.0 else 5)
        b, c = x, y
    return f, b / m, c / m


@njit(cache=True, fastmath=False)
def cube_decode(f, s, t):
    a = f // 2
    sg = 1.0 if f % 2 == 0 else -1.0
    v = np.empty(3)
    v[a] = sg
    v[(a + 1) % 3] = s
    v[(a + 2) % 3] = t
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return v[0] / n, v[1] / n, v[2] / n


@njit(cache=True, fastmath=False)
def _pixel_dir(pid, F):
    f = pid // (F * F)
    r = pid % (F * F)
    i = r // F
    j = r % F
    return cube_decode(f, (2.0 * i + 1.0) / F - 1.0, (2.0 * j + 1.0) / F - 1.0)


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _pixel_dirs(pixels, F, out):
    for p in prange(pixels.shape[0]):
        out[p, 0], out[p, 1], out[p, 2] = _pixel_dir(pixels[p], F)


@njit(cache=True, fastmath=False)
def _stencil(F, K, t_max, ox, oy, oz, x, y, z):
    """(face, i0, j0, wx, wy, k0, wk, t) of the clamped trilinear stencil."""
    vx, vy, vz = x - ox, y - oy, z - oz
    t = math.sqrt(vx * vx + vy * vy + vz * vz)
    if t == 0.0:
        vz = 1.0
    f, s, tt = cube_encode(vx, vy, vz)
    fx = min(max((s + 1.0) * 0.5 * F - 0.5, 0.0), F - 1.0)
    fy = min(max((tt + 1.0) * 0.5 * F - 0.5, 0.0), F - 1.0)
    i0 = min(int(math.floor(fx)), F - 2)
    j0 = min(int(math.floor(fy)), F - 2)
    fk = t * K / t_max - 0.5
    if fk > K - 1:
        fk = K - 1.0
    if fk < 0.0:
        k0 = -1
        wk = 2.0 * t * K / t_max
    else:
        k0 = int(math.floor(fk))
        wk = fk - k0
    return f, i0, j0, fx - i0, fy - j0, k0, wk, t


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _roi(light, pts, F, K, t_max, pix, kk):
    for m in prange(pts.shape[0]):
        f, i0, j0, wx, wy, k0, wk, t = _stencil(F, K, t_max, light[0], light[1], light[2],
                                                pts[m, 0], pts[m, 1], pts[m, 2])
        n = 0
        for di in range(2):
            for dj in range(2):
                pix[m, n] = f * F * F + (i0 + di) * F + j0 + dj
                n += 1
        kk[m, 0] = max(k0, 0)
        kk[m, 1] = min(k0 + 1, K - 1)


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _tile_lists(tcone, cone, theta, counts, start, items, fill_mode):
    for g in prange(tcone.shape[0]):
        cx, cy, cz, rho = tcone[g, 0], tcone[g, 1], tcone[g, 2], tcone[g, 3]
        k = start[g] if fill_mode else 0
        for o in range(cone.shape[0]):
            if cone[o, 3] < -1.5:
                continue  # global occluders are gathered separately
            lim = theta[o] + rho
            if lim < math.pi and cx * cone[o, 0] + cy * cone[o, 1] + cz * cone[o, 2] < math.cos(lim):
                continue
            if fill_mode:
                items[k] = o
            k += 1
        if not fill_mode:
            counts[g] = k


def build_point_cube(light, occ, dir_dep: int, cov6, roi_points, face: int = 208, K: int = 64,
                     t_max: float | None = None, k_sigma: float = 4.0, bin_skip: bool = True) -> Atlas:
    """Cube-map DGSM over the ROI voxels of ``roi_points``; ``Atlas.width`` holds the face size
    F and pixel ids are ``f F^2 + i F + j`` (6 F^2 pixels). F must be a multiple of 8."""
    light = check_vector("light position", light)
    pts = check_points("ROI points", roi_points)
    if face % TILE or face < TILE:
        raise ValueError(f"face size must be a positive multiple of {TILE}, got {face}")
    if t_max is None:
        t_max = t_max_for(far_distance(light, pts), K)
    F = int(face)
    pix = np.empty((len(pts), 4), np.int64)
    kk = np.empty((len(pts), 2), np.int64)
    _roi(light, pts, F, K, float(t_max), pix, kk)
    mask = np.zeros(6 * F * F, np.bool_)
    mask[pix.ravel()] = True
    pixels = np.flatnonzero(mask)
    kmin, kmax = (int(kk[:, 0].min()), int(kk[:, 1].max())) if len(pts) else (0, -1)
    index, out, pairs, erfs = atlas_buffers(6 * F * F, pixels, kmin, kmax)
    nk = out.shape[1]
    if len(pixels) and nk and occ.shape[0]:
        occ = np.ascontiguousarray(occ, dtype=np.float64)
        n = occ.shape[0]
        fxs, fys, rps = np.empty(n), np.empty(n), np.empty(n)
        is_glob = np.zeros(n, np.bool_)
        cone = np.empty((n, 4))
        run_chunks(_footprints, occ.shape[0], light, occ,
                   np.ascontiguousarray(cov6, dtype=np.float64), 512, float(k_sigma), fxs, fys, rps, is_glob, cone)
        theta = np.arccos(np.clip(cone[:, 3], -1.0, 1.0))
        ft = F // TILE
        tile = (pixels // (F * F)) * ft * ft + ((pixels % (F * F)) // F // TILE) * ft + (pixels % F) // TILE
        order = np.argsort(tile, kind="stable")
        tl = tile[order]
        cuts = np.flatnonzero(np.diff(tl)) + 1
        gs = np.concatenate([[0], cuts, [len(tl)]]).astype(np.int64)
        gt = np.arange(len(gs) - 1, dtype=np.int64)  # group g uses tile list g
        pdirs = np.empty((len(pixels), 3))
        _pixel_dirs(pixels, F, pdirs)
        # bounding cone of each group's pixel directions (+ half a pixel diagonal)
        tcone = np.empty((len(gs) - 1, 4))
        for g in range(len(gs) - 1):
            dsub = pdirs[order[gs[g]:gs[g + 1]]]
            cdir = dsub.mean(axis=0)
            cdir /= np.linalg.norm(cdir)
            tcone[g, :3] = cdir
            tcone[g, 3] = np.arccos(np.clip(dsub @ cdir, -1, 1)).max() + 2.0 / F
        counts = np.zeros(len(gs) - 1, np.int64)
        dummy = np.zeros(1, np.int64)
        _tile_lists(tcone, cone, theta, counts, dummy, dummy, False)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        items = np.empty(start[-1], np.int64)
        _tile_lists(tcone, cone, theta, counts, start, items, True)
        glob = np.flatnonzero(is_glob).astype(np.int64)
        run_chunks(_accumulate_point, len(gs) - 1, light, occ, int(dir_dep), pdirs, K, float(t_max), kmin, kmax, gs,
                   order.astype(np.int64), gt, start, items, glob, cone, bool(bin_skip), out, pairs, erfs,
                   chunks_per_thread=8)
    return Atlas(F, K, float(t_max), kmin, kmax, index, out, pixels, int(pairs.sum()), int(erfs.sum()), None)


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _lookup(index, values, F, K, t_max, kmin, kmax, light, pts, out):
    for m in prange(pts.shape[0]):
        f, i0, j0, wx, wy, k0, wk, t = _stencil(F, K, t_max, light[0], light[1], light[2],
                                                pts[m, 0], pts[m, 1], pts[m, 2])
        if t == 0.0:
            out[m] = 1.0
            continue
        acc = 0.0
        for di in range(2):
            for dj in range(2):
                wij = (wx if di else 1.0 - wx) * (wy if dj else 1.0 - wy)
                r = index[f * F * F + (i0 + di) * F + j0 + dj]
                for dk in range(2):
                    k = k0 + dk
                    v = 1.0 if (r < 0 or k < kmin or k > kmax) else values[r, k - kmin]
                    acc += wij * (wk if dk else 1.0 - wk) * v
        out[m] = min(max(acc, 0.0), 1.0)


def lookup_point_cube(atlas: Atlas, light, points) -> np.ndarray:
    """(M,) float64 trilinear (per-face, clamp-to-edge) lookups of a cube-map ``Atlas``."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(pts))
    _lookup(atlas.index, atlas.values, atlas.width, atlas.K, atlas.t_max, atlas.kmin, atlas.kmax,
            np.asarray(light, dtype=np.float64), pts, out)
    return out


def pixel_directions(face: int, pixels) -> np.ndarray:
    """(len(pixels), 3) unit directions of cube-map pixel centres."""
    out = np.empty((len(pixels), 3))
    _pixel_dirs(np.ascontiguousarray(pixels, dtype=np.int64), int(face), out)
    return out
