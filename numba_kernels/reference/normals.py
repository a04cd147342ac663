"""Reference of :mod:`numba_kernels.normals` (tests only): the same five steps as its module
docstring, written the slow, obvious way.

Neighbours from a dense distance matrix (all of them, sorted by distance then index; the kernel
keeps the first ``max_neighbours`` it meets, the same set whenever no Gaussian has more), the
smallest axis from the Hamilton rotation of :mod:`numba_kernels.reference.quaternion`, local PCA
with ``np.linalg.eigh`` one Gaussian at a time, the signed union-find as plain Python over
Gaussians in input order (the kernel goes in grid order: where a join is refused or a cycle of
relative signs contradicts itself the two may differ; on a smooth surface they agree), votes and
per-component sums with Python loops, the consistency passes as dense sums. O(N^2) memory: a
few thousand Gaussians at most.
"""

from __future__ import annotations

import math

import numpy as np

from .quaternion import hamilton_rotation

# the constants of the method (module docstring of numba_kernels.normals), restated
VOTE_NEIGHBOURS = 32
JOIN_PASSES = ((0.98, 1.0), (0.9, 0.6))
JOIN_TANGENTIAL = 0.35
AGREE = (0.3, 10.0)
COHERENCE = 0.3
SMOOTH_BELOW = 32
VOTE_CLIP = 0.05


def smallest_axis(q, s) -> tuple[np.ndarray, float]:
    """Column of R(q) of the smallest scale (the first one on ties) and smallest / middle scale."""
    k = int(np.argmin(s))
    others = [s[(k + 1) % 3], s[(k + 2) % 3]]
    mid = min(others)
    return hamilton_rotation(*np.asarray(q, np.float64))[:, k], (s[k] / mid if mid > 0 else 1.0)


def neighbour_lists(pos, radius):
    """Per Gaussian the indices j != i with ``|p_j - p_i|^2 <= radius^2``, nearest first."""
    d = pos[None, :, :] - pos[:, None, :]
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    out = []
    for i in range(len(pos)):
        js = np.flatnonzero((d2[i] <= radius * radius) & (np.arange(len(pos)) != i))
        out.append(js[np.lexsort((js, d2[i, js]))])
    return out


def estimate_radius(pos, target_neighbours: int = 24, sample: int = 512, seed: int = 0) -> float:
    """``normals.estimate_radius``: the surface-like guess ``diag sqrt(target / N)``, rescaled until
    the mean neighbour count of the same random sample is within a factor 1.5 of the target."""
    pos = np.asarray(pos, np.float64).reshape(-1, 3)
    n = len(pos)
    if n < 2:
        return 1.0
    diag = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))
    if not diag > 0.0:
        return 1.0
    r = diag * math.sqrt(target_neighbours / n)
    idx = np.random.default_rng(seed).choice(n, size=min(sample, n), replace=False)
    for _ in range(6):
        d2 = ((pos[idx][:, None, :] - pos[None, :, :]) ** 2).sum(-1)
        counts = np.minimum((d2 <= r * r).sum(1) - 1, 4096)
        mean = float(counts.mean())
        if target_neighbours / 1.5 <= mean <= target_neighbours * 1.5:
            return r
        r = min(r * math.sqrt(target_neighbours / max(mean, 0.5)), diag)
    return r


def _find(parent, par, i):
    p = 1
    while parent[i] != i:
        p *= par[i]
        i = parent[i]
    return i, p


def _orient(pos, axis, nbr, count, radius, vote, weight):
    """Signed union-find (step 3): per Gaussian its component root and parity (+-1)."""
    n = len(pos)
    parent, par, size = list(range(n)), [1] * n, [1] * n
    cv, cw = list(vote), list(weight)
    code = {}
    for i in range(n):
        for j in nbr[i]:
            if j < i and count[j] <= VOTE_NEIGHBOURS:
                continue  # the pair is tried as (j, i)
            off = pos[j] - pos[i]
            dist = math.sqrt(float(off @ off))
            if abs(off @ axis[i]) > JOIN_TANGENTIAL * dist or abs(off @ axis[j]) > JOIN_TANGENTIAL * dist:
                continue
            dot = abs(float(axis[i] @ axis[j]))
            for e, (cos_min, reach) in enumerate(JOIN_PASSES):
                if dot >= cos_min and dist <= reach * radius:
                    code[i, j] = e
                    break
    for k in range(len(JOIN_PASSES)):
        for i in range(n):
            for j in nbr[i]:
                if code.get((i, j)) != k:
                    continue
                ri, pi = _find(parent, par, i)
                rj, pj = _find(parent, par, j)
                if ri == rj:
                    continue
                rel = pi * pj if axis[i] @ axis[j] >= 0.0 else -pi * pj
                vj = rel * cv[rj]
                if k > 0 and cv[ri] * vj < 0.0 and abs(cv[ri]) > AGREE[0] * cw[ri] + AGREE[1] \
                        and abs(vj) > AGREE[0] * cw[rj] + AGREE[1]:
                    continue
                if size[ri] < size[rj]:
                    parent[ri], par[ri] = rj, rel
                    size[rj] += size[ri]
                    cv[rj] = vj + rel * cv[ri]
                    cw[rj] += cw[ri]
                else:
                    parent[rj], par[rj] = ri, rel
                    size[ri] += size[rj]
                    cv[ri] += vj
                    cw[ri] += cw[rj]
    found = [_find(parent, par, i) for i in range(n)]
    return np.array([r for r, _ in found], np.int64), np.array([p for _, p in found], np.float64)


