"""DGSM lookup (paper sec. 3.3 and ablation A of sec. 4.4).

``lookup_point``: trilinear interpolation of a point-light ``Atlas`` at world points: bilinear
over the 4 fold-wrapped octahedral pixels around ``psi(d)`` and linear over the two radial
bins around ``t = |x - o|`` (continuous bin coordinate ``t K / t_max - 1/2``). Below the first
bin centre (``t < t_max / 2K``) it is interpolated linearly in ``t`` towards ``T = 1`` at the light;
beyond the last centre it is clamped. Voxels outside ``P x [kmin, kmax]`` read as 1.

Footprint sampling of receiver Gaussians (centre ``mu``, rotation ``R``, scales ``s``):
``x_i = mu + R (s * z_i)``, ``T = sum_i w_i T(x_i)``:

- ``center``: ``z = 0``, ``w = 1``.
- ``stencil7``: ``z`` in {0, +-e_x, +-e_y, +-e_z} (one sigma along each principal axis),
  weights proportional to the Gaussian kernel ``exp(-|z|^2/2)`` (1 and ``e^-1/2``), normalised.
- ``mc``: ``z ~ N(0, I)`` drawn independently per receiver from ``numpy.random.default_rng(seed)``
  (deterministic for a given seed and receiver count), ``w = 1/n``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .dgsm_build import cone_hits
from .dgsm_model import depth_from_light_call, depth_from_offset, light_offset
from .jit_options import prange_only, threaded
from .octahedral import oct_encode, uv_to_pixel_coords, wrap_pixel
from .quaternion import quat_to_rotation
from .thread_chunks import run_chunks


@njit(cache=True, fastmath=False, inline="always")
def _voxel_at(index, values, kmin, kmax, p, k):
    r = index[p]
    if r < 0 or k < kmin or k > kmax:
        return 1.0
    return values[r, k - kmin]


@njit(cache=True, fastmath=False)
def lookup_one(index, values, w, K, t_max, kmin, kmax, ox, oy, oz, x, y, z):
    v, lo, hi = lookup_one_range(index, values, w, K, t_max, kmin, kmax, ox, oy, oz, x, y, z)
    return v


@njit(cache=True, fastmath=False)
def lookup_one_range(index, values, w, K, t_max, kmin, kmax, ox, oy, oz, x, y, z):
    """Trilinear value and the min / max of the voxels it used (weights > 0)."""
    vx = x - ox
    vy = y - oy
    vz = z - oz
    t = math.sqrt(vx * vx + vy * vy + vz * vz)
    if t == 0.0:
        return 1.0, 1.0, 1.0
    u, v = oct_encode(vx, vy, vz)
    fx, fy = uv_to_pixel_coords(u, v, w)
    i0 = math.floor(fx)
    j0 = math.floor(fy)
    wx = fx - i0
    wy = fy - j0
    fk = t * K / t_max - 0.5
    if fk > K - 1:
        fk = K - 1.0
    if fk < 0.0:  # between the light (T = 1 at t = 0) and the first bin centre (t = dt/2)
        k0 = -1.0
        wk = 2.0 * t * K / t_max
    else:
        k0 = math.floor(fk)
        wk = fk - k0
    i0 = int(i0)
    j0 = int(j0)
    a0, b0 = wrap_pixel(i0, j0, w)
    a1, b1 = wrap_pixel(i0, j0 + 1, w)
    a2, b2 = wrap_pixel(i0 + 1, j0, w)
    a3, b3 = wrap_pixel(i0 + 1, j0 + 1, w)
    return _blend_voxels(index, values, kmin, kmax, a0 * w + b0, a1 * w + b1, a2 * w + b2, a3 * w + b3, wx, wy, wk,
                         int(k0))


@njit(cache=True, fastmath=False, inline="always")
def _blend_voxels(index, values, kmin, kmax, p00, p01, p10, p11, wx, wy, wk, k0):
    """The trilinear blend of :func:`lookup_one_range` over the flat pixel ids ``p<di><dj>`` of the
    corners (i0 + di, j0 + dj), bins ``k0`` and ``k0 + 1``: ``(value, min, max of the voxels used)``."""
    acc = 0.0
    lo = 1.0
    hi = 0.0
    for c in range(4):
        di, dj = c >> 1, c & 1
        wij = (wx if di else 1.0 - wx) * (wy if dj else 1.0 - wy)
        if wij == 0.0:
            continue
        p = p00 if c == 0 else (p01 if c == 1 else (p10 if c == 2 else p11))
        a = _voxel_at(index, values, kmin, kmax, p, k0)
        b = _voxel_at(index, values, kmin, kmax, p, k0 + 1) if wk > 0.0 else a
        acc += wij * ((1.0 - wk) * a + wk * b)
        lo = min(lo, a, b)
        hi = max(hi, a, b)
    return min(max(acc, 0.0), 1.0), lo, hi


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _lookup_point(index, values, w, K, t_max, kmin, kmax, light, pts, out):
    for m in prange(pts.shape[0]):
        out[m] = lookup_one(index, values, w, K, t_max, kmin, kmax, light[0], light[1], light[2],
                            pts[m, 0], pts[m, 1], pts[m, 2])


def lookup_point(atlas, light, points) -> np.ndarray:
    """(M,) float64 trilinear transmittance of ``atlas`` (``dgsm_build.Atlas``) at ``points``."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(pts.shape[0])
    _lookup_point(atlas.index, atlas.values, atlas.width, atlas.K, atlas.t_max, atlas.kmin, atlas.kmax,
                  np.asarray(light, dtype=np.float64), pts, out)
    return out


