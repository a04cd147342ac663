"""DGSM for a directional light (UsdLux DistantLight): orthographic grid x depth bins.

The light travels along unit ``l`` (for a DistantLight, its -Z axis in world space). With an
orthonormal basis ``(e1, e2)`` of the plane orthogonal to ``l`` and a reference point ``c``
(the centre of the ROI points' projected bounding square), a world point ``x`` has grid
coordinates ``(p1, p2) = ((x - c).e1, (x - c).e2)`` and depth ``s = (x - c).l``.

Grid: W x W square pixels of side ``h`` covering the ROI points' projected bounding square
plus one pixel on every side; pixel ``(i, j)`` has its centre at
``p = (-S/2 + (i + 1/2) h, -S/2 + (j + 1/2) h)`` with ``S = W h``. Depth bins: K centres
``s_k = tb + (k + 1/2) ds`` spanning the ROI points' depth range exactly (first centre at
the smallest depth, last at the largest; ``ds = (s_max - s_min)/(K - 1)``).

Table ``T[i, j, k] = exp(-int_{-inf}^{s_k} sigma(c + p1 e1 + p2 e2 + s l) ds)``, computed
only on the ROI voxels (the bilinear stencils of the ROI points x the bins they touch),
1 elsewhere. Culling is exact for parallel rays: an occluder's k_sigma ellipsoid projects to
the ellipse of ``Sigma_perp`` on the grid plane, inside a circle of radius
``k_sigma sqrt(lambda_1)``; occluders are bucketed into 8x8 tiles by that circle's box and each
pixel tests the circle itself. Lookups: bilinear in the grid (indices clamped to the grid),
linear in depth (clamped to the first/last centre). Bin skipping as in ``dgsm_build``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .dgsm_build import TILE, atlas_buffers
from .dgsm_build import accumulate_one_call as _accumulate_one
from .dgsm_exact import unit_direction
from .dgsm_model import check_points
from .jit_options import prange_only


class DirAtlas(NamedTuple):
    """A directional DGSM (see module doc). Lengths in metres; ``values`` float32."""

    width: int
    K: int
    centre: np.ndarray  # (3,) reference point c
    basis: np.ndarray  # (3, 3) rows e1, e2, l
    h: float  # pixel size
    tb: float  # bin origin: centres at tb + (k + 1/2) ds
    ds: float
    kmin: int
    kmax: int
    index: np.ndarray  # (W*W,) int32
    values: np.ndarray  # (|P|, kmax - kmin + 1) float32
    pixels: np.ndarray  # (|P|,) int64
    pairs: int
    erf_evals: int

    def dense(self) -> np.ndarray:
        t = np.ones((self.width * self.width, self.K), np.float32)
        t[self.pixels, self.kmin:self.kmax + 1] = self.values
        return t.reshape(self.width, self.width, self.K)


def light_basis(direction) -> np.ndarray:
    """(3, 3) rows ``e1, e2, l`` (right-handed, ``l`` the unit propagation direction)."""
    l = unit_direction(direction)
    h = np.array([1.0, 0.0, 0.0]) if abs(l[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(h, l)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(l, e1)
    return np.stack([e1, e2, l])


@njit(cache=True, fastmath=False)
def _coords(x, y, z, c, B, S, h, tb, ds):
    rx, ry, rz = x - c[0], y - c[1], z - c[2]
    p1 = rx * B[0, 0] + ry * B[0, 1] + rz * B[0, 2]
    p2 = rx * B[1, 0] + ry * B[1, 1] + rz * B[1, 2]
    s = rx * B[2, 0] + ry * B[2, 1] + rz * B[2, 2]
    return (p1 + 0.5 * S) / h - 0.5, (p2 + 0.5 * S) / h - 0.5, (s - tb) / ds - 0.5


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _stencils(pts, c, B, w, K, S, h, tb, ds, pix, kk):
    for m in prange(pts.shape[0]):
        fx, fy, fk = _coords(pts[m, 0], pts[m, 1], pts[m, 2], c, B, S, h, tb, ds)
        i0 = min(max(int(math.floor(fx)), 0), w - 2)
        j0 = min(max(int(math.floor(fy)), 0), w - 2)
        n = 0
        for di in range(2):
            for dj in range(2):
                pix[m, n] = (i0 + di) * w + j0 + dj
                n += 1
        fk = min(max(fk, 0.0), K - 1.0)
        k0 = int(math.floor(fk))
        kk[m, 0] = k0
        kk[m, 1] = min(k0 + 1, K - 1)


@njit(cache=True, fastmath=False)
def _bin(mu, cov, c, B, w, S, h, k_sigma, tile_active):
    n = mu.shape[0]
    wt = w // TILE
    circ = np.empty((n, 3))
    counts = np.zeros(wt * wt, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            start = np.zeros(wt * wt + 1, np.int64)
            for t in range(wt * wt):
                start[t + 1] = start[t] + counts[t]
            fill = start[:-1].copy()
            items = np.empty(start[wt * wt], np.int64)
        else:
            start = np.zeros(1, np.int64)
            fill = np.zeros(1, np.int64)
            items = np.zeros(1, np.int64)
        for i in range(n):
            if pass_ == 0:
                fx, fy, _ = _coords(mu[i, 0], mu[i, 1], mu[i, 2], c, B, S, h, 0.0, 1.0)
                s00, s01, s02, s11, s12, s22 = cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5]
                p = 0.0
                q = 0.0
                o = 0.0
                for a in range(3):
                    for b in range(3):
                        sab = (s00 if a == 0 and b == 0 else s11 if a == 1 and b == 1 else s22 if a == 2 and b == 2
                               else s01 if a + b == 1 else s02 if a + b == 2 else s12)
                        p += B[0, a] * sab * B[0, b]
                        q += B[1, a] * sab * B[1, b]
                        o += B[0, a] * sab * B[1, b]
                lam1 = 0.5 * (p + q) + math.sqrt(0.25 * (p - q) * (p - q) + o * o)
                r = k_sigma * math.sqrt(max(lam1, 0.0))
                circ[i, 0] = (fx + 0.5) * h - 0.5 * S  # grid-plane coordinates of mu
                circ[i, 1] = (fy + 0.5) * h - 0.5 * S
                circ[i, 2] = r
            fx = (circ[i, 0] + 0.5 * S) / h - 0.5
            fy = (circ[i, 1] + 0.5 * S) / h - 0.5
            rp = circ[i, 2] / h + 1.0
            tx0 = max(int(math.floor((fx - rp) / TILE)), 0)
            tx1 = min(int(math.floor((fx + rp) / TILE)), wt - 1)
            ty0 = max(int(math.floor((fy - rp) / TILE)), 0)
            ty1 = min(int(math.floor((fy + rp) / TILE)), wt - 1)
            for tx in range(tx0, tx1 + 1):
                for ty in range(ty0, ty1 + 1):
                    t = tx * wt + ty
                    if not tile_active[t]:
                        continue
                    if pass_ == 0:
                        counts[t] += 1
                    else:
                        items[fill[t]] = i
                        fill[t] += 1
    return start, items, circ


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _accumulate(occ, dir_dep, c, B, pixels, w, S, h, tb, ds, kmin, kmax, use_tiles, tile_start, tile_items, circ,
                bin_skip, out, pairs, erfs):
    nk = kmax - kmin + 1
    wt = w // TILE
    lx, ly, lz = B[2, 0], B[2, 1], B[2, 2]
    n_all = occ.shape[0]
    for p in prange(pixels.shape[0]):
        i = pixels[p] // w
        j = pixels[p] % w
        p1 = -0.5 * S + (i + 0.5) * h
        p2 = -0.5 * S + (j + 0.5) * h
        ox = c[0] + p1 * B[0, 0] + p2 * B[1, 0]
        oy = c[1] + p1 * B[0, 1] + p2 * B[1, 1]
        oz = c[2] + p1 * B[0, 2] + p2 * B[1, 2]
        tau = np.zeros((1, nk))
        diff = np.zeros((1, nk))
        ne = 0
        npairs = 0
        if use_tiles:
            t = (i // TILE) * wt + j // TILE
            for q in range(tile_start[t], tile_start[t + 1]):
                o = tile_items[q]
                du = p1 - circ[o, 0]
                dv = p2 - circ[o, 1]
                if du * du + dv * dv > circ[o, 2] * circ[o, 2]:
                    continue
                npairs += 1
                ne += _accumulate_one(occ, o, ox, oy, oz, lx, ly, lz, dir_dep, ds, kmin, kmax, bin_skip, tau, diff,
                                      0, -np.inf, tb)
        else:
            for o in range(n_all):
                npairs += 1
                ne += _accumulate_one(occ, o, ox, oy, oz, lx, ly, lz, dir_dep, ds, kmin, kmax, bin_skip, tau, diff,
                                      0, -np.inf, tb)
        run = 0.0
        for k in range(nk):
            run += diff[0, k]
            out[p, k] = math.exp(-(tau[0, k] + run))
        pairs[p] = npairs
        erfs[p] = ne


def build_directional(direction, occ, dir_dep: int, cov6, roi_points, width: int = 512, K: int = 64,
                      k_sigma: float = 3.0, use_tiles: bool = True, bin_skip: bool = True) -> DirAtlas:
    """Build the directional DGSM over the voxels needed by ``roi_points`` (M, 3).

    direction: (3,) propagation direction of the light (normalised here); occ, dir_dep:
    ``dgsm_model`` packing; cov6: (N, 6) covariances (culling only); width: grid side W
    (multiple of 8, >= 8); K: depth bins (>= 2)."""
    B = light_basis(direction)
    pts = check_points("ROI points", roi_points)
    if width % TILE or width < TILE or K < 2:
        raise ValueError(f"width must be a positive multiple of {TILE} and K >= 2 (got {width}, {K})")
    if len(pts) == 0:
        z = np.zeros(0, np.int64)
        return DirAtlas(width, K, np.zeros(3), B, 1.0, 0.0, 1.0, 0, -1, np.full(width * width, -1, np.int32),
                        np.zeros((0, 0), np.float32), z, 0, 0)
    proj = pts @ B.T
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    mid = 0.5 * (lo + hi)
    c = B[0] * mid[0] + B[1] * mid[1]
    ext = max(hi[0] - lo[0], hi[1] - lo[1], 1e-6)
    h = ext / (width - 2) * (1 + 1e-9)
    S = h * width
    s_min, s_max = lo[2], hi[2]
    ds = max(s_max - s_min, 1e-6) / (K - 1)
    tb = s_min - c @ B[2] - 0.5 * ds
    pix = np.empty((len(pts), 4), np.int64)
    kk = np.empty((len(pts), 2), np.int64)
    _stencils(pts, c, B, width, K, S, h, tb, ds, pix, kk)
    mask = np.zeros(width * width, np.bool_)
    mask[pix.ravel()] = True
    pixels = np.flatnonzero(mask)
    kmin, kmax = int(kk[:, 0].min()), int(kk[:, 1].max())
    index, out, pairs, erfs = atlas_buffers(width * width, pixels, kmin, kmax)
    occ = np.ascontiguousarray(occ, dtype=np.float64)
    wt = width // TILE
    active = np.zeros(wt * wt, np.bool_)
    active[(pixels // width // TILE) * wt + (pixels % width) // TILE] = True
    if occ.shape[0]:
        start, items, circ = _bin(np.ascontiguousarray(occ[:, :3]), np.ascontiguousarray(cov6, dtype=np.float64), c, B,
                                  width, S, h, float(k_sigma), active)
        _accumulate(occ, int(dir_dep), c, B, pixels, width, S, h, tb, ds, kmin, kmax, bool(use_tiles), start, items,
                    circ, bool(bin_skip), out, pairs, erfs)
    return DirAtlas(width, K, c, B, h, tb, ds, kmin, kmax, index, out, pixels, int(pairs.sum()), int(erfs.sum()))


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _lookup(index, values, w, K, kmin, kmax, c, B, S, h, tb, ds, pts, out):
    for m in prange(pts.shape[0]):
        fx, fy, fk = _coords(pts[m, 0], pts[m, 1], pts[m, 2], c, B, S, h, tb, ds)
        fx = min(max(fx, 0.0), w - 1.0)
        fy = min(max(fy, 0.0), w - 1.0)
        fk = min(max(fk, 0.0), K - 1.0)
        i0 = min(int(math.floor(fx)), w - 2)
        j0 = min(int(math.floor(fy)), w - 2)
        k0 = min(int(math.floor(fk)), K - 2)
        wx, wy, wk = fx - i0, fy - j0, fk - k0
        acc = 0.0
        for di in range(2):
            for dj in range(2):
                wij = (wx if di else 1.0 - wx) * (wy if dj else 1.0 - wy)
                r = index[(i0 + di) * w + j0 + dj]
                for dk in range(2):
                    k = k0 + dk
                    v = 1.0 if (r < 0 or k < kmin or k > kmax) else values[r, k - kmin]
                    acc += wij * (wk if dk else 1.0 - wk) * v
        out[m] = min(max(acc, 0.0), 1.0)


def lookup_directional(atlas: DirAtlas, points) -> np.ndarray:
    """(M,) float64 trilinear transmittance of a ``DirAtlas`` at world ``points`` (M, 3)."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(pts))
    _lookup(atlas.index, atlas.values, atlas.width, atlas.K, atlas.kmin, atlas.kmax, atlas.centre, atlas.basis,
            atlas.h * atlas.width, atlas.h, atlas.tb, atlas.ds, pts, out)
    return out


def pixel_rays(atlas: DirAtlas) -> tuple[np.ndarray, np.ndarray]:
    """World points of the ROI voxel centres (|P|*(kmax-kmin+1), 3) and the light direction."""
    w = atlas.width
    i, j = atlas.pixels // w, atlas.pixels % w
    S = atlas.h * w
    p1 = -0.5 * S + (i + 0.5) * atlas.h
    p2 = -0.5 * S + (j + 0.5) * atlas.h
    ks = np.arange(atlas.kmin, atlas.kmax + 1)
    s = atlas.tb + (ks + 0.5) * atlas.ds
    e1, e2, l = atlas.basis
    base = atlas.centre + p1[:, None] * e1 + p2[:, None] * e2
    return (base[:, None, :] + s[None, :, None] * l).reshape(-1, 3), l
