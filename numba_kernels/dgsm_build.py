"""DGSM build for a point light: octahedral atlas x K radial bins (paper sec. 3.2).

Table ``T[i, j, k] = exp(-tau(d(i, j), t_k))``: ``d(i, j)`` the pixel-centre direction of the
octahedral atlas (``octahedral``), ``t_k = (k + 1/2) t_max / K`` metres from the light.

Receiver-driven ROI: the caller passes the points that will be looked up (the footprint
sample points of the ROI receivers). Each point's trilinear stencil (4 fold-wrapped pixels x
2 bins) is marked; the unique pixel set ``P`` and the tight bin range ``[kmin, kmax]`` are
the only voxels computed. Storage is sparse: ``index`` (W*W,) int32 maps a flat pixel
``i*W + j`` to a row of ``values`` (|P|, kmax-kmin+1) float32, or -1; every voxel outside
``P x [kmin, kmax]`` is 1 by construction. ``use_roi=False`` computes all W*W pixels and all K
bins (the paper's ablation D).

Light-space culling (``use_tiles``): per occluder, ``Sigma_perp = [u v]^T Sigma [u v]`` on the
plane orthogonal to ``d_i = (mu_i - o)/D_i``; largest eigenvalue ``lambda_1``; angular radius
``theta = atan(k_sigma sqrt(lambda_1) / (D_i - r_i))`` with ``r_i = k_sigma sqrt(tr Sigma)``
(the k_sigma ellipsoid lies within ``r_i`` of ``mu_i``, so this is a conservative cone around
``d_i``, perspective included). Pixel radius ``theta * L * W / 2 + 1`` with ``L`` the octahedral
map's stretch over the cap times 1.2, capped at ``OCT_LIPSCHITZ``: for a small cap away from the
octants' borders (most occluders), ``1.2 (s(d_i) + STRETCH_RATE theta)`` from the map's largest
singular value ``s`` at ``d_i`` (:func:`small_cap_stretch`), else 1.2 times the largest secant
stretch from ``d_i`` to the cap's boundary in 8 directions (:func:`secant_stretch`). The first is
never below the second (``tests/test_dgsm_footprint.py``), so the tile lists hold every occluder
that the secant estimate alone would list (the atlas has the same values), and it costs no
``oct_encode``. Occluders are bucketed into 8x8-pixel tiles (fold-wrapped, deduplicated);
occluders with ``D_i <= 2 r_i`` or ``theta > 0.5`` (light inside or very near) go to a global
list every pixel gathers. Pixels are processed tile by tile: each tile's occluder list is read
once and every occluder's cone ``(d_i, cos theta)`` is tested against all the tile's pixel
directions in one vectorisable loop before any ray integral. A skipped occluder's closest
approach to the pixel ray has a Mahalanobis distance above ``k_sigma``, so its optical depth
on that ray is below ``beta sqrt(2 pi / a) exp(-k_sigma^2 / 2)`` (k_sigma = 3: 1.1 % of the
on-axis value, k_sigma = 4: 0.03 %). Pairs whose depth scale is below ``EPS_PAIR = 1e-10`` are
skipped (< 2e-10 each).

Bin skipping (``bin_skip``, beyond the paper): along one ray an occluder's cumulative depth is
``scale * (erf(z(t)) - erf(z(0)))``, saturated outside ``|z| > ZC = 6`` (erfc(6) = 2.2e-17).
Only bins inside the window get an erf; bins past it receive the constant full step through a
difference array and one prefix sum over k. The same saturation skips the erfc at the ray's
start: for a point light ``z(0) <= -ZC`` whenever the light lies outside the occluder's
6-sigma support along the ray (nearly every pair), so a pair usually costs no erfc at all, and
a pair with ``z(0) >= ZC`` (support behind the light) is dropped. Error per (pixel,
occluder) < ``2.2e-17 * scale``.

The depth cuts of the directional build (``dgsm_directional``: occluders by support start,
:func:`support_starts`; a pixel's cut at its deepest read bin and where its ray turns opaque,
:func:`_saturate`) live here with the shared pair kernel; the point-light build does not use
them: on the demo's avatar casters the rays seldom turn opaque and the receivers lie behind the
casters, so they skipped under 3 % of the pairs and their bookkeeping cost 15 % of the build.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .dgsm_model import Z_SATURATED, check_points, check_vector, light_offset, ray_params_from
from .jit_options import threaded
from .octahedral import OCT_LIPSCHITZ, oct_decode, oct_encode, pixel_center_uv, uv_to_pixel_coords, wrap_pixel
from .thread_chunks import run_chunks

ZC = Z_SATURATED
EPS_PAIR = 1e-10
TILE = 8
GLOBAL_THETA = 0.5
_CA = np.cos(np.arange(8) * np.pi / 4.0)
_SA = np.sin(np.arange(8) * np.pi / 4.0)


class Atlas(NamedTuple):
    """A built DGSM (see module doc). ``t_max`` metres; ``values`` float32."""

    width: int
    K: int
    t_max: float
    kmin: int
    kmax: int
    index: np.ndarray  # (W*W,) int32
    values: np.ndarray  # (|P|, kmax - kmin + 1) float32
    pixels: np.ndarray  # (|P|,) int64 flat pixel ids i*W + j
    pairs: int  # (pixel, occluder) pairs evaluated
    erf_evals: int  # erf differences evaluated
    # culling lists kept for exact refinement (dgsm_sample.lookup_point_refined):
    # (tile_start, tile_items, glob, cone) or None when built without tile culling
    tiles: tuple | None = None
    # the ROI points' lookup stencils (build_point's roi_points, in their order), or None
    stencils: Stencils | None = None

    def dense(self) -> np.ndarray:
        """(W, W, K) float32 table with the implicit ones filled in (tests, small W only)."""
        t = np.ones((self.width * self.width, self.K), np.float32)
        t[self.pixels, self.kmin:self.kmax + 1] = self.values
        return t.reshape(self.width, self.width, self.K)


# --------------------------------------------------------------------------- ROI
class Stencils(NamedTuple):
    """The trilinear lookup stencils of M points in a point-light atlas (:func:`point_stencils`)."""

    pix: np.ndarray  # (M, 4) int64 flat ids of the fold-wrapped pixels (i0 + di, j0 + dj), (di, dj) = 00, 01, 10, 11
    kk: np.ndarray  # (M, 2) int64 the two radial bins, clamped to [0, K - 1] (the ROI's)
    wts: np.ndarray  # (M, 3) float64 the weights (wx, wy, wk) of dgsm_sample.lookup_one_range
    k0: np.ndarray  # (M,) int64 its lower bin: -1 before the first bin centre, -2 for a point at the light

    def rows(self, sub: slice) -> Stencils:
        """The stencils of the points ``sub`` (a slice: views, no copy)."""
        return Stencils(*(a[sub] for a in self))


@njit(cache=True, **threaded(), fastmath=False)
def _stencils(i0_, i1_, light, pts, w, K, t_max, pix, kk, wts, k0s):
    for m in range(i0_, i1_):
        vx = pts[m, 0] - light[0]
        vy = pts[m, 1] - light[1]
        vz = pts[m, 2] - light[2]
        t = math.sqrt(vx * vx + vy * vy + vz * vz)
        if t == 0.0:
            vx, vy, vz = 0.0, 0.0, 1.0
        u, v = oct_encode(vx, vy, vz)
        fx, fy = uv_to_pixel_coords(u, v, w)
        fi0 = math.floor(fx)
        fj0 = math.floor(fy)
        i0 = int(fi0)
        j0 = int(fj0)
        c = 0
        for di in range(2):
            for dj in range(2):
                pi, pj = wrap_pixel(i0 + di, j0 + dj, w)
                pix[m, c] = pi * w + pj
                c += 1
        fk = t * K / t_max - 0.5
        if fk > K - 1:
            fk = K - 1.0
        k0 = int(math.floor(fk))
        kk[m, 0] = max(k0, 0)
        kk[m, 1] = min(k0 + 1, K - 1)
        # the lookup's weights, as dgsm_sample.lookup_one_range computes them
        wts[m, 0] = fx - fi0
        wts[m, 1] = fy - fj0
        if t == 0.0:
            k0s[m] = -2
            wts[m, 2] = 0.0
        elif fk < 0.0:
            k0s[m] = -1
            wts[m, 2] = 2.0 * t * K / t_max
        else:
            fk0 = math.floor(fk)
            k0s[m] = int(fk0)
            wts[m, 2] = fk - fk0


def point_stencils(light, pts, w: int, K: int, t_max: float) -> Stencils:
    """:class:`Stencils` of ``pts`` (M, 3) float64 C-contiguous in the atlas of side ``w``, ``K``
    bins and range ``t_max`` of a point light at ``light`` (3,): what :func:`roi_voxels` needs and
    what ``dgsm_sample.lookup_point_refined`` (``stencils=``) then reads instead of computing
    every point's direction and bin again (the same values)."""
    m = pts.shape[0]
    st = Stencils(np.empty((m, 4), np.int64), np.empty((m, 2), np.int64), np.empty((m, 3)), np.empty(m, np.int64))
    run_chunks(_stencils, m, light, pts, w, K, t_max, *st, min_chunk=1024)
    return st


