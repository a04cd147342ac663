"""The light-space footprint of an occluder in the point-light DGSM (``numba_kernels.dgsm_build``):
the octahedral map's stretch at a direction against a finite-difference Jacobian, the cap's
stretch bound against the 8-direction secant estimate (numpy references), and the tile lists
holding every (tile, occluder) pair that the secant estimate's radius gives."""

from __future__ import annotations

import math

import numpy as np

from numba_kernels import dgsm_build as db
from numba_kernels import octahedral as oc


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _basis(d):
    """The tangent basis ``_footprint`` uses: e1 = h x d (h = x unless |d_x| >= 0.9, then y), e2 = d x e1."""
    h = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = _unit(np.cross(h, d))
    return e1, np.cross(d, e1)


def _directions(rng, n, margin=0.0):
    d = _unit(rng.normal(size=(n, 3)))
    return d[np.min(np.abs(d), axis=1) > margin]


def _secant_reference(d, e1, e2, theta):
    """1.2 x the largest of the 8 secant stretches |psi(cap boundary) - psi(d)| / theta, capped at
    OCT_LIPSCHITZ (numpy, one direction at a time)."""
    uv0 = oc.encode(d[None])[0]
    a = np.arange(8) * np.pi / 4.0
    t = np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2
    p = np.cos(theta) * d + np.sin(theta) * t
    s = np.max(np.linalg.norm(oc.encode(p) - uv0, axis=1)) / theta
    return min(1.2 * s, oc.OCT_LIPSCHITZ)


def test_oct_stretch_is_the_largest_singular_value_of_the_maps_jacobian():
    rng = np.random.default_rng(3)
    d = _directions(rng, 3000, margin=1e-3)  # away from the kinks (a coordinate at 0)
    e1, e2 = _basis(d)
    h = 1e-6
    got = np.array([db.oct_stretch(*x, *a, *b) for x, a, b in zip(d, e1, e2, strict=True)])
    for k in range(len(d)):
        cols = []
        for e in (e1[k], e2[k]):  # central differences along the great circles through d
            plus = oc.encode((np.cos(h) * d[k] + np.sin(h) * e)[None])[0]
            minus = oc.encode((np.cos(h) * d[k] - np.sin(h) * e)[None])[0]
            cols.append((plus - minus) / (2.0 * h))
        ref = np.linalg.svd(np.stack(cols, axis=1), compute_uv=False)[0]
        assert abs(got[k] - ref) <= 1e-5 * ref, (d[k], got[k], ref)
    # its range: 1 at the poles of the map (+-z, where psi is the identity to first order) up to
    # the map's Lipschitz bound
    assert got.min() > 0.5 and got.max() <= oc.OCT_LIPSCHITZ
    e1, e2 = _basis(np.array([[0.0, 0.0, 1.0]]))
    assert abs(db.oct_stretch(0.0, 0.0, 1.0, *e1[0], *e2[0]) - 1.0) < 1e-12


def test_small_cap_bound_is_never_below_the_secant_estimate():
    """On random caps (radii 1e-5 to 0.5 rad) the small-cap bound, where it applies, is at least
    the secant estimate (so a footprint never shrinks) and at most 5 % above 1.2 times the stretch
    at the centre; it declines the caps that reach an octant's border and the large ones."""
    rng = np.random.default_rng(5)
    d = _directions(rng, 60000)
    e1, e2 = _basis(d)
    theta = np.exp(rng.uniform(np.log(1e-5), np.log(0.5), len(d)))
    bound = np.array([db.small_cap_stretch(*x, *a, *b, t, math.tan(t))
                      for x, a, b, t in zip(d, e1, e2, theta, strict=True)])
    uv = oc.encode(d)
    secant = np.array([db.secant_stretch(*x, *a, *b, t, *q)
                       for x, a, b, t, q in zip(d, e1, e2, theta, uv, strict=True)])
    centre = np.array([db.oct_stretch(*x, *a, *b) for x, a, b in zip(d, e1, e2, strict=True)])
    ref = np.array([_secant_reference(x, a, b, t) for x, a, b, t in zip(d[:4000], e1[:4000], e2[:4000],
                                                                            theta[:4000], strict=True)])
    np.testing.assert_allclose(secant[:4000], ref, rtol=1e-12)
    used = bound > 0.0
    assert 0.3 < used.mean() < 0.8  # (the small caps among these radii)
    assert np.all(bound[used] >= secant[used])
    assert np.all(bound[used] <= np.minimum(1.2 * 1.05 * centre[used], oc.OCT_LIPSCHITZ) * (1 + 1e-12))
    kink = np.min(np.abs(d), axis=1) <= np.tan(theta)
    large = db.STRETCH_RATE * theta > db.SMALL_CAP_SLACK * centre
    assert kink.any() and large.any() and np.array_equal(used, ~kink & ~large)


