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
linear in depth (clamped to the first/last centre). Bin skipping, tile-major threaded
accumulation and the opaque-ray early out as in ``dgsm_build``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .dgsm_build import (
    TAU_OPAQUE,
    TILE,
    _accumulate_one,
    _groups,
    _max_of,
    _saturate,
    atlas_buffers,
    deepest_bins,
    support_starts,
)
from .dgsm_exact import unit_direction
from .dgsm_model import check_points, segment_depth
from .jit_options import prange_only, threaded
from .thread_chunks import run_chunks


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
def lattice_coords(x, y, z, c, B, S, h, tb, ds):
    """Continuous pixel and bin coordinates ``(fx, fy, fk)`` of point (x, y, z) in the light-space
    lattice with origin ``c``, rows of ``B`` (e1, e2, light direction), pixel size ``h``, the atlas's
    side ``S`` centred (0: a lattice centred on ``c``), first bin at ``tb``, bin size ``ds``."""
    rx, ry, rz = x - c[0], y - c[1], z - c[2]
    p1 = rx * B[0, 0] + ry * B[0, 1] + rz * B[0, 2]
    p2 = rx * B[1, 0] + ry * B[1, 1] + rz * B[1, 2]
    s = rx * B[2, 0] + ry * B[2, 1] + rz * B[2, 2]
    return (p1 + 0.5 * S) / h - 0.5, (p2 + 0.5 * S) / h - 0.5, (s - tb) / ds - 0.5


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _stencils(pts, c, B, w, K, S, h, tb, ds, pix, kk):
    for m in prange(pts.shape[0]):
        fx, fy, fk = lattice_coords(pts[m, 0], pts[m, 1], pts[m, 2], c, B, S, h, tb, ds)
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


@njit(cache=True, **threaded(), fastmath=False)
def _circles(i0_, i1_, mu, cov, c, B, S, h, k_sigma, circ):
    """Rows i0_..i1_-1 of ``circ``: grid-plane centre, culling radius and projected-ellipse conic."""
    for i in range(i0_, i1_):
        fx, fy, _ = lattice_coords(mu[i, 0], mu[i, 1], mu[i, 2], c, B, S, h, 0.0, 1.0)
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
        det = p * q - o * o
        if det > 1e-300 and r > 0.0:  # the k_sigma ellipse's conic (pixel test), else the circle
            circ[i, 3], circ[i, 4], circ[i, 5] = q / det, -o / det, p / det
        else:
            circ[i, 3] = circ[i, 5] = k_sigma * k_sigma / max(r * r, 1e-300)
            circ[i, 4] = 0.0


@njit(cache=True, fastmath=False)
def _tile_lists(circ, w, S, h, tile_active, order):  # serial: a counting sort, milliseconds
    n = circ.shape[0]
    wt = w // TILE
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
        for ii in range(n):
            i = order[ii]
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
    return start, items


def _bin(mu, cov, c, B, w, S, h, k_sigma, tile_active, order):
    """Tile lists of the occluders (each list in the order ``order`` lists them), with each
    occluder's grid-plane centre, culling radius and projected-ellipse conic (``circ`` (N, 6)):
    the circles in threads, the lists by one serial counting sort."""
    circ = np.empty((mu.shape[0], 6))
    run_chunks(_circles, mu.shape[0], mu, cov, c, B, float(S), float(h), float(k_sigma), circ, min_chunk=8192)
    start, items = _tile_lists(circ, int(w), float(S), float(h), tile_active, np.ascontiguousarray(order, np.int64))
    return start, items, circ


@njit(cache=True, fastmath=False, inline="always")
def _ellipse_hits(p1s, p2s, n, circ, o, k2, so, cut, every, hit):
    """``hit[a]``: the first ``n`` plane points ``(p1s, p2s)`` inside occluder ``o``'s projected
    ``k_sigma`` ellipse (``circ[o]``: centre, radius, conic; ``k2 = k_sigma^2``), or all of them with
    ``every``, whose cut depth ``cut[a]`` lies beyond the occluder's support start ``so``. Returns the
    number of hits. Branch-free, so numba vectorises it over the points (``dgsm_build.cone_hits``'s
    counterpart)."""
    cx, cy, ca, cb, cc = circ[o, 0], circ[o, 1], circ[o, 3], circ[o, 4], circ[o, 5]
    nh = 0
    for a in range(n):
        du = p1s[a] - cx
        dv = p2s[a] - cy
        h = ((ca * du * du + 2.0 * cb * du * dv + cc * dv * dv <= k2) | every) & (so < cut[a])
        hit[a] = h
        nh += h
    return nh