def stencil_roi(st: Stencils, w: int):
    """Unique flat pixel ids ``P`` and ``(kmin, kmax)`` covering the stencils ``st`` (empty ``P``
    and ``(0, -1)`` for none)."""
    if st.k0.shape[0] == 0:
        return np.zeros(0, np.int64), 0, -1
    mask = np.zeros(w * w, np.bool_)
    mask[st.pix.ravel()] = True
    return np.flatnonzero(mask), int(st.kk[:, 0].min()), int(st.kk[:, 1].max())


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _far_distance2(light, pts):
    best = 0.0
    for m in range(pts.shape[0]):
        dx = pts[m, 0] - light[0]
        dy = pts[m, 1] - light[1]
        dz = pts[m, 2] - light[2]
        d2 = dx * dx + dy * dy + dz * dz  # (numpy's order for a row's three terms)
        if d2 > best or d2 != d2:  # (a NaN wins, as numpy's max gives it)
            best = d2
    return best


def far_distance(light, pts) -> float:
    """Largest distance (m) from ``light`` (3,) to ``pts`` (M, 3), as ``sqrt(max(sum((pts - light)^2,
    axis=1)))`` in float64 (one pass, no temporaries)."""
    if len(pts) == 0:
        return 0.0
    p = np.ascontiguousarray(pts, np.float64).reshape(-1, 3)  # (no copy when it is one already)
    return float(np.sqrt(_far_distance2(np.asarray(light, np.float64).reshape(3), p)))


def t_max_for(t_far: float, K: int) -> float:
    """``t_max`` putting the last bin centre at (just beyond) ``t_far``: ``t_far K / (K - 1/2)``."""
    return max(t_far, 1e-6) * K / (K - 0.5) * (1.0 + 1e-9)


