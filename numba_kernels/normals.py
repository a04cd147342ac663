"""Per-Gaussian pseudo-normals for lighting transfer (paper 3.5; 4.1 "smallest ellipsoid axis").

For each Gaussian i (positions (N, 3), quaternions (N, 4) ordered (w, x, y, z), linear
scales (N, 3), linear opacities (N,)):

1. Axis: the column of the rotation matrix R(q) (world = R @ local) belonging to the
   smallest scale. If the Gaussian is nearly isotropic (smallest / middle scale >
   ``iso_ratio``) the axis is instead the smallest-eigenvalue eigenvector of the
   opacity-weighted covariance of its neighbours' centres (local PCA), when it has >= 3.
2. Sign: outward, i.e. away from the opacity-weighted centroid of the neighbours within
   ``radius`` (excluding i). If that offset along the axis is below ``1e-4 * radius``
   (flat neighbourhood) or there are no neighbours, away from the global opacity-weighted
   centroid of the whole set (fallback).
3. Consistency: ``n_smooth`` Jacobi passes flip a normal whose opacity-weighted vote
   ``sum_j o_j <n_i, n_j>`` over tangential neighbours (|<p_j - p_i, n_i>| <= 0.5 |p_j - p_i|,
   so the opposite side of a thin sheet does not vote) is negative, using the first 32
   neighbours found in step 2. This removes isolated sign flips between neighbours.

Neighbours come from a uniform grid (cell = radius) stored as a hash table built with a
sort (points are processed in grid order for cache locality); no KD-tree is needed at run
time. ``radius=None`` picks the radius so that a sample of Gaussians has
~``target_neighbours`` neighbours on average (surface-like sets).

Animated avatars: estimate normals once in the rest pose, convert them to each Gaussian's
local frame with :func:`normals_to_local`, and get every posed frame with
:func:`local_normals_to_world` (O(N), no neighbour search).

Real captures: the smallest axis of a trained 3DGS Gaussian is only loosely tied to the
surface (on ``biker.ply`` its direction barely correlates with an outward proxy); expect
noisy normals there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .jit_options import prange_only
from .quaternion import quat_to_rotation

_P1, _P2, _P3 = 73856093, 19349663, 83492791
_CHUNK = 256
_VOTE_NEIGHBOURS = 32  # neighbours kept per Gaussian for the consistency passes
_BITS = 21  # bits per axis in a packed cell key


@njit(cache=True, fastmath=False)
def _cell_hash(ix, iy, iz, mask):
    h = (ix * _P1) ^ (iy * _P2) ^ (iz * _P3)
    return h & mask


@njit(cache=True, fastmath=False)
def _cell_key(ix, iy, iz):
    """Exact packed cell id (cells are offset by +1 so that the -1 neighbour is >= 0)."""
    return ((ix + 1) << (2 * _BITS)) | ((iy + 1) << _BITS) | (iz + 1)


@njit(cache=True, fastmath=False)
def _hash_points(pos, origin, inv_cell, mask, hashes, keys):
    for i in range(pos.shape[0]):
        ix = np.int64(math.floor((pos[i, 0] - origin[0]) * inv_cell))
        iy = np.int64(math.floor((pos[i, 1] - origin[1]) * inv_cell))
        iz = np.int64(math.floor((pos[i, 2] - origin[2]) * inv_cell))
        hashes[i] = _cell_hash(ix, iy, iz, mask)
        keys[i] = _cell_key(ix, iy, iz)


class _Grid:
    """Uniform grid hash: points sorted by cell hash; ``start[h]:start[h+1]`` is bucket h.

    ``cellkey[t]`` is the exact cell of the point at sorted slot t (filters hash collisions).
    """

    def __init__(self, pos: np.ndarray, radius: float):
        self.pos = pos
        self.radius = float(radius)
        self.origin = pos.min(axis=0) if len(pos) else np.zeros(3)
        if len(pos):
            cells = float(np.max((pos.max(axis=0) - self.origin) / self.radius))
            if cells > 2 ** _BITS - 4:
                raise ValueError(f"neighbourhood radius {radius} is too small for the extent of the points "
                                 f"({cells:.0f} cells per axis, at most {2 ** _BITS - 4})")
        table = 1
        while table < 2 * max(1, len(pos)):
            table *= 2
        self.mask = table - 1
        hashes = np.empty(len(pos), dtype=np.int64)
        keys = np.empty(len(pos), dtype=np.int64)
        _hash_points(pos, self.origin, 1.0 / self.radius, self.mask, hashes, keys)
        self.order = np.argsort(hashes, kind="stable").astype(np.int64)
        self.cellkey = keys[self.order]
        counts = np.bincount(hashes, minlength=table)
        self.start = np.zeros(table + 1, dtype=np.int64)
        np.cumsum(counts, out=self.start[1:])


@njit(cache=True, fastmath=False)
def _neighbours_of(i, pos, origin, radius, mask, order, start, cellkey, buf):
    """Fill ``buf`` with indices j != i within ``radius`` of point i; returns the count
    (at most ``len(buf)``: further neighbours are ignored)."""
    inv = 1.0 / radius
    r2 = radius * radius
    cx = np.int64(math.floor((pos[i, 0] - origin[0]) * inv))
    cy = np.int64(math.floor((pos[i, 1] - origin[1]) * inv))
    cz = np.int64(math.floor((pos[i, 2] - origin[2]) * inv))
    cnt = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                h = _cell_hash(cx + dx, cy + dy, cz + dz, mask)
                key = _cell_key(cx + dx, cy + dy, cz + dz)
                for t in range(start[h], start[h + 1]):
                    j = order[t]
                    ddx = pos[j, 0] - pos[i, 0]
                    ddy = pos[j, 1] - pos[i, 1]
                    ddz = pos[j, 2] - pos[i, 2]
                    # distance first (cheap, vectorisable); the exact cell check then drops
                    # points reached twice through colliding hashes
                    if ddx * ddx + ddy * ddy + ddz * ddz <= r2 and cellkey[t] == key and j != i:
                        if cnt < buf.shape[0]:
                            buf[cnt] = j
                            cnt += 1
    return cnt


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _count_kernel(sample, pos, origin, radius, mask, order, start, cellkey, max_nb, out):
    for s in prange(sample.shape[0]):
        buf = np.empty(max_nb, dtype=np.int64)
        out[s] = _neighbours_of(sample[s], pos, origin, radius, mask, order, start, cellkey, buf)


@njit(cache=True, fastmath=False)
def quat_axis_smallest(q, s):
    """Unit column of R(q) (q = (w, x, y, z), normalised here) for the smallest of scales s.

    Returns (ax, ay, az, ratio) with ratio = smallest / middle scale (1 = isotropic pair).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(q[0], q[1], q[2], q[3])
    k = 0
    if s[1] < s[k]:
        k = 1
    if s[2] < s[k]:
        k = 2
    a = s[(k + 1) % 3]
    b = s[(k + 2) % 3]
    mid = a if a < b else b
    ratio = s[k] / mid if mid > 0.0 else 1.0
    if k == 0:
        return r00, r10, r20, ratio
    if k == 1:
        return r01, r11, r21, ratio
    return r02, r12, r22, ratio