@njit(cache=True, **threaded(), fastmath=False)
def _accumulate(g0, g1, occ, dir_dep, c, B, pix_p1, pix_p2, tb, ds, kmin, kmax, group_start, group_rows,
                group_tile, tile_start, tile_items, circ, k2, starts, limits, bin_skip, out, pairs, erfs):
    """Tile-major accumulation as ``dgsm_build._accumulate_point``: each group is the ROI pixels
    (rows of ``pixels``/``out`` in ``group_rows[group_start[g]:group_start[g+1]]``) of one 8x8
    tile, whose occluder list (sorted by the support starts ``starts``) is read once and tested
    against every pixel of the group in one vectorisable loop (the pixel centre inside the
    occluder's projected ``k_sigma`` ellipse, ``circ[o, 3:6]`` its conic, ``k2 = k_sigma^2``); a pixel takes only
    occluders whose support starts before its cut depth (``limits[p]``, the centre of the deepest
    bin its lookups read, lowered where the ray is opaque: ``dgsm_build._saturate``), the tile
    stops at the first occluder past every cut. ``group_tile[g] < 0``: no culling, every occluder (in
    ``tile_items``, sorted) for every
    pixel. A pixel's ray is ``c + pix_p1[p] e1 + pix_p2[p] e2 + s l`` (its plane coordinates, in the
    frame of ``circ[:, 0:2]``). Groups ``g0..g1-1`` (run in threads by ``thread_chunks.run_chunks``)."""
    nk = kmax - kmin + 1
    lx, ly, lz = B[2, 0], B[2, 1], B[2, 2]
    for g in range(g0, g1):
        r0 = group_start[g]
        npx = group_start[g + 1] - r0
        p1s = np.empty(npx)
        p2s = np.empty(npx)
        hit = np.zeros(npx, np.bool_)
        tau = np.zeros((npx, nk))
        diff = np.zeros((npx, nk))
        ne = np.zeros(npx, np.int64)
        npairs = np.zeros(npx, np.int64)
        acc = np.zeros(npx)
        endm = np.full(npx, -np.inf)
        cut = np.empty(npx)
        for a in range(npx):
            p = group_rows[r0 + a]
            p1s[a] = pix_p1[p]
            p2s[a] = pix_p2[p]
            cut[a] = limits[p]
        cutmax = _max_of(cut, npx)
        t = group_tile[g]
        q0, q1 = (tile_start[t], tile_start[t + 1]) if t >= 0 else (0, tile_items.shape[0])
        for q in range(q0, q1):
            o = tile_items[q]
            so = starts[o]
            if so >= cutmax:
                break  # past every pixel's cut (the list is sorted: so are all later ones)
            if _ellipse_hits(p1s, p2s, npx, circ, o, k2, so, cut, t < 0, hit) == 0:
                continue
            for a in range(npx):
                if not hit[a]:
                    continue
                npairs[a] += 1
                ox = c[0] + p1s[a] * B[0, 0] + p2s[a] * B[1, 0]
                oy = c[1] + p1s[a] * B[0, 1] + p2s[a] * B[1, 1]
                oz = c[2] + p1s[a] * B[0, 2] + p2s[a] * B[1, 2]
                r = _accumulate_one(occ, o, ox, oy, oz, lx, ly, lz, dir_dep, ds, kmin, kmax, bin_skip, tau, diff,
                                    a, -np.inf, tb)
                ne[a] += r[0]
                if _saturate(r, a, acc, endm, cut):
                    cutmax = _max_of(cut, npx)
        for a in range(npx):
            p = group_rows[r0 + a]
            run = 0.0
            for k in range(nk):
                run += diff[a, k]
                out[p, k] = math.exp(-(tau[a, k] + run))
            pairs[p] = npairs[a]
            erfs[p] = ne[a]


def dot_rows(a, v) -> np.ndarray:
    """(N,) float64 ``a @ v`` for (N, 3) ``a`` and (3,) ``v``, elementwise (no BLAS call: numpy's
    threaded BLAS made these small products up to 20x slower while the kernels' threads ran, and the
    result of an elementwise product does not depend on how the rows are split)."""
    a = np.asarray(a, np.float64)
    return a[:, 0] * v[0] + a[:, 1] * v[1] + a[:, 2] * v[2]