@njit(cache=True, fastmath=False)
def _deepest_bins(pix, kk, deep):  # serial: one pass over the stencils, milliseconds
    for m in range(pix.shape[0]):
        k = kk[m, 1]
        for c in range(pix.shape[1]):
            p = pix[m, c]
            if k > deep[p]:
                deep[p] = k


def deepest_bins(pix, kk, pixels, n_pixels: int) -> np.ndarray:
    """(len(pixels),) int64: the deepest bin that a stencil (``pix`` (M, S) flat pixel ids with
    ``kk[:, 1]`` (M,) the deeper of its two bins) reads at each of ``pixels``."""
    deep = np.full(n_pixels, -1, np.int64)
    _deepest_bins(pix, np.ascontiguousarray(kk), deep)
    return deep[pixels]


def roi_voxels(light, pts, w: int, K: int, t_max: float):
    """Unique flat pixel ids ``P`` and ``(kmin, kmax)`` covering the trilinear stencils of
    ``pts`` (M, 3). Empty ``pts`` gives an empty ``P`` and ``(0, -1)``."""
    return stencil_roi(point_stencils(light, pts, w, K, t_max), w)


# ----------------------------------------------------------------- tile culling
@njit(cache=True, fastmath=False)
def _footprint(light, mu, cov, i, w, k_sigma):
    """Returns (global?, fx, fy, radius_px, cos(theta)) of occluder i."""
    vx = mu[i, 0] - light[0]
    vy = mu[i, 1] - light[1]
    vz = mu[i, 2] - light[2]
    D = math.sqrt(vx * vx + vy * vy + vz * vz)
    s00, s01, s02, s11, s12, s22 = cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5]
    r = k_sigma * math.sqrt(max(s00 + s11 + s22, 0.0))
    if not (D > 2.0 * r) or D == 0.0:
        return True, 0.0, 0.0, 0.0, -2.0
    dx, dy, dz = vx / D, vy / D, vz / D
    # orthonormal basis (e1, e2) of the plane orthogonal to d
    if abs(dx) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    e1x = hy * dz - hz * dy
    e1y = hz * dx - hx * dz
    e1z = hx * dy - hy * dx
    n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
    e2x = dy * e1z - dz * e1y
    e2y = dz * e1x - dx * e1z
    e2z = dx * e1y - dy * e1x
    # Sigma_perp entries
    se1x = s00 * e1x + s01 * e1y + s02 * e1z
    se1y = s01 * e1x + s11 * e1y + s12 * e1z
    se1z = s02 * e1x + s12 * e1y + s22 * e1z
    se2x = s00 * e2x + s01 * e2y + s02 * e2z
    se2y = s01 * e2x + s11 * e2y + s12 * e2z
    se2z = s02 * e2x + s12 * e2y + s22 * e2z
    p = e1x * se1x + e1y * se1y + e1z * se1z
    q = e2x * se2x + e2y * se2y + e2z * se2z
    o = e1x * se2x + e1y * se2y + e1z * se2z
    lam1 = 0.5 * (p + q) + math.sqrt(0.25 * (p - q) * (p - q) + o * o)
    tan_theta = k_sigma * math.sqrt(max(lam1, 0.0)) / (D - r)
    theta = math.atan(tan_theta)
    if theta > GLOBAL_THETA:
        return True, 0.0, 0.0, 0.0, -2.0
    u0, v0 = oct_encode(dx, dy, dz)
    fx, fy = uv_to_pixel_coords(u0, v0, w)
    ct = math.cos(theta)
    lip = small_cap_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z, theta, tan_theta)
    rp = theta * lip * 0.5 * w + 1.0
    if not (lip > 0.0 and 2.0 * rp < w):  # (a near-global footprint: the global list stays the secant's)
        rp = theta * secant_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z, theta, u0, v0) * 0.5 * w + 1.0
    return False, fx, fy, rp, ct


#: bound of the rate (per radian) at which the octahedral map's largest singular value changes
#: inside an octant (measured sup 4.43 over 2e6 random caps up to 0.5 rad)
STRETCH_RATE = 5.0
#: a cap is small when ``STRETCH_RATE theta`` is at most this share of the stretch at its centre
SMALL_CAP_SLACK = 0.05


@njit(cache=True, fastmath=False)
def oct_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z):
    """Largest singular value of the octahedral map's differential at the unit direction ``d``
    (``|d(u, v)| / |d angle|`` at its largest), on the tangent plane spanned by the orthonormal
    ``e1, e2``. Inside an octant with signs ``s`` the map is ``q = d / (s . d)`` followed by its
    ``(x, y)`` part, folded for ``z < 0`` (the fold is an isometry of that part), so the
    differential takes a tangent ``t`` to ``(t - q (s . t))_xy / (s . d)``."""
    sx = 1.0 if dx >= 0.0 else -1.0
    sy = 1.0 if dy >= 0.0 else -1.0
    sz = 1.0 if dz >= 0.0 else -1.0
    ic = 1.0 / (sx * dx + sy * dy + sz * dz)
    qx = dx * ic
    qy = dy * ic
    a1 = sx * e1x + sy * e1y + sz * e1z
    a2 = sx * e2x + sy * e2y + sz * e2z
    m1x = (e1x - qx * a1) * ic
    m1y = (e1y - qy * a1) * ic
    m2x = (e2x - qx * a2) * ic
    m2y = (e2y - qy * a2) * ic
    p = m1x * m1x + m1y * m1y
    q = m2x * m2x + m2y * m2y
    o = m1x * m2x + m1y * m2y
    return math.sqrt(0.5 * (p + q) + math.sqrt(0.25 * (p - q) * (p - q) + o * o))