def _reference_pairs(light, mu, cone, w):
    """(tile, occluder) pairs of the secant estimate's footprint: the 8x8-pixel tiles of the box
    of radius ``theta * L * W / 2 + 1`` pixels around each occluder's centre direction, fold-wrapped."""
    wt = w // db.TILE
    pairs = set()
    for i in range(len(mu)):
        if cone[i, 3] < -1.0:  # global (light inside or near the occluder)
            continue
        d = _unit(mu[i] - light)
        theta = math.acos(min(cone[i, 3], 1.0))
        e1, e2 = _basis(d[None])
        rp = theta * _secant_reference(d, e1[0], e2[0], theta) * 0.5 * w + 1.0
        fx, fy = (oc.encode(d[None])[0] + 1.0) * 0.5 * w - 0.5
        for tx in range(math.floor((fx - rp) / db.TILE), math.floor((fx + rp) / db.TILE) + 1):
            for ty in range(math.floor((fy - rp) / db.TILE), math.floor((fy + rp) / db.TILE) + 1):
                a, b = oc.wrap(np.array([[tx, ty]]), wt)[0]
                pairs.add((int(a * wt + b), i))
    return pairs


def test_tile_lists_hold_every_pair_of_the_secant_footprints():
    rng = np.random.default_rng(11)
    w, n = 256, 1500
    light = np.array([0.1, 0.2, 2.0])
    # occluders all around the light (every octant, seams and poles), 1-4 m away, 1-5 mm sigmas
    # (an avatar's), a tenth of them ten times that
    mu = light + _unit(rng.normal(size=(n, 3))) * rng.uniform(1.0, 4.0, (n, 1))
    mu[:20, :2] = light[:2] + rng.normal(scale=1e-3, size=(20, 2))  # near the map's +-z poles
    rot = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    sig = rng.uniform(0.001, 0.005, (n, 3)) * np.where(rng.random((n, 1)) < 0.1, 10.0, 1.0)
    cov = np.einsum("nij,nj,nkj->nik", rot, sig ** 2, rot)
    cov6 = db.covariance6(cov)
    active = np.ones((w // db.TILE) ** 2, np.bool_)
    start, items, glob, cone = db.bin_tiles(light, mu, cov6, w, 3.0, active)
    got = {(t, int(i)) for t in range(len(start) - 1) for i in items[start[t]:start[t + 1]]}
    ref = _reference_pairs(light, mu, cone, w)
    assert len(ref) > 2 * n and ref <= got
    # (the small-cap bound applies to most of them)
    d = _unit(mu - light)
    e1, e2 = _basis(d)
    theta = np.arccos(np.clip(cone[:, 3], -1.0, 1.0))
    small = [db.small_cap_stretch(*x, *a, *b, t, math.tan(t)) > 0 for x, a, b, t in zip(d, e1, e2, theta, strict=True)]
    assert np.mean(small) > 0.5
    assert len(got) < 1.1 * len(ref)  # (the small-cap bound's extra tiles)
    # each tile's list in increasing occluder order (the accumulation's summation order)
    assert all(np.all(np.diff(items[start[t]:start[t + 1]]) > 0) for t in range(len(start) - 1))
