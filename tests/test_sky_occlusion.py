"""The sky a moving caster hides (usd_gs.shadows.sky_occlusion) against numerical integration."""

import numpy as np

from usd_gs.colorspace import srgb_encode
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.shot import Receivers, prim_spheres
from usd_gs.shadows.sky_occlusion import (
    hidden_sky_share,
    min_hidden_share,
    sky_factor,
    sphere_proxy,
    static_sky_factors,
)

UP = np.array([0.0, 1.0, 0.0])


def _hemisphere_hidden(x, n, c, r, m=200_000, seed=0):
    """Cosine-weighted share of the hemisphere around ``n`` whose rays from ``x`` hit the sphere."""
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random(m), rng.random(m)
    t1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    rr, ph = np.sqrt(u1), 2 * np.pi * u2  # cosine-weighted directions (Malley)
    d = (rr * np.cos(ph))[:, None] * t1 + (rr * np.sin(ph))[:, None] * t2 + np.sqrt(1 - u1)[:, None] * n
    v = c - x
    b = d @ v
    hit = (b > 0) & (b * b - (v @ v - r * r) >= 0)
    return hit.mean()


def test_sphere_share_equals_integrated_form_factor():
    x = np.zeros(3)
    for c, r in ((np.array([0.3, 1.0, -0.2]), 0.25), (np.array([1.5, 0.6, 0.4]), 0.3), (np.array([0, 3.0, 0]), 0.5)):
        got = hidden_sky_share(c[None], np.array([r]), x[None], UP[None])[0]
        ref = _hemisphere_hidden(x, UP, c, r)
        assert abs(got - ref) < 0.004 + 0.02 * ref, (got, ref)
    # inside a sphere: wholly hidden; two-sided normals
    assert hidden_sky_share(np.zeros((1, 3)), np.array([1.0]), np.zeros((1, 3)), UP[None])[0] == 1.0
    a = hidden_sky_share(np.array([[0, 1.0, 0]]), np.array([0.3]), np.zeros((1, 3)), -UP[None])
    np.testing.assert_allclose(a, 0.09)


def _box_cloud(lo, hi, n=20_000, seed=1):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    p = lo + rng.random((n, 3)) * (hi - lo)
    face = rng.integers(0, 3, n)
    side = rng.integers(0, 2, n)
    p[np.arange(n), face] = np.where(side == 1, hi[face], lo[face])  # on the box's faces
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    return GaussianSet(p, q, np.full((n, 3), 0.01), np.full(n, 0.9), np.zeros((n, 1, 3)))


def test_sphere_proxy_of_an_avatar_sized_box():
    g = _box_cloud((0.0, 0.0, 0.0), (0.45, 1.75, 0.3))
    c, r = sphere_proxy(g, UP, n=8)
    assert len(r) == 8
    np.testing.assert_allclose(c[:, [0, 2]], np.tile([0.225, 0.15], (8, 1)), atol=0.03)
    assert np.all(np.diff(c[:, 1]) > 0.15)
    slab = 1.75 * 0.98 / 8  # percentile-trimmed height per slab
    np.testing.assert_allclose(r, np.sqrt(slab * 0.375 * 0.96 / np.pi), rtol=0.1)


def test_sky_factor_analytic_and_monotone():
    h = np.linspace(0.0, 1.0, 11)
    np.testing.assert_allclose(sky_factor(np.zeros(3), np.ones(3), 0.7, 0.9, 0.4), 1.0)
    # all sky (D = 0): Y'(L (1 - h)) / Y'(L)
    np.testing.assert_allclose(sky_factor(h, np.ones(11), 0.0, 1.0, 0.3), srgb_encode(0.3 * (1 - h)) / srgb_encode(0.3))
    f = sky_factor(h, np.ones(11), 0.75, 0.8, 0.4)
    assert np.all(np.diff(f) <= 0) and f[-1] > 0
    # in a full sun shadow the sky is all the light left: a larger relative loss
    assert np.all(sky_factor(h[1:], np.zeros(10), 0.75, 0.8, 0.4) < f[1:])


def test_static_factors_follow_the_caster_and_the_tolerance():
    rng = np.random.default_rng(2)
    m = 40_000
    p = np.stack([rng.uniform(-4, 4, m), np.zeros(m), rng.uniform(-4, 4, m)], 1)
    q = np.tile([1.0, 0, 0, 0], (m, 1))
    ground = GaussianSet(p, q, np.tile([0.02, 0.001, 0.02], (m, 1)), np.ones(m), np.zeros((m, 1, 3)))
    recv = Receivers.build([("/g", ground)])
    caster = _box_cloud((0.0, 0.0, 0.0), (0.45, 1.75, 0.3))
    params = (0.75, 0.9, 0.35)
    tol = 1 / 512
    idx, k = static_sky_factors([caster], recv, prim_spheres(recv), UP, params, tol)
    assert idx.size and np.all(np.diff(idx) > 0) and np.all(k < 1) and k.dtype == np.float32
    c, r = sphere_proxy(caster, UP)
    h = hidden_sky_share(c, r, p, np.tile(UP, (m, 1)))
    np.testing.assert_allclose(k, sky_factor(h[idx], np.ones(idx.size), *params), rtol=1e-6)
    h_min = min_hidden_share(params, tol)
    assert np.all(h[idx] >= h_min) and not np.any(np.setdiff1d(np.flatnonzero(h >= h_min), idx))
    assert abs((1 - sky_factor(np.array([h_min]), np.ones(1), *params)[0]) - tol) < 1e-6
    # a receiver in the sun shadow gets the darker factor for its transmittance
    i0 = idx[np.argmin(k)]
    _, k2 = static_sky_factors([caster], recv, prim_spheres(recv), UP, params, tol, sun_t=(np.array([i0]), [0.0]))
    assert k2[np.searchsorted(idx, i0)] < k.min()
    # no sky in the lights: nothing
    none_i, _ = static_sky_factors([caster], recv, prim_spheres(recv), UP, (1.0, 1.0, 0.35), tol)
    assert none_i.size == 0


def test_kernel_equals_numpy_reference():
    from numba_kernels.reference.sky_occlusion import hidden_sky_share as reference
    from numba_kernels.sky_occlusion import hidden_sky_share as kernel

    rng = np.random.default_rng(5)
    c = rng.uniform(-1, 1, (8, 3)) + [0, 1.0, 0]
    r = rng.uniform(0.05, 0.3, 8)
    x = np.concatenate([rng.uniform(-3, 3, (20_000, 3)) * [1, 0, 1], c[:3] + 0.01])  # some inside spheres
    n = rng.normal(size=(len(x), 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    got = kernel(c, r, x, n)
    np.testing.assert_allclose(got, reference(c, r, x, n), rtol=1e-12, atol=1e-15)
    assert np.all(got[-3:] == 1.0) and 0.0 < np.median(got) < 0.5 and got.min() >= 0.0