@njit(cache=True, fastmath=False)
def small_cap_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z, theta, tan_theta):
    """``L`` of the module doc for a small cap of angular radius ``theta`` (``tan_theta`` its
    tangent) around the unit direction ``d`` (``e1, e2``: an orthonormal basis of its tangent
    plane): ``1.2 (oct_stretch(d) + STRETCH_RATE theta)`` (at most 5 % above ``1.2 oct_stretch(d)``),
    capped at ``OCT_LIPSCHITZ``; 0 where the cap is not small (``STRETCH_RATE theta >
    SMALL_CAP_SLACK oct_stretch(d)``) or may reach an octant's border (a coordinate of ``d`` within
    ``tan theta >= sin theta`` of 0: a coordinate changes sign on the cap where it is within
    ``sin theta``; the map has a kink there), for :func:`secant_stretch` to take over."""
    if min(abs(dx), abs(dy), abs(dz)) <= tan_theta * (1.0 + 1e-9):
        return 0.0
    s = oct_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z)
    if STRETCH_RATE * theta > SMALL_CAP_SLACK * s:
        return 0.0
    return min(1.2 * (s + STRETCH_RATE * theta), OCT_LIPSCHITZ)


@njit(cache=True, fastmath=False)
def secant_stretch(dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z, theta, u0, v0):
    """The secant estimate of ``L`` (module doc): 1.2 times the largest secant stretch of the
    octahedral map from ``d`` to the boundary of the cap of radius ``theta`` in 8 directions
    (``e1, e2`` and the diagonals between them), capped at ``OCT_LIPSCHITZ`` (``OCT_LIPSCHITZ``
    for ``theta = 0``); ``(u0, v0)``: ``oct_encode(d)``, which the caller has."""
    if not theta > 0.0:
        return OCT_LIPSCHITZ
    ct = math.cos(theta)
    st = math.sin(theta)
    l2 = 0.0
    for a in range(8):
        ca = _CA[a]
        sa = _SA[a]
        tx = ca * e1x + sa * e2x
        ty = ca * e1y + sa * e2y
        tz = ca * e1z + sa * e2z
        u1, v1 = oct_encode(ct * dx + st * tx, ct * dy + st * ty, ct * dz + st * tz)
        dd = (u1 - u0) ** 2 + (v1 - v0) ** 2
        if dd > l2:
            l2 = dd
    return min(1.2 * (math.sqrt(l2) / theta), OCT_LIPSCHITZ)


@njit(cache=True, fastmath=False)
def _visit_tiles(i, fx, fy, rp, wt, tile_active, stamp, counts, items, fill, fill_mode):
    tx0 = int(math.floor((fx - rp) / TILE))
    tx1 = int(math.floor((fx + rp) / TILE))
    ty0 = int(math.floor((fy - rp) / TILE))
    ty1 = int(math.floor((fy + rp) / TILE))
    if tx0 >= 0 and ty0 >= 0 and tx1 < wt and ty1 < wt:
        # the rectangle inside the atlas (the usual case): no fold-wrap, so no tile twice and no stamp
        for tx in range(tx0, tx1 + 1):
            for t in range(tx * wt + ty0, tx * wt + ty1 + 1):
                if not tile_active[t]:
                    continue
                if fill_mode:
                    items[fill[t]] = i
                    fill[t] += 1
                else:
                    counts[t] += 1
        return
    for tx in range(tx0, tx1 + 1):
        for ty in range(ty0, ty1 + 1):
            a, b = wrap_pixel(tx, ty, wt)
            t = a * wt + b
            if not tile_active[t] or stamp[t] == i + 1:
                continue
            stamp[t] = i + 1
            if fill_mode:
                items[fill[t]] = i
                fill[t] += 1
            else:
                counts[t] += 1


@njit(cache=True, **threaded(), fastmath=False)
def _footprints(i0_, i1_, light, mu, cov, w, k_sigma, fxs, fys, rps, is_glob, cone):
    for i in range(i0_, i1_):
        g, fx, fy, rp, cth = _footprint(light, mu, cov, np.int64(i), w, k_sigma)
        if not g and 2.0 * rp >= w:
            g = True
        is_glob[i] = g
        fxs[i], fys[i], rps[i] = fx, fy, rp
        vx = mu[i, 0] - light[0]
        vy = mu[i, 1] - light[1]
        vz = mu[i, 2] - light[2]
        D = math.sqrt(vx * vx + vy * vy + vz * vz)
        if g or D == 0.0:
            cone[i, 0], cone[i, 1], cone[i, 2], cone[i, 3] = 0.0, 0.0, 0.0, -2.0
        else:
            cone[i, 0], cone[i, 1], cone[i, 2], cone[i, 3] = vx / D, vy / D, vz / D, cth


BIN_CHUNKS = 64  # at most, and at least BIN_CHUNK_MIN occluders per chunk
BIN_CHUNK_MIN = 4096