@njit(cache=True, fastmath=False, inline="always")
def _culling_tile(pts, m, light, w):
    """The flat id of the 8x8 culling tile (``dgsm_build.bin_tiles``) of point ``pts[m]``'s direction."""
    wt = w // 8
    u, v = oct_encode(pts[m, 0] - light[0], pts[m, 1] - light[1], pts[m, 2] - light[2])
    fx, fy = uv_to_pixel_coords(u, v, w)
    ti, tj = wrap_pixel(int(math.floor(fx / 8.0)), int(math.floor(fy / 8.0)), wt)
    return ti * wt + tj


@njit(cache=True, **threaded(), fastmath=False)
def _lookup_flag(i0_, i1_, index, values, w, K, t_max, kmin, kmax, light, pts, contrast, out, refined, tile):
    ox, oy, oz = light[0], light[1], light[2]
    for m in range(i0_, i1_):
        val, lo, hi = lookup_one_range(index, values, w, K, t_max, kmin, kmax, ox, oy, oz, pts[m, 0], pts[m, 1],
                                       pts[m, 2])
        out[m] = val
        refined[m] = hi - lo > contrast
        tile[m] = _culling_tile(pts, m, light, w) if refined[m] else -1


@njit(cache=True, **threaded(), fastmath=False)
def _lookup_flag_stencils(i0_, i1_, index, values, w, kmin, kmax, light, pts, pix, wts, k0s, contrast, out, refined,
                          tile):
    """:func:`_lookup_flag` from the points' ``dgsm_build.Stencils`` (``pix``, ``wts``, ``k0s``):
    the same blend, in the same order, of the same voxels with the same weights."""
    for m in range(i0_, i1_):
        k0 = k0s[m]
        if k0 == -2:  # at the light
            out[m] = 1.0
            refined[m] = False
            tile[m] = -1
            continue
        val, lo, hi = _blend_voxels(index, values, kmin, kmax, pix[m, 0], pix[m, 1], pix[m, 2], pix[m, 3],
                                    wts[m, 0], wts[m, 1], wts[m, 2], k0)
        out[m] = val
        refined[m] = hi - lo > contrast
        tile[m] = _culling_tile(pts, m, light, w) if refined[m] else -1


@njit(cache=True, fastmath=False)
def _refine_group(g, light, pts, rows, gstart, gtile, occ, dir_dep, use_tiles, tile_start, tile_items, glob, cone,
                  out):
    """Group ``g`` of :func:`_refine_groups` (a called function, not the parallel loop's inlined
    body, which numba would type twice)."""
    ox, oy, oz = light[0], light[1], light[2]
    r0 = gstart[g]
    n = gstart[g + 1] - r0
    dxs = np.empty(n)
    dys = np.empty(n)
    dzs = np.empty(n)
    ts = np.empty(n)
    tau = np.zeros(n)
    hit = np.zeros(n, np.bool_)
    for a in range(n):
        m = rows[r0 + a]
        vx, vy, vz = pts[m, 0] - ox, pts[m, 1] - oy, pts[m, 2] - oz
        t = math.sqrt(vx * vx + vy * vy + vz * vz)
        ts[a] = t
        dxs[a], dys[a], dzs[a] = vx / t, vy / t, vz / t
    if use_tiles:
        tt = gtile[g]
        for q in range(tile_start[tt], tile_start[tt + 1]):
            o = tile_items[q]
            if cone_hits(dxs, dys, dzs, n, cone, o, hit) == 0:
                continue
            p0, p1, p2 = light_offset(occ, o, ox, oy, oz)  # (every ray leaves the light)
            for a in range(n):
                if hit[a]:
                    tau[a] += depth_from_offset(occ, o, p0, p1, p2, dxs[a], dys[a], dzs[a], ts[a], dir_dep)
        for a in range(n):  # the global list (few occluders) and the no-culling ablation: calls, not inlined
            for q in range(glob.shape[0]):
                tau[a] += depth_from_light_call(occ, glob[q], ox, oy, oz, dxs[a], dys[a], dzs[a], ts[a], dir_dep)
    else:
        for a in range(n):
            for o in range(occ.shape[0]):
                tau[a] += depth_from_light_call(occ, o, ox, oy, oz, dxs[a], dys[a], dzs[a], ts[a], dir_dep)
    for a in range(n):
        out[rows[r0 + a]] = math.exp(-tau[a])