@njit(cache=True, fastmath=False)
def _local_stats_chunk(ch, n, pos, quat, scales, opac, origin, radius, mask, order, start, cellkey, max_nb,
                       axis, ratio, centroid, count, cov, nbr):
    """One chunk of :func:`_local_stats_kernel` (the parallel loop's body as a call: an inlined body is typed twice)."""
    buf = np.empty(max_nb, dtype=np.int64)
    qd = np.empty(4, dtype=np.float64)
    sd = np.empty(3, dtype=np.float64)
    for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
        for c in range(4):
            qd[c] = quat[i, c]
        for c in range(3):
            sd[c] = scales[i, c]
        ax, ay, az, rt = quat_axis_smallest(qd, sd)
        axis[i, 0] = ax
        axis[i, 1] = ay
        axis[i, 2] = az
        ratio[i] = rt
        cnt = _neighbours_of(i, pos, origin, radius, mask, order, start, cellkey, buf)
        count[i] = cnt
        for t in range(nbr.shape[1]):  # first neighbours, kept for the consistency passes
            nbr[i, t] = buf[t] if t < cnt else -1
        wsum = 0.0
        mx = 0.0
        my = 0.0
        mz = 0.0
        for t in range(cnt):
            j = buf[t]
            wj = max(np.float64(opac[j]), 1e-6)
            wsum += wj
            mx += wj * pos[j, 0]
            my += wj * pos[j, 1]
            mz += wj * pos[j, 2]
        for c in range(6):
            cov[i, c] = 0.0
        if cnt == 0:
            centroid[i, 0] = pos[i, 0]
            centroid[i, 1] = pos[i, 1]
            centroid[i, 2] = pos[i, 2]
            continue
        mx /= wsum
        my /= wsum
        mz /= wsum
        centroid[i, 0] = mx
        centroid[i, 1] = my
        centroid[i, 2] = mz
        for t in range(cnt):
            j = buf[t]
            wj = max(np.float64(opac[j]), 1e-6)
            d0 = pos[j, 0] - mx
            d1 = pos[j, 1] - my
            d2 = pos[j, 2] - mz
            cov[i, 0] += wj * d0 * d0
            cov[i, 1] += wj * d0 * d1
            cov[i, 2] += wj * d0 * d2
            cov[i, 3] += wj * d1 * d1
            cov[i, 4] += wj * d1 * d2
            cov[i, 5] += wj * d2 * d2


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _local_stats_kernel(pos, quat, scales, opac, origin, radius, mask, order, start, cellkey, max_nb,
                        axis, ratio, centroid, count, cov, nbr):
    """Per Gaussian: smallest axis and scale ratio, opacity-weighted neighbour centroid,
    neighbour count and the 6 unique entries (xx, xy, xz, yy, yz, zz) of the weighted covariance."""
    n = pos.shape[0]
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for ch in prange(n_chunks):
        _local_stats_chunk(np.int64(ch), n, pos, quat, scales, opac, origin, radius, mask, order, start, cellkey,
                           max_nb, axis, ratio, centroid, count, cov, nbr)


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _consistency_kernel(pos, opac, nin, nbr, nout):
    """One Jacobi pass: flip n_i when the opacity-weighted vote of tangential neighbours is < 0."""
    n = pos.shape[0]
    for i in prange(n):
        vote = 0.0
        for t in range(nbr.shape[1]):
            j = nbr[i, t]
            if j < 0:
                break
            dx = pos[j, 0] - pos[i, 0]
            dy = pos[j, 1] - pos[i, 1]
            dz = pos[j, 2] - pos[i, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            along = dx * nin[i, 0] + dy * nin[i, 1] + dz * nin[i, 2]
            if abs(along) > 0.5 * dist:
                continue
            dot = nin[i, 0] * nin[j, 0] + nin[i, 1] * nin[j, 1] + nin[i, 2] * nin[j, 2]
            vote += max(np.float64(opac[j]), 1e-6) * dot
        sgn = -1.0 if vote < 0.0 else 1.0
        for c in range(3):
            nout[i, c] = sgn * nin[i, c]


def estimate_radius(pos: np.ndarray, target_neighbours: int = 24, sample: int = 512, seed: int = 0) -> float:
    """Neighbourhood radius giving ~``target_neighbours`` neighbours on average (surface-like sets)."""
    n = pos.shape[0]
    if n < 2:
        return 1.0
    ext = pos.max(axis=0) - pos.min(axis=0)
    diag = float(np.linalg.norm(ext))
    if not diag > 0.0:
        return 1.0
    r = diag * math.sqrt(target_neighbours / n)  # surface-like guess: area ~ diag^2
    rng = np.random.default_rng(seed)
    idx = rng.choice(n, size=min(sample, n), replace=False).astype(np.int64)
    for _ in range(6):
        grid = _Grid(pos, r)
        counts = np.empty(idx.shape[0], dtype=np.int64)
        _count_kernel(idx, pos, grid.origin, r, grid.mask, grid.order, grid.start, grid.cellkey, 4096, counts)
        mean = float(counts.mean())
        if target_neighbours / 1.5 <= mean <= target_neighbours * 1.5:
            break
        r *= math.sqrt(target_neighbours / max(mean, 0.5))
        r = min(r, diag)
    return r


def gaussian_normals(positions, orientations, scales, opacities, radius: float | None = None,
                     iso_ratio: float = 0.85, n_smooth: int = 2, max_neighbours: int = 256,
                     return_fallback: bool = False):
    """Outward unit pseudo-normals (N, 3) float32; see the module docstring.

    positions (N, 3), orientations (N, 4) (w, x, y, z), scales (N, 3) linear sigma,
    opacities (N,) linear. radius: neighbourhood radius in scene units (None: automatic).
    With ``return_fallback`` also returns (N,) bool: True where the global-centroid
    fallback decided the sign.
    """
    pos = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
    quat = np.ascontiguousarray(orientations, dtype=np.float32).reshape(-1, 4)
    sc = np.ascontiguousarray(scales, dtype=np.float32).reshape(-1, 3)
    op = np.ascontiguousarray(opacities, dtype=np.float32).reshape(-1)
    n = pos.shape[0]
    if not (quat.shape[0] == sc.shape[0] == op.shape[0] == n):
        raise ValueError("positions, orientations, scales and opacities must have the same length")
    if n == 0:
        empty = np.zeros((0, 3), dtype=np.float32)
        return (empty, np.zeros(0, dtype=bool)) if return_fallback else empty
    for name, arr in (("positions", pos), ("orientations", quat), ("scales", sc), ("opacities", op)):
        bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
        if bad.any():
            raise ValueError(f"normals: '{name}' element {int(np.flatnonzero(bad)[0])} is not finite")
    r = estimate_radius(pos) if radius is None else float(radius)
    if not (r > 0.0 and math.isfinite(r)):
        raise ValueError(f"normal neighbourhood radius must be > 0, got {r}")
    w = np.maximum(op.astype(np.float64), 1e-6)
    gcen = (pos * w[:, None]).sum(axis=0) / w.sum()
    # Work in grid order (points of one cell contiguous in memory: far fewer cache misses).
    grid = _Grid(pos, r)
    perm = grid.order
    pos = np.ascontiguousarray(pos[perm])
    quat, sc, op = quat[perm], sc[perm], op[perm]
    grid.order = np.arange(n, dtype=np.int64)
    axis = np.empty((n, 3), dtype=np.float64)
    ratio = np.empty(n, dtype=np.float64)
    cen = np.empty((n, 3), dtype=np.float64)
    cnt = np.empty(n, dtype=np.int64)
    cov6 = np.empty((n, 6), dtype=np.float64)
    nbr = np.empty((n, _VOTE_NEIGHBOURS), dtype=np.int32)
    _local_stats_kernel(pos, quat, sc, op, grid.origin, r, grid.mask, grid.order, grid.start, grid.cellkey,
                        int(max_neighbours), axis, ratio, cen, cnt, cov6, nbr)
    iso = np.flatnonzero((ratio > float(iso_ratio)) & (cnt >= 3))
    if iso.size:  # local PCA for nearly isotropic Gaussians (batched 3x3 eigh)
        c = cov6[iso]
        mats = np.stack([c[:, [0, 1, 2]], c[:, [1, 3, 4]], c[:, [2, 4, 5]]], axis=1)
        axis[iso] = np.linalg.eigh(mats)[1][:, :, 0]
    off = np.einsum("ij,ij->i", pos - cen, axis)
    fb_s = (cnt == 0) | (np.abs(off) <= 1e-4 * r)
    off_g = np.einsum("ij,ij->i", pos - gcen, axis)
    sign = np.where(fb_s, np.where(off_g < 0, -1.0, 1.0), np.where(off < 0, -1.0, 1.0))
    out = axis * (sign / np.linalg.norm(axis, axis=1))[:, None]
    tmp = np.empty_like(out)
    for _ in range(int(n_smooth)):
        _consistency_kernel(pos, op, out, nbr, tmp)
        out, tmp = tmp, out
    res = np.empty((n, 3), dtype=np.float32)
    res[perm] = out
    fb = np.empty(n, dtype=bool)
    fb[perm] = fb_s
    return (res, fb) if return_fallback else res


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _rotate_kernel(quat, vec, inverse, out):
    for i in prange(quat.shape[0]):
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(
            np.float64(quat[i, 0]), np.float64(quat[i, 1]), np.float64(quat[i, 2]), np.float64(quat[i, 3]))
        a = np.float64(vec[i, 0])
        b = np.float64(vec[i, 1])
        c = np.float64(vec[i, 2])
        if inverse:
            out[i, 0] = r00 * a + r10 * b + r20 * c
            out[i, 1] = r01 * a + r11 * b + r21 * c
            out[i, 2] = r02 * a + r12 * b + r22 * c
        else:
            out[i, 0] = r00 * a + r01 * b + r02 * c
            out[i, 1] = r10 * a + r11 * b + r12 * c
            out[i, 2] = r20 * a + r21 * b + r22 * c


def normals_to_local(orientations, normals) -> np.ndarray:
    """World normals -> each Gaussian's local frame, ``R(q)^T n`` (N, 3) float32.

    For animated avatars: estimate normals once in the rest pose, store them locally, and
    get every posed frame with :func:`local_normals_to_world` (O(N), no neighbour search);
    the normal then follows each Gaussian's rotation rigidly.
    """
    q = np.ascontiguousarray(orientations, dtype=np.float32).reshape(-1, 4)
    v = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
    out = np.empty((q.shape[0], 3), dtype=np.float32)
    _rotate_kernel(q, v, True, out)
    return out


def local_normals_to_world(orientations, local) -> np.ndarray:
    """Local normals -> world, ``R(q) n_local`` (N, 3) float32 (inverse of :func:`normals_to_local`)."""
    q = np.ascontiguousarray(orientations, dtype=np.float32).reshape(-1, 4)
    v = np.ascontiguousarray(local, dtype=np.float32).reshape(-1, 3)
    out = np.empty((q.shape[0], 3), dtype=np.float32)
    _rotate_kernel(q, v, False, out)
    return out