def _sigma_along(cov6, l) -> np.ndarray:
    """(N,) ``sqrt(l^T Sigma l)`` of (N, 6) covariances (xx, xy, xz, yy, yz, zz) along unit ``l``."""
    cv = np.asarray(cov6, np.float64)
    var = (cv[:, 0] * l[0] * l[0] + cv[:, 3] * l[1] * l[1] + cv[:, 5] * l[2] * l[2]
           + 2.0 * (cv[:, 1] * l[0] * l[1] + cv[:, 2] * l[0] * l[2] + cv[:, 4] * l[1] * l[2]))
    return np.sqrt(np.maximum(var, 0.0))


def _projected_box(B, pts):
    """``(c, ext, lo, hi)``: the grid's reference point (centre of the points' projected bounding
    box, on the plane through the origin orthogonal to ``l``), the box's larger side and the
    per-axis minima/maxima of ``pts @ B.T`` (grid coordinates and depth)."""
    proj = np.stack([dot_rows(pts, B[0]), dot_rows(pts, B[1]), dot_rows(pts, B[2])], axis=1)
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    mid = 0.5 * (lo + hi)
    return B[0] * mid[0] + B[1] * mid[1], max(hi[0] - lo[0], hi[1] - lo[1], 1e-6), lo, hi


def roi_pixel_count(direction, roi_points, width: int = 512) -> int:
    """Number of grid pixels the bilinear stencils of ``roi_points`` (M, 3) touch in a
    :func:`build_directional` grid of side ``width``: the pixel columns an atlas would compute."""
    B = light_basis(direction)
    pts = check_points("ROI points", roi_points)
    if len(pts) == 0:
        return 0
    c, ext, _, _ = _projected_box(B, pts)
    h = ext / (width - 2) * (1 + 1e-9)
    pix = np.empty((len(pts), 4), np.int64)
    kk = np.empty((len(pts), 2), np.int64)
    _stencils(pts, c, B, width, 2, h * width, h, 0.0, 1.0, pix, kk)
    mask = np.zeros(width * width, np.bool_)
    mask[pix.ravel()] = True
    return int(mask.sum())


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
    c, ext, lo, hi = _projected_box(B, pts)
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
        starts = support_starts(dot_rows(occ[:, :3] - c, B[2]), occ, k_sigma, _sigma_along(cov6, B[2]))
        order = np.argsort(starts, kind="stable").astype(np.int64)
        start, items, circ = _bin(np.ascontiguousarray(occ[:, :3]), np.ascontiguousarray(cov6, dtype=np.float64), c, B,
                                  width, S, h, float(k_sigma), active, order)
        if not use_tiles:
            items = order
        gs, rows, gt = _groups(pixels, width, use_tiles)
        limits = tb + (deepest_bins(pix, kk, pixels, width * width) + 0.5) * ds
        run_chunks(_accumulate, len(gs) - 1, occ, int(dir_dep), c, B, -0.5 * S + (pixels // width + 0.5) * h,
                   -0.5 * S + (pixels % width + 0.5) * h, tb, ds, kmin, kmax, gs, rows, gt, start, items, circ,
                   float(k_sigma) ** 2, starts, limits, bool(bin_skip), out, pairs, erfs, chunks_per_thread=8)
    return DirAtlas(width, K, c, B, h, tb, ds, kmin, kmax, index, out, pixels, int(pairs.sum()), int(erfs.sum()))


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _lookup(index, values, w, K, kmin, kmax, c, B, S, h, tb, ds, pts, out):
    for m in prange(pts.shape[0]):
        fx, fy, fk = lattice_coords(pts[m, 0], pts[m, 1], pts[m, 2], c, B, S, h, tb, ds)
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


# ------------------------------------------------------------------ exact at points
#: tile side of :func:`transmittance_points`' occluder buckets, in median culling radii
TILE_RADII = 2.0

@njit(cache=True, **threaded(), fastmath=False)
def _point_depths(g0, g1, occ, dir_dep, c, B, pts, group_start, group_rows, group_tile, tile_start, tile_items,
                  circ, k2, starts, out, pairs):
    """Optical depth on each point's own ray towards the light, grouped like the atlas pixels (the
    points of one 8x8 tile per group, the tile's occluder list sorted by support start and
    ellipse-tested for the whole group): a point takes the occluders whose support starts before
    its own depth and stops when its ray is opaque (``dgsm_build.TAU_OPAQUE``)."""
    lx, ly, lz = B[2, 0], B[2, 1], B[2, 2]
    for g in range(g0, g1):
        r0 = group_start[g]
        npx = group_start[g + 1] - r0
        p1s = np.empty(npx)
        p2s = np.empty(npx)
        cut = np.empty(npx)
        acc = np.zeros(npx)
        hit = np.zeros(npx, np.bool_)
        npairs = np.zeros(npx, np.int64)
        for a in range(npx):
            m = group_rows[r0 + a]
            rx, ry, rz = pts[m, 0] - c[0], pts[m, 1] - c[1], pts[m, 2] - c[2]
            p1s[a] = rx * B[0, 0] + ry * B[0, 1] + rz * B[0, 2]
            p2s[a] = rx * B[1, 0] + ry * B[1, 1] + rz * B[1, 2]
            cut[a] = rx * lx + ry * ly + rz * lz  # the point's depth
        cutmax = _max_of(cut, npx)
        t = group_tile[g]
        for q in range(tile_start[t], tile_start[t + 1]):
            o = tile_items[q]
            so = starts[o]
            if so >= cutmax:
                break
            if _ellipse_hits(p1s, p2s, npx, circ, o, k2, so, cut, False, hit) == 0:
                continue
            for a in range(npx):
                if not hit[a]:
                    continue
                m = group_rows[r0 + a]
                npairs[a] += 1
                acc[a] += segment_depth(occ, o, pts[m, 0], pts[m, 1], pts[m, 2], lx, ly, lz, -np.inf, 0.0, dir_dep)
                if acc[a] >= TAU_OPAQUE:
                    cut[a] = -np.inf
                    cutmax = _max_of(cut, npx)
        for a in range(npx):
            m = group_rows[r0 + a]
            out[m] = math.exp(-acc[a])
            pairs[m] = npairs[a]


def transmittance_points(direction, occ, dir_dep: int, cov6, points, k_sigma: float = 3.0,
                         max_width: int = 2048) -> tuple[np.ndarray, int]:
    """Exact directional transmittance at ``points`` (M, 3) metres, no atlas: ``(T (M,) float64 in
    [0, 1], pairs evaluated)``. Each point's own ray ``x + s l``, ``s <= 0``, sums the optical
    depth of the occluders whose projected ``k_sigma`` ellipse contains it (the culling of
    :func:`build_directional`: a dropped occluder adds below ``exp(-k_sigma^2/2)`` of its peak),
    in order of their support starts, stopping at the point's depth and where the ray is opaque
    (``T < exp(-TAU_OPAQUE)``). Cheaper than an atlas where the points are not much denser than
    its pixels (each atlas pixel costs about one point, times the few bins of each pair's erf
    window). Occluders are bucketed into 8x8-pixel tiles of a grid whose tile side is about two
    median culling radii (at most ``max_width`` pixels a side)."""
    B = light_basis(direction)
    pts = check_points("points", points)
    m = len(pts)
    out = np.ones(m)
    if m == 0 or occ.shape[0] == 0:
        return out, 0
    cv = np.ascontiguousarray(cov6, dtype=np.float64)
    c, ext, _, _ = _projected_box(B, pts)
    r_med = float(k_sigma) * float(np.sqrt(max(np.median(cv[:, 0] + cv[:, 3] + cv[:, 5]) / 3.0, 0.0)))
    h = max(TILE_RADII * r_med / TILE, ext / (max_width - 2), 1e-9)
    width = int(TILE * math.ceil((ext / h + 2.0) / TILE))
    S = h * width
    i = np.clip(np.floor((dot_rows(pts, B[0]) - c @ B[0] + 0.5 * S) / h), 0, width - 1).astype(np.int64)
    j = np.clip(np.floor((dot_rows(pts, B[1]) - c @ B[1] + 0.5 * S) / h), 0, width - 1).astype(np.int64)
    flat = i * width + j
    wt = width // TILE
    active = np.zeros(wt * wt, np.bool_)
    active[(i // TILE) * wt + j // TILE] = True
    occ = np.ascontiguousarray(occ, dtype=np.float64)
    starts = support_starts(dot_rows(occ[:, :3] - c, B[2]), occ, k_sigma, _sigma_along(cv, B[2]))
    # each tile list in support-start order, the occluders left where they are: copying a large
    # caster into that order cost more than the sums' scattered reads save; the same values either way
    start, items, circ = _bin(np.ascontiguousarray(occ[:, :3]), cv, c, B, width, S, h, float(k_sigma), active,
                              np.argsort(starts, kind="stable"))
    gs, rows, gt = _groups(flat, width, True)
    pairs = np.zeros(m, np.int64)
    run_chunks(_point_depths, len(gs) - 1, occ, int(dir_dep), c, B, pts, gs, rows, gt, start, items, circ,
               float(k_sigma) ** 2, starts, out, pairs, chunks_per_thread=8)
    return np.clip(out, 0.0, 1.0), int(pairs.sum())


# ------------------------------------------------------------------ shot-long lattice
LATTICE_BLOCK = 1024



def lattice_columns(B, occ, dir_dep: int, cov6, c, h: float, ij, tb: float, ds: float, K: int, k_sigma: float,
                    bin_skip: bool = True) -> tuple[np.ndarray, int]:
    """Whole voxel columns of a fixed lattice (a shot-long directional DGSM): lattice pixel
    ``(i, j)`` (rows of ``ij`` (M, 2) int64, any sign, unique) is the ray
    ``c + (i + 1/2) h e1 + (j + 1/2) h e2 + s l`` (``B`` rows ``e1, e2, l``, :func:`light_basis`),
    its K bins at depths ``s = tb + (k + 1/2) ds`` from that plane. Returns ``(T (M, K) float32,
    pairs evaluated)``. A column's values do not depend on which other columns are computed with it
    (the plane coordinates and the occluders' projected centres are taken in the lattice's own frame,
    the occluders in one global order), so a lattice filled in any order holds the same values. The
    work runs in blocks of at most ``LATTICE_BLOCK`` pixels a side, each binning only the occluders
    whose ``k_sigma`` sphere can reach it."""
    ij = np.asarray(ij, np.int64).reshape(-1, 2)
    m = ij.shape[0]
    out = np.ones((m, K), np.float32)
    occ = np.ascontiguousarray(occ, dtype=np.float64)
    if m == 0 or occ.shape[0] == 0:
        return out, 0
    cv = np.ascontiguousarray(cov6, dtype=np.float64)
    c = np.asarray(c, np.float64)
    rel = occ[:, :3] - c
    cu, cw, depth = dot_rows(rel, B[0]), dot_rows(rel, B[1]), dot_rows(rel, B[2])
    starts = support_starts(depth, occ, k_sigma, _sigma_along(cv, B[2]))
    reach = float(k_sigma) / np.min(occ[:, 12:15], axis=1) + h  # k_sigma sigma_max, plus a pixel
    blocks, inv = np.unique(ij // LATTICE_BLOCK, axis=0, return_inverse=True)
    pairs_total = 0
    for b in range(len(blocks)):
        rows_b = np.flatnonzero(inv.reshape(-1) == b)
        sub = ij[rows_b]
        i0, j0 = sub.min(axis=0)
        w = int(TILE * math.ceil((int(max(sub[:, 0].max() - i0, sub[:, 1].max() - j0)) + 1) / TILE))
        lo_u, lo_v = i0 * h, j0 * h
        cand = np.flatnonzero((cu + reach >= lo_u) & (cu - reach <= lo_u + w * h)
                              & (cw + reach >= lo_v) & (cw - reach <= lo_v + w * h))
        if cand.size == 0:
            continue
        S = w * h
        c_sub = c + (i0 * h + 0.5 * S) * B[0] + (j0 * h + 0.5 * S) * B[1]
        pixels = (sub[:, 0] - i0) * w + (sub[:, 1] - j0)
        wt = w // TILE
        active = np.zeros(wt * wt, np.bool_)
        active[(pixels // w // TILE) * wt + (pixels % w) // TILE] = True
        occ_c = np.ascontiguousarray(occ[cand])
        start, items, circ = _bin(np.ascontiguousarray(occ_c[:, :3]), np.ascontiguousarray(cv[cand]), c_sub, B, w, S, h,
                                  float(k_sigma), active, np.argsort(starts[cand], kind="stable").astype(np.int64))
        circ[:, 0], circ[:, 1] = cu[cand], cw[cand]  # in the lattice's frame, as the pixels
        gs, rows, gt = _groups(pixels, w, True)
        vals = np.ones((len(rows_b), K), np.float32)
        pairs = np.zeros(len(rows_b), np.int64)
        erfs = np.zeros(len(rows_b), np.int64)
        run_chunks(_accumulate, len(gs) - 1, occ_c, int(dir_dep), c, B, (sub[:, 0] + 0.5) * h, (sub[:, 1] + 0.5) * h,
                   float(tb), float(ds), 0, K - 1, gs, rows, gt, start, items, circ, float(k_sigma) ** 2,
                   np.ascontiguousarray(starts[cand]), np.full(len(rows_b), np.inf), bool(bin_skip), vals, pairs,
                   erfs, chunks_per_thread=8)
        out[rows_b] = vals
        pairs_total += int(pairs.sum())
    return out, pairs_total
