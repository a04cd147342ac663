"""Per-Gaussian pseudo-normals for lighting transfer (paper 3.5; 4.1 "smallest ellipsoid axis").

For each Gaussian i (positions (N, 3), quaternions (N, 4) ordered (w, x, y, z), linear
scales (N, 3), linear opacities (N,)):

1. Axis a_i: the column of the rotation matrix R(q) (world = R @ local) belonging to the
   smallest scale. If the Gaussian is nearly isotropic (smallest / middle scale >
   ``iso_ratio``) the axis is instead the smallest-eigenvalue eigenvector of the
   opacity-weighted covariance of its neighbours' centres (local PCA), when it has >= 3.
2. Own vote: the offset ``off_i = <p_i - c_i, a_i>`` from the opacity-weighted centroid c_i of
   the neighbours within ``radius`` (on a locally convex surface the centroid lies inside),
   as ``v_i = o_i clip(off_i / (0.05 radius), -1, 1)``.
3. Relative orientation (Hoppe-style propagation): a signed union-find over the 32 nearest
   neighbours of each Gaussian joins i and j, with the relative sign sign(<a_i, a_j>), when
   their axes are nearly parallel and j lies near the tangent planes of both
   (|<p_j - p_i, a>| <= 0.35 |p_j - p_i| for a = a_i and a_j, which keeps out the far side of
   a thin limb or sheet). Two passes join the most reliable pairs first: |cos| >= 0.98 within
   ``radius``, then |cos| >= 0.9 within 0.6 ``radius`` (on CesiumMan every pair across two
   body parts that passes the tangent test is longer than 0.75 ``radius`` and has
   |cos| < 0.98; a third pass up to ``radius`` joined arm and torso at 1000-2000 Gaussians).
   In the second pass a join is refused when both components are confidently oriented the
   other way (|sum of parity * v| > 0.3 sum of opacity + 10 on each side, opposite signs).
   Creases (> 25 deg between neighbours) and gaps split the set into components whose axes
   are consistently oriented.
4. Sign per component: the sign of the sum of its members' votes (thousands of votes on a
   smooth body part, so flat regions and a few concave spots no longer decide alone). If the
   component's mean |offset| is below ``1e-4 * radius`` (flat, or no neighbours): away from
   the global opacity-weighted centroid of the whole set (fallback). A component whose votes
   cancel (|sum| < 0.3 sum |v_i|: joined across a gap narrower than the sampling, e.g.
   fingers a few mm apart; real captures with noisy axes) is not trusted: each of its
   Gaussians takes its own vote (the per-Gaussian rule of the earlier version).
5. Consistency: ``n_smooth`` Jacobi passes over Gaussians of components smaller than 32 and
   of untrusted ones flip a normal whose opacity-weighted vote ``sum_j o_j <n_i, n_j>`` over
   tangential neighbours (|<p_j - p_i, n_i>| <= 0.5 |p_j - p_i|) is negative.

``tests/test_normals.py`` bounds the share of normals pointing into a mesh avatar's body and
across flat faces; the figures are in docs/design.md, "Normals".

Neighbours come from the spatial hash of ``numba_kernels.grid_neighbours`` (cell = radius;
points are processed in grid order for cache locality); no KD-tree is needed at run time.
``radius=None`` picks the radius so that a sample of Gaussians has ~``target_neighbours``
neighbours on average (surface-like sets).

Animated avatars: estimate normals once in the rest pose, convert them to each Gaussian's
local frame with :func:`normals_to_local`, and get every posed frame with
:func:`local_normals_to_world` (O(N), no neighbour search).

Real captures: the smallest axis of a trained 3DGS Gaussian is only loosely tied to the
surface (on ``biker.ply`` its direction barely correlates with an outward proxy); expect
noisy normals there (about a third of biker's / guitar's Gaussians end up in untrusted
components and keep their own vote).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .grid_neighbours import HashGrid, build_grid, neighbour_slots
from .jit_options import threaded
from .quaternion import quat_to_rotation
from .thread_chunks import run_chunks

_CHUNK = 256
_VOTE_NEIGHBOURS = 32  # nearest neighbours kept per Gaussian for the orientation and consistency passes
_MAX_CELLS = 2 ** 20 - 4  # cells per axis, below grid_neighbours' coordinate clamp (2^20 - 1)
_JOIN_PASSES = ((0.98, 1.0), (0.9, 0.6))  # (min |cos| of the axes, max distance / radius) per pass
_JOIN_TANGENTIAL = 0.35  # max |<p_j - p_i, a>| / |p_j - p_i| of a joined pair
_AGREE = (0.3, 10.0)  # passes >= 2 refuse a join of components with |sum v| > 0.3 sum o + 10, opposite signs
_COHERENCE = 0.3  # min |sum v| / sum |v| of a trusted component
_SMOOTH_BELOW = 32  # consistency passes for components smaller than this (and untrusted ones)
_VOTE_CLIP = 0.05  # own votes saturate at an offset of this times the radius


def _grid(pos: np.ndarray, radius: float) -> HashGrid:
    """The neighbour grid: cells of edge ``radius`` from the lower corner of the points, a table of
    >= 2 N buckets (``grid_neighbours.build_grid``); its ``points`` are ``pos`` in grid order."""
    origin = pos.min(axis=0) if len(pos) else np.zeros(3)
    if len(pos):
        cells = float(np.max((pos.max(axis=0) - origin) / radius))
        if cells > _MAX_CELLS:
            raise ValueError(f"neighbourhood radius {radius} is too small for the extent of the points "
                             f"({cells:.0f} cells per axis, at most {_MAX_CELLS})")
    return build_grid(pos, radius, origin=origin, min_buckets=2 * max(1, len(pos)))


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _count_kernel(slots, points, origin, radius, mask, cellkey, start, max_nb, out):
    for s in prange(slots.shape[0]):
        buf = np.empty(max_nb, dtype=np.int64)
        t = slots[s]
        out[s] = neighbour_slots(points, origin, radius, mask, cellkey, start, points[t, 0], points[t, 1],
                                 points[t, 2], radius, t, buf)


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
def _select_smallest(key, val, cnt, k):
    """Reorder ``key[:cnt]`` and ``val[:cnt]`` together so that the k smallest keys come first
    (in any order): quickselect with a middle pivot, O(cnt) on average."""
    lo = 0
    hi = cnt - 1
    while lo < hi:
        piv = key[(lo + hi) // 2]
        a = lo
        b = hi
        while a <= b:
            while key[a] < piv:
                a += 1
            while key[b] > piv:
                b -= 1
            if a <= b:
                key[a], key[b] = key[b], key[a]
                val[a], val[b] = val[b], val[a]
                a += 1
                b -= 1
        # now key[lo:b+1] <= piv <= key[a:hi+1]
        if k - 1 <= b:
            hi = b
        elif k - 1 >= a:
            lo = a
        else:
            return


@njit(cache=True, fastmath=False)
def _local_stats_chunk(ch, n, pos, quat, scales, opac, origin, radius, mask, cellkey, start, max_nb,
                       iso_ratio, axis, ratio, centroid, count, cov, nbr):
    """One chunk of :func:`_local_stats_kernel` (the parallel loop's body as a call: an inlined body is typed twice)."""
    buf = np.empty(max_nb, dtype=np.int64)
    dist2 = np.empty(max_nb, dtype=np.float64)
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
        cnt = neighbour_slots(pos, origin, radius, mask, cellkey, start, pos[i, 0], pos[i, 1], pos[i, 2], radius, i,
                              buf)
        count[i] = cnt
        keep = nbr.shape[1]
        if cnt > keep:  # move the nearest ``keep`` neighbours to the front
            for t in range(cnt):
                dx = pos[buf[t], 0] - pos[i, 0]
                dy = pos[buf[t], 1] - pos[i, 1]
                dz = pos[buf[t], 2] - pos[i, 2]
                dist2[t] = dx * dx + dy * dy + dz * dz
            _select_smallest(dist2, buf, cnt, keep)
        for t in range(keep):  # nearest neighbours, kept for orientation and the consistency passes
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
        if rt <= iso_ratio:  # the covariance is only used for nearly isotropic Gaussians
            continue
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


@njit(**threaded(), cache=True, fastmath=False)
def _local_stats_kernel(c0, c1, pos, quat, scales, opac, origin, radius, mask, cellkey, start, max_nb,
                        iso_ratio, axis, ratio, centroid, count, cov, nbr):
    """Per Gaussian: smallest axis and scale ratio, opacity-weighted neighbour centroid,
    neighbour count and the 6 unique entries (xx, xy, xz, yy, yz, zz) of the weighted covariance.
    Chunks ``c0..c1-1`` of ``_CHUNK`` Gaussians (threads: ``thread_chunks.run_chunks``)."""
    n = pos.shape[0]
    for ch in range(c0, c1):
        _local_stats_chunk(np.int64(ch), n, pos, quat, scales, opac, origin, radius, mask, cellkey, start,
                           max_nb, iso_ratio, axis, ratio, centroid, count, cov, nbr)


@njit(**threaded(), cache=True, fastmath=False)
def _consistency_kernel(i0_, i1_, pos, opac, nin, nbr, active, nout):
    """One Jacobi pass: flip n_i when the opacity-weighted vote of tangential neighbours is < 0
    (only where ``active``; elsewhere n_i is copied). Gaussians ``i0_..i1_-1`` (threads:
    ``thread_chunks.run_chunks``)."""
    for i in range(i0_, i1_):
        if not active[i]:
            for c in range(3):
                nout[i, c] = nin[i, c]
            continue
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


@njit(cache=True, fastmath=False)
def _find_root(parent, par, i):
    """Root of i in the signed union-find and the parity (+-1) of i relative to it (path halving)."""
    p = 1
    while parent[i] != i:
        g = parent[i]
        if parent[g] != g:  # path halving: i now points to its grandparent
            par[i] = par[i] * par[g]
            parent[i] = parent[g]
        p = p * par[i]
        i = parent[i]
    return i, p


@njit(cache=True, fastmath=False, nogil=True)  # serial: union-find is sequential (jit_options.SERIAL_NOTE)
def _orient_kernel(pos, axis, nbr, count, radius, passes, tangential, vote, weight, agree, root, parity):
    """Signed union-find over the kept neighbour pairs (module docstring, step 3): pass k joins
    i and j when |<a_i, a_j>| >= passes[k, 0], |p_j - p_i| <= passes[k, 1] * radius and j lies
    near the tangent planes of both (|<p_j - p_i, a>| <= tangential |p_j - p_i| for a = a_i and
    a_j), recording the relative sign sign(<a_i, a_j>); a pair is tried in the first pass whose
    limits it meets. ``count``: neighbours found per Gaussian (a pair (i, j), j < i, is tried
    once, as (j, i), when j kept all its neighbours). ``vote`` / ``weight``: per-Gaussian signed
    votes along ``axis`` and opacities; from the second pass on, a join is refused when both
    components' summed votes exceed ``agree[0] * weight + agree[1]`` and contradict it. Writes
    each Gaussian's component ``root`` and its ``parity`` (+-1) relative to the root: the axes
    ``parity * axis`` are consistently oriented within every component."""
    n = pos.shape[0]
    parent = np.empty(n, dtype=np.int64)
    par = np.empty(n, dtype=np.int64)
    size = np.empty(n, dtype=np.int64)
    cv = np.empty(n, dtype=np.float64)  # per root: the component's vote sum parity * vote
    cw = np.empty(n, dtype=np.float64)  # and weight
    for i in range(n):
        parent[i] = i
        par[i] = 1
        size[i] = 1
        cv[i] = vote[i]
        cw[i] = weight[i]
    keep = nbr.shape[1]
    code = np.empty(nbr.shape, dtype=np.int8)  # first pass that tries pair (i, nbr[i, t]); -1: none
    for i in range(n):
        for t in range(nbr.shape[1]):
            code[i, t] = -1
            j = nbr[i, t]
            if j < 0:
                break
            if j < i and count[j] <= keep:
                continue  # i is in j's list too (j kept all its neighbours): pair tried as (j, i)
            dot = abs(axis[i, 0] * axis[j, 0] + axis[i, 1] * axis[j, 1] + axis[i, 2] * axis[j, 2])
            dx = pos[j, 0] - pos[i, 0]
            dy = pos[j, 1] - pos[i, 1]
            dz = pos[j, 2] - pos[i, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            lim = tangential * dist
            if abs(dx * axis[i, 0] + dy * axis[i, 1] + dz * axis[i, 2]) > lim:
                continue
            if abs(dx * axis[j, 0] + dy * axis[j, 1] + dz * axis[j, 2]) > lim:
                continue
            for e in range(passes.shape[0]):
                if dot >= passes[e, 0] and dist <= passes[e, 1] * radius:
                    code[i, t] = e
                    break
    for k in range(passes.shape[0]):
        for i in range(n):
            ri = -1
            pi = 1
            for t in range(nbr.shape[1]):
                j = nbr[i, t]
                if j < 0:
                    break
                if code[i, t] != k:
                    continue
                if ri < 0:  # root of i, kept up to date below
                    ri, pi = _find_root(parent, par, i)
                if parent[j] == ri:
                    continue  # already joined (the common case: no walk needed)
                rj, pj = _find_root(parent, par, j)
                if ri == rj:
                    continue
                sd = axis[i, 0] * axis[j, 0] + axis[i, 1] * axis[j, 1] + axis[i, 2] * axis[j, 2]
                rel = pi * pj if sd >= 0.0 else -pi * pj  # parity of rj relative to ri
                vj = rel * cv[rj]
                if k > 0 and cv[ri] * vj < 0.0 and abs(cv[ri]) > agree[0] * cw[ri] + agree[1] \
                        and abs(vj) > agree[0] * cw[rj] + agree[1]:
                    continue  # a weaker pair contradicting two confidently oriented components
                if size[ri] < size[rj]:  # union by size
                    parent[ri] = rj
                    par[ri] = rel
                    size[rj] += size[ri]
                    cv[rj] = vj + rel * cv[ri]
                    cw[rj] += cw[ri]
                    pi = pi * rel
                    ri = rj
                else:
                    parent[rj] = ri
                    par[rj] = rel
                    size[ri] += size[rj]
                    cv[ri] += vj
                    cw[ri] += cw[rj]
    for i in range(n):
        r, p = _find_root(parent, par, i)
        root[i] = r
        parity[i] = p


def estimate_radius(pos: np.ndarray, target_neighbours: int = 24, sample: int = 512, seed: int = 0) -> float:
    """Neighbourhood radius giving ~``target_neighbours`` neighbours on average (surface-like sets)."""
    return _estimate_radius_grid(pos, target_neighbours, sample, seed)[0]


def _estimate_radius_grid(pos, target_neighbours=24, sample=512, seed=0):
    """:func:`estimate_radius` and the last grid (:func:`_grid`) it built if that one has the
    returned radius (None otherwise), so that the caller need not build it again."""
    n = pos.shape[0]
    if n < 2:
        return 1.0, None
    ext = pos.max(axis=0) - pos.min(axis=0)
    diag = float(np.linalg.norm(ext))
    if not diag > 0.0:
        return 1.0, None
    r = diag * math.sqrt(target_neighbours / n)  # surface-like guess: area ~ diag^2
    rng = np.random.default_rng(seed)
    idx = rng.choice(n, size=min(sample, n), replace=False).astype(np.int64)
    grid = None
    for _ in range(6):
        grid = _grid(pos, r)
        slot = np.empty(n, dtype=np.int64)
        slot[grid.order] = np.arange(n, dtype=np.int64)
        counts = np.empty(idx.shape[0], dtype=np.int64)
        _count_kernel(slot[idx], grid.points, grid.origin, r, grid.mask, grid.cell_keys, grid.bucket_start, 4096,
                      counts)
        mean = float(counts.mean())
        if target_neighbours / 1.5 <= mean <= target_neighbours * 1.5:
            return r, grid
        r *= math.sqrt(target_neighbours / max(mean, 0.5))
        r = min(r, diag)
    return r, None


def gaussian_normals(positions, orientations, scales, opacities, radius: float | None = None,
                     iso_ratio: float = 0.85, n_smooth: int = 2, max_neighbours: int = 256,
                     return_fallback: bool = False):
    """Outward unit pseudo-normals (N, 3) float32; see the module docstring.

    positions (N, 3), orientations (N, 4) (w, x, y, z), scales (N, 3) linear sigma,
    opacities (N,) linear. radius: neighbourhood radius in scene units (None: automatic).
    n_smooth: consistency passes (step 5). With ``return_fallback`` also returns (N,) bool:
    True where the global-centroid fallback decided the sign.
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
    r, grid = _estimate_radius_grid(pos) if radius is None else (float(radius), None)
    if not (r > 0.0 and math.isfinite(r)):
        raise ValueError(f"normal neighbourhood radius must be > 0, got {r}")
    w = np.maximum(op.astype(np.float64), 1e-6)
    gcen = (pos * w[:, None]).sum(axis=0) / w.sum()
    # Work in grid order (points of one cell contiguous in memory: far fewer cache misses).
    grid = _grid(pos, r) if grid is None else grid
    perm = grid.order
    pos = grid.points  # pos[perm]
    quat, sc, op = quat[perm], sc[perm], op[perm]
    axis = np.empty((n, 3), dtype=np.float64)
    ratio = np.empty(n, dtype=np.float64)
    cen = np.empty((n, 3), dtype=np.float64)
    cnt = np.empty(n, dtype=np.int64)
    cov6 = np.empty((n, 6), dtype=np.float64)
    nbr = np.empty((n, _VOTE_NEIGHBOURS), dtype=np.int32)
    run_chunks(_local_stats_kernel, (n + _CHUNK - 1) // _CHUNK, pos, quat, sc, op, grid.origin, r, grid.mask,
               grid.cell_keys, grid.bucket_start, int(max_neighbours), float(iso_ratio), axis, ratio, cen, cnt,
               cov6, nbr)
    iso = np.flatnonzero((ratio > float(iso_ratio)) & (cnt >= 3))
    if iso.size:  # local PCA for nearly isotropic Gaussians (batched 3x3 eigh)
        c = cov6[iso]
        mats = np.stack([c[:, [0, 1, 2]], c[:, [1, 3, 4]], c[:, [2, 4, 5]]], axis=1)
        axis[iso] = np.linalg.eigh(mats)[1][:, :, 0]
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    off = np.einsum("ij,ij->i", pos - cen, axis)
    wv = np.where(cnt > 0, w[perm], 0.0)
    v = wv * np.clip(off / (_VOTE_CLIP * r), -1.0, 1.0)
    root = np.empty(n, dtype=np.int64)
    parity = np.empty(n, dtype=np.int8)
    passes = np.asarray(_JOIN_PASSES, dtype=np.float64).reshape(-1, 2)
    _orient_kernel(pos, axis, nbr, cnt, r, passes, float(_JOIN_TANGENTIAL), v, wv, np.asarray(_AGREE, dtype=np.float64),
                   root, parity)
    axis *= parity[:, None]
    off *= parity
    off_g = np.einsum("ij,ij->i", pos - gcen, axis)
    vote = np.bincount(root, v * parity, minlength=n)
    mass = np.bincount(root, wv * np.abs(off), minlength=n)
    wsum = np.bincount(root, wv, minlength=n)
    gvote = np.bincount(root, w[perm] * off_g, minlength=n)
    fb_c = ~(mass > 1e-4 * r * wsum)
    sign_c = np.where(fb_c, np.where(gvote < 0, -1.0, 1.0), np.where(vote < 0, -1.0, 1.0))
    # incoherent components (their members' votes cancel out: probably joined across a gap
    # between two surfaces) fall back to each Gaussian's own vote
    incoherent = (np.abs(vote) < _COHERENCE * np.bincount(root, np.abs(v), minlength=n))[root]
    fb_own = (cnt == 0) | (np.abs(off) <= 1e-4 * r)
    sign_own = np.where(fb_own, np.where(off_g < 0, -1.0, 1.0), np.where(off < 0, -1.0, 1.0))
    fb_s = np.where(incoherent, fb_own, fb_c[root])
    out = axis * np.where(incoherent, sign_own, sign_c[root])[:, None]
    sz = np.bincount(root, minlength=n)[root]
    active = incoherent | (sz < _SMOOTH_BELOW)
    tmp = np.empty_like(out)
    for _ in range(int(n_smooth)):
        run_chunks(_consistency_kernel, pos.shape[0], pos, op, out, nbr, active, tmp, min_chunk=1024)
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