@njit(cache=True, **threaded(), fastmath=False)
def _bin_pass(c0, c1, fxs, fys, rps, is_glob, w, tile_active, step, rows, items, fill_mode):
    """One pass of :func:`_bin_tiles_chunked` for occluder chunks ``c0..c1-1``, each with its own
    stamp array: ``fill_mode`` False counts chunk c's (tile, occluder) entries into ``rows[c]``;
    True writes them to ``items`` from the offsets ``rows[c]`` on (advanced in place)."""
    n = fxs.shape[0]
    wt = w // TILE
    for c in range(c0, c1):
        stamp = np.zeros(wt * wt, np.int64)
        row = rows[c]
        for i in range(c * step, min((c + 1) * step, n)):
            if not is_glob[i]:
                _visit_tiles(i, fxs[i], fys[i], rps[i], wt, tile_active, stamp, row, items, row, fill_mode)


def _bin_tiles_chunked(fxs, fys, rps, is_glob, w, tile_active):
    """CSR tile lists built in up to ``BIN_CHUNKS`` occluder chunks in parallel (at least
    ``BIN_CHUNK_MIN`` occluders each, so small casters stay as cheap as a serial pass): each chunk counts
    its (tile, occluder) entries with its own stamp array, one prefix sum over (tile, chunk)
    gives every chunk its write offsets, and a second parallel pass fills them. Items of a
    tile come out in increasing occluder order, as a serial pass would give. Returns
    ``(start (T+1,) int64, items int64)``."""
    n = fxs.shape[0]
    wt = w // TILE
    nt = wt * wt
    nc = min(BIN_CHUNKS, max(n // BIN_CHUNK_MIN, 1))
    step = (n + nc - 1) // nc
    counts = np.zeros((nc, nt), np.int64)
    run_chunks(_bin_pass, nc, fxs, fys, rps, is_glob, int(w), tile_active, step, counts, np.zeros(1, np.int64),
               False, chunks_per_thread=1)
    # tile-major prefix sum over (tile, chunk): chunk c of tile t starts after all earlier tiles
    # and the earlier chunks of tile t
    flat = counts.T.reshape(-1)
    excl = np.concatenate([[0], np.cumsum(flat)]).astype(np.int64)
    offs = excl[:-1].reshape(nt, nc).T.copy()  # copies: the fill pass advances offs in place
    start = excl[::nc].copy()  # (nt + 1,): excl[nt * nc] is the total
    items = np.empty(int(excl[-1]), np.int64)
    run_chunks(_bin_pass, nc, fxs, fys, rps, is_glob, int(w), tile_active, step, offs, items, True,
               chunks_per_thread=1)
    return start, items


def bin_tiles(light, mu, cov6, w: int, k_sigma: float, tile_active):
    """Light-space culling: ``(tile_start (T+1,), tile_items, global_items, cone (N, 4))``.
    ``mu`` (N, >= 3) float64 C-contiguous: the occluder centres in its first three columns (the
    packed occluders ``occ`` themselves will do, without a copy).

    CSR lists of occluder ids per 8x8 tile (flat tile id ``ti * (W/8) + tj``; only tiles with
    ``tile_active`` get entries), the ids every pixel must gather, and each occluder's
    conservative cone ``(d_i, cos theta_i)`` (``cos = -2`` for global ones)."""
    n = mu.shape[0]
    fxs, fys, rps = np.empty(n), np.empty(n), np.empty(n)
    is_glob = np.zeros(n, np.bool_)
    cone = np.empty((n, 4))
    run_chunks(_footprints, mu.shape[0], light, mu, cov6, w, float(k_sigma), fxs, fys, rps, is_glob, cone,
               min_chunk=1024)
    start, items = _bin_tiles_chunked(fxs, fys, rps, is_glob, w, tile_active)
    return start, items, np.flatnonzero(is_glob).astype(np.int64), cone


@njit(cache=True, fastmath=False, inline="always")
def cone_hits(dxs, dys, dzs, n, cone, o, hit):
    """Cone test of occluder ``o`` (``cone[o] = (d, cos theta)`` of :func:`bin_tiles`) against
    the first ``n`` unit directions ``(dxs, dys, dzs)``: ``hit[a] = d_a . d >= cos theta``.
    Returns the number of hits. Branch-free, so numba vectorises it over the directions."""
    cx, cy, cz, cc = cone[o, 0], cone[o, 1], cone[o, 2], cone[o, 3]
    nh = 0
    for a in range(n):
        h = dxs[a] * cx + dys[a] * cy + dzs[a] * cz >= cc
        hit[a] = h
        nh += h
    return nh


def atlas_buffers(n_pixels: int, pixels, kmin: int, kmax: int):
    """Storage of an atlas over its ROI pixels ``pixels`` (sorted ids among ``n_pixels``) and
    bins ``kmin..kmax``: ``(index (n_pixels,) int32`` row of each pixel in ``values`` or -1,
    ``values (len(pixels), nk) float32`` all 1 (transmittance), ``pairs`` and ``erfs`` (len(pixels),)
    int64 zero counters), with ``nk = max(kmax - kmin + 1, 0)``."""
    index = np.full(n_pixels, -1, np.int32)
    index[pixels] = np.arange(len(pixels), dtype=np.int32)
    m, nk = len(pixels), max(kmax - kmin + 1, 0)
    return index, np.ones((m, nk), np.float32), np.zeros(m, np.int64), np.zeros(m, np.int64)


# ------------------------------------------------------------------ accumulate
@njit(cache=True, fastmath=False)
def _cum(zk, e0, e0m):
    """``erf(zk) - erf(z0)`` for ``zk >= z0`` from ``e0 = erfc(z0)`` and ``e0m = erfc(-z0)``
    (one erfc per call, no cancellation: same-sign pairs use the tail that is small)."""
    if zk >= 0.0:
        v = e0 - math.erfc(zk)
    else:  # zk < 0 implies z0 < 0
        v = math.erfc(-zk) - e0m
    return v if v > 0.0 else 0.0


#: optical depth from which a ray counts as opaque (exp(-12) = 6.1e-6): see :func:`_saturate`
TAU_OPAQUE = 12.0
#: erf window of the opaque-ray bookkeeping: a pair adds less than ``erfc(Z_CUT) = 7.4e-7`` of its
#: full step before ``s* - Z_CUT/sq`` and all but that after ``s* + Z_CUT/sq`` (``1/sq = sqrt(2) sigma_c``,
#: sigma_c the occluder's sigma along the ray given the ray's offset)
Z_CUT = 3.5
#: the window in sigmas: ``Z_CUT sqrt(2)``
SUPPORT_SIGMAS = Z_CUT * math.sqrt(2.0)


def support_starts(centre_depth, occ, k_sigma: float, sigma_along=None) -> np.ndarray:
    """(N,) float64 lower bound of the ray depth before which occluder i adds less than
    ``erfc(Z_CUT)`` of its full step on any ray through its ``k_sigma`` ellipsoid: ``centre_depth``
    (N,) (the distance of its centre from a point light, or its centre's depth along a
    directional light) minus ``(k_sigma + SUPPORT_SIGMAS) sigma``. ``sigma``: ``sigma_along``
    (N,) when given (a directional light: the occluder's sigma along it, ``sqrt(l^T Sigma l)``,
    which bounds both the ellipsoid's depth extent and sigma_c), else its largest sigma
    (``occ[:, 12:15]`` hold ``1/sigma``; the ellipsoid lies within ``k_sigma sigma_max`` of the
    centre)."""
    sig = (1.0 / np.min(np.asarray(occ)[:, 12:15], axis=1)) if sigma_along is None else np.asarray(sigma_along)
    return np.asarray(centre_depth, np.float64) - (float(k_sigma) + SUPPORT_SIGMAS) * sig


@njit(cache=True, fastmath=False, inline="always")
def _saturate(r, a, acc, endm, cut):
    """Opacity bookkeeping of pixel ``a`` after one pair (``r`` = :func:`_accumulate_one`'s result):
    ``acc[a]`` sums the pairs' full steps and ``endm[a]`` their furthest support end; when the sum
    first reaches ``TAU_OPAQUE`` every bin beyond ``endm[a]`` holds at least that depth (less
    ``erfc(Z_CUT)`` of it, :data:`Z_CUT`), so the
    pixel's cut depth ``cut[a]`` (occluders whose support starts at or beyond it are skipped)
    drops to ``endm[a]``: a skipped occluder could change that pixel's transmittance only where
    it is below exp(-TAU_OPAQUE). Returns True when the cut moved."""
    if r[1] <= 0.0:
        return False
    before = acc[a]
    acc[a] = before + r[1]
    if r[2] > endm[a]:
        endm[a] = r[2]
    if before < TAU_OPAQUE <= acc[a] and endm[a] < cut[a]:
        cut[a] = endm[a]
        return True
    return False


@njit(cache=True, fastmath=False, inline="always")
def _max_of(x, n):
    m = -np.inf
    for a in range(n):
        if x[a] > m:
            m = x[a]
    return m


@njit(cache=True, fastmath=False, inline="always")
def _accumulate_one(occ, i, ox, oy, oz, dx, dy, dz, dir_dep, dt, kmin, kmax, bin_skip, tau, diff, row, t0, tb):
    """:func:`_accumulate_one_from` for a ray from ``(ox, oy, oz)``."""
    p0, p1, p2 = light_offset(occ, i, ox, oy, oz)
    return _accumulate_one_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep, dt, kmin, kmax, bin_skip, tau, diff, row, t0,
                                tb)


@njit(cache=True, fastmath=False, inline="always")
def _accumulate_one_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep, dt, kmin, kmax, bin_skip, tau, diff, row, t0, tb):
    """Add occluder i's depth on the ray ``o + s d`` from ``s = t0`` (0 for a point light,
    ``-inf`` for a directional one) to the bin centres ``tb + (k + 1/2) dt``, k = kmin..kmax;
    ``tau``/``diff`` are 2D work arrays and ``row`` the row to add to (passing the 2D array
    and a row index avoids creating a refcounted view per call); ``(p0, p1, p2)`` is the occluder's
    ``dgsm_model.light_offset`` of the ray origin (the same for every ray of a point light: computed
    once per occluder). Returns ``(erfc evaluations,
    the pair's full step (its depth on the whole ray past t0), s* + Z_CUT/sq: the ray depth past
    which it has added all but erfc(Z_CUT) of that step)`` (0, 0, -inf for a pair that adds
    nothing)."""
    scale, s_star, sq = ray_params_from(occ, i, p0, p1, p2, dx, dy, dz, dir_dep)
    if scale < EPS_PAIR:
        return 0, 0.0, -np.inf
    z0 = sq * (t0 - s_star)
    ne = 0
    if z0 <= -ZC:  # the ray starts before the occluder's support (the common case): erfc(-z0) < 2.2e-17
        e0m = 0.0
        e0 = 2.0
    elif z0 >= ZC:  # the support lies behind the ray's start: depth < scale * 2.2e-17 on the whole ray
        return 0, 0.0, -np.inf
    elif z0 >= 0.0:
        e0 = math.erfc(z0)
        e0m = 2.0 - e0
        ne = 1
    else:
        e0m = math.erfc(-z0)
        e0 = 2.0 - e0m
        ne = 1
    half = ZC / sq
    if not bin_skip:
        for k in range(kmin, kmax + 1):
            tk = tb + (k + 0.5) * dt
            tau[row, k - kmin] += scale * _cum(sq * (tk - s_star), e0, e0m)
        return kmax - kmin + 1 + ne, scale * e0, s_star + Z_CUT / sq
    lo = (s_star - half - tb) / dt - 0.5
    hi = (s_star + half - tb) / dt - 0.5
    lo = min(max(lo, kmin - 1.0), kmax + 1.0)
    hi = min(max(hi, kmin - 1.0), kmax + 1.0)
    klo = max(int(math.ceil(lo)), kmin)
    khi = min(int(math.floor(hi)), kmax)
    for k in range(klo, khi + 1):
        tk = tb + (k + 0.5) * dt
        tau[row, k - kmin] += scale * _cum(sq * (tk - s_star), e0, e0m)
        ne += 1
    kfull = max(int(math.floor(hi)) + 1, kmin)
    if kfull <= kmax:
        diff[row, kfull - kmin] += scale * e0  # erf(inf) - erf(z0) = erfc(z0)
    return ne, scale * e0, s_star + Z_CUT / sq