def gaussian_normals(positions, orientations, scales, opacities, radius: float | None = None,
                     iso_ratio: float = 0.85, n_smooth: int = 2, return_fallback: bool = False):
    """``normals.gaussian_normals``: outward unit pseudo-normals (N, 3) float32 (and the (N,) bool
    global-centroid fallback mask with ``return_fallback``)."""
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    quat = np.asarray(orientations, np.float32).reshape(-1, 4)
    sc = np.asarray(scales, np.float32).reshape(-1, 3)
    w = np.maximum(np.asarray(opacities, np.float32).reshape(-1).astype(np.float64), 1e-6)
    n = len(pos)
    r = estimate_radius(pos) if radius is None else float(radius)
    gcen = (pos * w[:, None]).sum(axis=0) / w.sum()
    nb = neighbour_lists(pos, r)
    count = np.array([len(js) for js in nb])
    nbr = [js[:VOTE_NEIGHBOURS] for js in nb]
    # 1. axes, own offsets from the neighbours' centroid
    axis = np.zeros((n, 3))
    cen = pos.copy()
    for i in range(n):
        a, ratio = smallest_axis(quat[i], sc[i].astype(np.float64))
        if count[i]:
            cen[i] = (w[nb[i], None] * pos[nb[i]]).sum(0) / w[nb[i]].sum()
        if ratio > iso_ratio and count[i] >= 3:  # nearly isotropic: local PCA
            d = pos[nb[i]] - cen[i]
            a = np.linalg.eigh((w[nb[i], None, None] * d[:, :, None] * d[:, None, :]).sum(0))[1][:, 0]
        axis[i] = a / np.linalg.norm(a)
    off = ((pos - cen) * axis).sum(1)
    wv = np.where(count > 0, w, 0.0)
    v = wv * np.clip(off / (VOTE_CLIP * r), -1.0, 1.0)
    # 2.-4. components and their signs
    root, parity = _orient(pos, axis, nbr, count, r, v, wv)
    axis = axis * parity[:, None]
    off = off * parity
    off_g = ((pos - gcen) * axis).sum(1)
    out = np.zeros((n, 3))
    fb = np.zeros(n, bool)
    members = {c: np.flatnonzero(root == c) for c in np.unique(root)}
    for m in members.values():
        vote = (v[m] * parity[m]).sum()
        if abs(vote) < COHERENCE * np.abs(v[m]).sum():  # votes cancel: each Gaussian its own vote
            for i in m:
                own_fb = count[i] == 0 or abs(off[i]) <= 1e-4 * r
                fb[i] = own_fb
                out[i] = axis[i] * (np.sign(off_g[i] if own_fb else off[i]) or 1.0)
            continue
        comp_fb = not (wv[m] * np.abs(off[m])).sum() > 1e-4 * r * wv[m].sum()
        s = (w[m] * off_g[m]).sum() if comp_fb else vote
        fb[m] = comp_fb
        out[m] = axis[m] * (-1.0 if s < 0 else 1.0)
    # 5. consistency passes over small or incoherent components
    coherent = {c: abs((v[m] * parity[m]).sum()) >= COHERENCE * np.abs(v[m]).sum() for c, m in members.items()}
    active = np.array([len(members[c]) < SMOOTH_BELOW or not coherent[c] for c in root])
    for _ in range(int(n_smooth)):
        new = out.copy()
        for i in np.flatnonzero(active):
            total = 0.0
            for j in nbr[i]:
                d = pos[j] - pos[i]
                if abs(d @ out[i]) <= 0.5 * math.sqrt(float(d @ d)):
                    total += w[j] * float(out[i] @ out[j])
            new[i] = -out[i] if total < 0.0 else out[i]
        out = new
    res = out.astype(np.float32)
    return (res, fb) if return_fallback else res


def normals_to_local(orientations, normals) -> np.ndarray:
    """``R(q)^T n`` (N, 3) float32."""
    q = np.asarray(orientations, np.float64).reshape(-1, 4)
    v = np.asarray(normals, np.float64).reshape(-1, 3)
    return np.array([hamilton_rotation(*q[i]).T @ v[i] for i in range(len(q))], np.float32).reshape(-1, 3)


def local_normals_to_world(orientations, local) -> np.ndarray:
    """``R(q) n_local`` (N, 3) float32."""
    q = np.asarray(orientations, np.float64).reshape(-1, 4)
    v = np.asarray(local, np.float64).reshape(-1, 3)
    return np.array([hamilton_rotation(*q[i]) @ v[i] for i in range(len(q))], np.float32).reshape(-1, 3)