@njit(cache=True, **threaded(), fastmath=False)
def _refine_groups(i0_, i1_, light, pts, rows, gstart, gtile, occ, dir_dep, use_tiles, tile_start, tile_items, glob,
                   cone, out):
    """Exact depth for the flagged points, grouped by culling tile: each tile's occluder list
    is read once and cone-tested (vectorised) against all of the group's point directions."""
    for g in range(i0_, i1_):
        _refine_group(np.int64(g), light, pts, rows, gstart, gtile, occ, dir_dep, use_tiles, tile_start, tile_items,
                      glob, cone, out)


def lookup_point_refined(atlas, light, points, occ, dir_dep: int, contrast: float = 0.1, group: int = 64,
                         stencils=None):
    """Trilinear lookup with edge-adaptive exact refinement (beyond the paper).

    Where the voxels a lookup blends differ by more than ``contrast`` (a shadow edge sharper
    than the atlas resolves), the transmittance is recomputed exactly on the point's own ray
    from the occluders of the atlas's culling tile (cone-tested, plus the global list), i.e.
    exact up to the k_sigma truncation of the culling. Refined points are processed in groups
    of at most ``group`` per tile. Returns ``(values (M,) float64, refined (M,) bool)``.
    ``occ, dir_dep``: the packed occluders the atlas was built from. ``stencils``: None, or
    ``dgsm_build.point_stencils`` of these very ``points`` in this atlas (its width, K and t_max;
    e.g. ``atlas.stencils`` for its own ROI points), read instead of computed again (the same values)."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    light = np.asarray(light, dtype=np.float64)
    m = pts.shape[0]
    out = np.empty(m)
    refined = np.zeros(m, np.bool_)
    tile = np.empty(m, np.int64)
    if stencils is not None:
        if stencils.k0.shape[0] != m:
            raise ValueError(f"lookup_point_refined: stencils of {stencils.k0.shape[0]} points for {m} points")
        run_chunks(_lookup_flag_stencils, m, atlas.index, atlas.values, atlas.width, atlas.kmin, atlas.kmax, light,
                   pts, stencils.pix, stencils.wts, stencils.k0, float(contrast), out, refined, tile, min_chunk=1024)
    else:
        run_chunks(_lookup_flag, m, atlas.index, atlas.values, atlas.width, atlas.K, atlas.t_max, atlas.kmin,
                   atlas.kmax, light, pts, float(contrast), out, refined, tile, min_chunk=1024)
    rows = np.flatnonzero(refined)
    if len(rows) == 0:
        return out, refined
    if atlas.tiles is not None:
        start, items, glob, cone = atlas.tiles
        use_tiles = True
        order = np.argsort(tile[rows], kind="stable")
        rows = rows[order]
        tl = tile[rows]
        cuts = np.flatnonzero(np.diff(tl)) + 1
        bounds = np.concatenate([[0], cuts, [len(rows)]])
    else:
        start, items, glob, cone = np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4))
        use_tiles = False
        tl = np.zeros(len(rows), np.int64)
        bounds = np.array([0, len(rows)])
    # split big groups so parallel chunks stay balanced
    gs = np.unique(np.concatenate([np.arange(bounds[i], bounds[i + 1], group) for i in range(len(bounds) - 1)]
                                  + [np.array([len(rows)])])).astype(np.int64)
    gtile = tl[gs[:-1]].astype(np.int64)
    run_chunks(_refine_groups, len(gs) - 1, light, pts, rows.astype(np.int64), gs, gtile, np.ascontiguousarray(occ),
               int(dir_dep), use_tiles, start, items, glob, cone, out, chunks_per_thread=8)
    return out, refined


# ----------------------------------------------------------------- footprints
STENCIL7 = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def stencil_offsets(mode: str, n: int, m: int, seed: int = 0):
    """Offsets ``z`` (m, n', 3) float64 and weights (n',) for ``m`` receivers.

    mode ``center`` (n' = 1), ``stencil7`` (n' = 7, n ignored) or ``mc`` (n' = n >= 1)."""
    if mode == "center":
        return np.zeros((m, 1, 3)), np.ones(1)
    if mode == "stencil7":
        w = np.exp(-0.5 * np.sum(STENCIL7 ** 2, axis=1))
        return np.broadcast_to(STENCIL7, (m, 7, 3)), w / w.sum()
    if mode == "mc":
        if n < 1:
            raise ValueError(f"n_samples must be >= 1 for Monte Carlo footprints, got {n}")
        z = np.random.default_rng(seed).standard_normal((m, n, 3))
        return z, np.full(n, 1.0 / n)
    raise ValueError(f"unknown footprint sampling {mode!r}; expected 'center', 'stencil7' or 'mc'")


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _footprint_points(mu, rot, scales, z, out):
    m = mu.shape[0]
    n = z.shape[1]
    for r in prange(m):
        for s in range(n):
            a0 = scales[r, 0] * z[r, s, 0]
            a1 = scales[r, 1] * z[r, s, 1]
            a2 = scales[r, 2] * z[r, s, 2]
            for c in range(3):
                out[r * n + s, c] = mu[r, c] + rot[r, c, 0] * a0 + rot[r, c, 1] * a1 + rot[r, c, 2] * a2


def footprint_points(mu, rot, scales, z) -> np.ndarray:
    """(m*n, 3) float64 sample points ``mu + R (s * z)``; mu (m, 3), rot (m, 3, 3) acting on
    column vectors, scales (m, 3) sigma in metres, z (m, n, 3)."""
    mu = np.ascontiguousarray(mu, dtype=np.float64)
    z = np.ascontiguousarray(z, dtype=np.float64)
    out = np.empty((mu.shape[0] * z.shape[1], 3))
    _footprint_points(mu, np.ascontiguousarray(rot, dtype=np.float64), np.ascontiguousarray(scales, dtype=np.float64),
                      z, out)
    return out


def weighted_mean(values, weights) -> np.ndarray:
    """(m*n,) per-sample values -> (m,) weighted means with (n,) weights."""
    n = len(weights)
    return np.asarray(values).reshape(-1, n) @ np.asarray(weights, dtype=np.float64)


# ------------------------------------------------- fast path straight from 3DGS arrays
_GOLD = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, fastmath=False)
def _splitmix(x):
    z = x + _GOLD
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, fastmath=False)
def _uniform(seed, rid, s, c):
    h = _splitmix(np.uint64(seed) * np.uint64(0x100000001B3) ^ _splitmix(np.uint64(rid) * np.uint64(64)
                                                                         + np.uint64(s * 4 + c)))
    return (float(h >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)


@njit(cache=True, fastmath=False)
def hash_normals(seed, rid, s):
    """Three N(0, 1) numbers for (seed, receiver id, sample): a counter-based hash
    (splitmix64) and Box-Muller, so a receiver's samples depend only on the seed and its own
    index, not on which other receivers are in the ROI."""
    u1 = _uniform(seed, rid, s, 0)
    u2 = _uniform(seed, rid, s, 1)
    u3 = _uniform(seed, rid, s, 2)
    u4 = _uniform(seed, rid, s, 3)
    r1 = math.sqrt(-2.0 * math.log(u1))
    r2 = math.sqrt(-2.0 * math.log(u3))
    return r1 * math.cos(2.0 * math.pi * u2), r1 * math.sin(2.0 * math.pi * u2), r2 * math.cos(2.0 * math.pi * u4)


@njit(cache=True, **threaded(), fastmath=False)
def _footprints_q(i0_, i1_, pos, quat, scales, idx, mode, n, seed, out):
    for r in range(i0_, i1_):
        g = idx[r]
        if mode == 0:  # the centre: no rotation needed (mu + R 0 = mu)
            out[r, 0] = pos[g, 0]
            out[r, 1] = pos[g, 1]
            out[r, 2] = pos[g, 2]
            continue
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(
            float(quat[g, 0]), float(quat[g, 1]), float(quat[g, 2]), float(quat[g, 3]))
        for s in range(n):
            if mode == 0:
                z0, z1, z2 = 0.0, 0.0, 0.0
            elif mode == 1:
                z0, z1, z2 = STENCIL7[s, 0], STENCIL7[s, 1], STENCIL7[s, 2]
            else:
                z0, z1, z2 = hash_normals(seed, g, s)
            a0 = float(scales[g, 0]) * z0
            a1 = float(scales[g, 1]) * z1
            a2 = float(scales[g, 2]) * z2
            o = r * n + s
            out[o, 0] = pos[g, 0] + r00 * a0 + r01 * a1 + r02 * a2
            out[o, 1] = pos[g, 1] + r10 * a0 + r11 * a1 + r12 * a2
            out[o, 2] = pos[g, 2] + r20 * a0 + r21 * a1 + r22 * a2


def footprint_points_gaussians(positions, quaternions, scales, idx, mode: str, n: int, seed: int = 0):
    """Sample points (len(idx)*n', 3) float64 and weights (n',) for receivers ``idx`` of a 3DGS
    set (positions (N, 3) m, quaternions (N, 4) (w, x, y, z), scales (N, 3) sigma m), in one
    parallel pass. ``mc`` offsets come from ``hash_normals(seed, receiver index, sample)``
    (deterministic per seed and receiver); ``stencil7`` / ``center`` as ``stencil_offsets``."""
    if mode == "center":
        code, nn, w = 0, 1, np.ones(1)
    elif mode == "stencil7":
        code, nn = 1, 7
        w = np.exp(-0.5 * np.sum(STENCIL7 ** 2, axis=1))
        w = w / w.sum()
    elif mode == "mc":
        if n < 1:
            raise ValueError(f"n_samples must be >= 1 for Monte Carlo footprints, got {n}")
        code, nn, w = 2, int(n), np.full(int(n), 1.0 / n)
    else:
        raise ValueError(f"unknown footprint sampling {mode!r}; expected 'center', 'stencil7' or 'mc'")
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    out = np.empty((len(idx) * nn, 3))
    run_chunks(_footprints_q, idx.shape[0], np.ascontiguousarray(positions), np.ascontiguousarray(quaternions),
               np.ascontiguousarray(scales), idx, code, nn, int(seed) & 0x7FFFFFFFFFFFFFFF, out, min_chunk=1024)
    return out, w


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _roi_count(pos, c, R, ha, aa, ba, lo, hi, chunk, counts, firstbad):
    n = pos.shape[0]
    nch = counts.shape[0]
    for ch in prange(nch):
        cnt = 0
        bad = -1
        for i in range(ch * chunk, min((ch + 1) * chunk, n)):
            x, y, z = float(pos[i, 0]), float(pos[i, 1]), float(pos[i, 2])
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
                if bad < 0:
                    bad = i
                continue
            if (abs(float(pos[i, aa]) - c[aa]) <= R and abs(float(pos[i, ba]) - c[ba]) <= R
                    and lo <= float(pos[i, ha]) <= hi):
                cnt += 1
        counts[ch] = cnt
        firstbad[ch] = bad


@njit(cache=True, parallel=prange_only(), fastmath=False)
def _roi_fill(pos, c, R, ha, aa, ba, lo, hi, chunk, starts, out):
    n = pos.shape[0]
    for ch in prange(starts.shape[0] - 1):
        k = starts[ch]
        for i in range(ch * chunk, min((ch + 1) * chunk, n)):
            if (abs(float(pos[i, aa]) - c[aa]) <= R and abs(float(pos[i, ba]) - c[ba]) <= R
                    and lo <= float(pos[i, ha]) <= hi):
                out[k] = i
                k += 1


def roi_box(positions, centre, radius: float, height_axis: int, lo: float, hi: float):
    """Indices (sorted, int64) of ``positions`` (N, 3) inside the ROI box
    ``|x_a - c_a| <= R, |x_b - c_b| <= R, lo <= x_h <= hi`` (``a, b`` the two axes other than
    ``height_axis``) and the index of the first non-finite position (-1 if none), in one
    parallel pass (non-finite positions are never selected)."""
    pos = np.ascontiguousarray(positions)
    n = pos.shape[0]
    aa, ba = [k for k in range(3) if k != height_axis]
    c = np.asarray(centre, dtype=np.float64)
    chunk = 1 << 15
    nch = max((n + chunk - 1) // chunk, 1)
    counts = np.zeros(nch, np.int64)
    firstbad = np.full(nch, -1, np.int64)
    _roi_count(pos, c, float(radius), height_axis, aa, ba, float(lo), float(hi), chunk, counts, firstbad)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    out = np.empty(starts[-1], np.int64)
    _roi_fill(pos, c, float(radius), height_axis, aa, ba, float(lo), float(hi), chunk, starts, out)
    bad = firstbad[firstbad >= 0]
    return out, int(bad[0]) if bad.size else -1