# the same function as an ordinary call (for kernels where compile time matters more than speed)
accumulate_one_call = njit(cache=True, fastmath=False)(_accumulate_one.py_func)


@njit(cache=True, **threaded(), fastmath=False)
def _accumulate_point(g0, g1, light, occ, dir_dep, pdirs, K, t_max, kmin, kmax,
                      group_start, group_rows, group_tile, tile_start, tile_items, glob, cone, bin_skip,
                      out, pairs, erfs):
    """Tile-major accumulation: each group is the ROI pixels of one 8x8 tile (rows of
    ``pixels``/``out`` listed in ``group_rows[group_start[g]:group_start[g+1]]``); the tile's
    occluders are read once and cone-tested against every pixel of the group; ``glob``
    occluders are evaluated for every pixel without a cone test. ``group_tile[g] < 0`` means
    no tile list (the no-culling ablation passes every occluder in ``glob``). ``pdirs`` (|P|, 3)
    are the unit directions of the pixel centres (any direction parameterisation). Groups
    ``g0..g1-1`` (run in threads by ``thread_chunks.run_chunks``)."""
    nk = kmax - kmin + 1
    dt = t_max / K
    ox, oy, oz = light[0], light[1], light[2]
    for g in range(g0, g1):
        r0 = group_start[g]
        npx = group_start[g + 1] - r0
        dxs = np.empty(npx)
        dys = np.empty(npx)
        dzs = np.empty(npx)
        hit = np.zeros(npx, np.bool_)
        idx = np.empty(npx, np.int64)
        tau = np.zeros((npx, nk))
        diff = np.zeros((npx, nk))
        ne = np.zeros(npx, np.int64)
        npairs = np.zeros(npx, np.int64)
        for a in range(npx):
            p = group_rows[r0 + a]
            dxs[a], dys[a], dzs[a] = pdirs[p, 0], pdirs[p, 1], pdirs[p, 2]
        t = group_tile[g]
        if t >= 0:
            for q in range(tile_start[t], tile_start[t + 1]):
                o = tile_items[q]
                if cone_hits(dxs, dys, dzs, npx, cone, o, hit) == 0:  # vectorised, for the whole tile
                    continue
                p0, p1, p2 = light_offset(occ, o, ox, oy, oz)  # (every ray leaves the light)
                m = 0
                for a in range(npx):  # the hits' rows, without a branch
                    idx[m] = a
                    m += hit[a]
                for j in range(m):
                    a = idx[j]
                    npairs[a] += 1
                    ne[a] += _accumulate_one_from(occ, o, p0, p1, p2, dxs[a], dys[a], dzs[a], dir_dep, dt, kmin,
                                                  kmax, bin_skip, tau, diff, a, 0.0, 0.0)[0]
        for a in range(npx):
            dx, dy, dz = dxs[a], dys[a], dzs[a]
            for q in range(glob.shape[0]):  # a call, not a second inlined copy (compile time; few occluders)
                ne[a] += accumulate_one_call(occ, glob[q], ox, oy, oz, dx, dy, dz, dir_dep, dt, kmin, kmax,
                                             bin_skip, tau, diff, a, 0.0, 0.0)[0]
            npairs[a] += glob.shape[0]
            p = group_rows[r0 + a]
            run = 0.0
            for k in range(nk):
                run += diff[a, k]
                out[p, k] = math.exp(-(tau[a, k] + run))
            pairs[p] = npairs[a]
            erfs[p] = ne[a]


@njit(cache=True, **threaded(), fastmath=False)
def _pixel_dirs(i0_, i1_, pixels, w, out):
    for p in range(i0_, i1_):
        u, v = pixel_center_uv(pixels[p] // w, pixels[p] % w, w)
        out[p, 0], out[p, 1], out[p, 2] = oct_decode(u, v)


def _groups(pixels, width: int, use_tiles: bool, seed: int = 12345):
    """Group ROI pixel rows by 8x8 tile (tile culling) or in runs of 64 (no culling), in a
    fixed pseudo-random group order so parallel chunks get similar loads."""
    wt = width // TILE
    tile = (pixels // width // TILE) * wt + (pixels % width) // TILE
    if use_tiles:
        order = np.argsort(tile, kind="stable")
        ts = tile[order]
        cuts = np.flatnonzero(np.diff(ts)) + 1
        starts = np.concatenate([[0], cuts, [len(ts)]]).astype(np.int64)
        gtile = ts[starts[:-1]].astype(np.int64)
    else:
        order = np.arange(len(pixels))
        starts = np.concatenate([np.arange(0, len(pixels), 64), [len(pixels)]]).astype(np.int64)
        gtile = np.full(len(starts) - 1, -1, np.int64)
    perm = np.random.default_rng(seed).permutation(len(starts) - 1)
    sizes = np.diff(starts)[perm]
    rows = np.concatenate([order[starts[g]:starts[g + 1]] for g in perm]) if len(perm) else order
    new_starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return new_starts, rows.astype(np.int64), gtile[perm]


def covariance6(cov) -> np.ndarray:
    """(N, 3, 3) covariances -> (N, 6) float64 (xx, xy, xz, yy, yz, zz)."""
    c = np.asarray(cov, dtype=np.float64)
    return np.ascontiguousarray(np.stack([c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 1], c[:, 1, 2], c[:, 2, 2]], 1))


def pixel_directions(pixels, width: int) -> np.ndarray:
    """(M, 3) float64 unit directions of the centres of atlas pixels ``pixels`` (M,) int64 flat
    ids of a ``width`` x ``width`` octahedral atlas."""
    out = np.empty((len(pixels), 3))
    run_chunks(_pixel_dirs, len(pixels), np.ascontiguousarray(pixels, dtype=np.int64), int(width), out, min_chunk=4096)
    return out


def accumulate_pixels(light, occ, dir_dep: int, pixels, width: int, K: int, t_max: float, kmin: int, kmax: int,
                      tiles, use_tiles: bool, bin_skip: bool, out, pairs, erfs) -> None:
    """Transmittance of the atlas pixels ``pixels`` (sorted flat ids) over bins ``kmin..kmax``
    into ``out`` (len(pixels), kmax - kmin + 1) float32, with per-pixel counters ``pairs`` and
    ``erfs`` (int64): the accumulation step of :func:`build_point`. ``tiles``:
    ``bin_tiles``' lists (every tile the pixels lie in must have been active), or with
    ``use_tiles=False`` lists whose ``glob`` holds every occluder."""
    start, items, glob, cone = tiles
    gs, rows, gt = _groups(pixels, width, use_tiles)
    pdirs = pixel_directions(pixels, width)
    run_chunks(_accumulate_point, len(gs) - 1, light, np.ascontiguousarray(occ, dtype=np.float64), int(dir_dep),
               pdirs, K, float(t_max), kmin, kmax, gs, rows, gt, start, items, glob, cone, bool(bin_skip), out, pairs,
               erfs, chunks_per_thread=8)


def build_point(light, occ, dir_dep: int, cov6, roi_points, width: int = 512, K: int = 64,
                t_max: float | None = None, k_sigma: float = 3.0, use_roi: bool = True,
                use_tiles: bool = True, bin_skip: bool = True) -> Atlas:
    """Build the DGSM of a point light at ``light`` (3,) metres.

    occ, dir_dep: ``dgsm_model.pack_occluders``; cov6: (N, 6) occluder covariances
    (``covariance6``), used for culling only; roi_points: (M, 3) points that will be looked
    up (they define P, the bin range and, when ``t_max`` is None, ``t_max = t_far K/(K - 1/2)``);
    width: atlas side W (multiple of 8); K: radial bins. See the module doc for the flags.
    """
    light = check_vector("light position", light)
    pts = check_points("ROI points", roi_points)
    if width % TILE or width < TILE:
        raise ValueError(f"atlas width must be a positive multiple of {TILE}, got {width}")
    if K < 1:
        raise ValueError(f"K must be >= 1, got {K}")
    if t_max is None:
        t_max = t_max_for(far_distance(light, pts), K)
    stencils = None
    if use_roi:
        stencils = point_stencils(light, pts, width, K, t_max)
        pixels, kmin, kmax = stencil_roi(stencils, width)
    else:
        pixels, kmin, kmax = np.arange(width * width, dtype=np.int64), 0, K - 1
    index, out, pairs, erfs = atlas_buffers(width * width, pixels, kmin, kmax)
    nk = out.shape[1]
    if len(pixels) and nk and occ.shape[0]:
        occ = np.ascontiguousarray(occ, dtype=np.float64)
        if use_tiles:
            wt = width // TILE
            pi, pj = pixels // width, pixels % width
            active = np.zeros(wt * wt, np.bool_)
            active[(pi // TILE) * wt + pj // TILE] = True
            start, items, glob, cone = bin_tiles(light, occ, np.ascontiguousarray(cov6, dtype=np.float64), width,
                                                 k_sigma, active)
        else:
            start = np.zeros(1, np.int64)
            items = np.zeros(0, np.int64)
            glob = np.arange(occ.shape[0], dtype=np.int64)
            cone = np.zeros((0, 4))
        accumulate_pixels(light, occ, dir_dep, pixels, width, K, t_max, kmin, kmax, (start, items, glob, cone),
                          use_tiles, bin_skip, out, pairs, erfs)
    tiles = (start, items, glob, cone) if (use_tiles and len(pixels) and nk and occ.shape[0]) else None
    return Atlas(width, K, float(t_max), kmin, kmax, index, out, pixels, int(pairs.sum()), int(erfs.sum()), tiles,
                 stencils)
