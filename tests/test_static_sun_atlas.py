"""The static scene's shot-long directional DGSM (StaticSceneSunAtlas) against the exact
transmittance, and its columns independent of the order they are computed in (farm chunks)."""

import numpy as np
from dgsm_testutil import random_occluders

from numba_kernels.dgsm_directional import lattice_columns, light_basis
from numba_kernels.dgsm_exact import transmittance_directional
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import DGSMConfig
from usd_gs.shadows.static_scene import StaticSceneSunAtlas

LDIR = np.array([0.35, -0.8, 0.25])


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    mu, q, s, a, *_ = random_occluders(rng, 400, centre=(0.0, 1.0, 0.0), spread=0.35, log_s=(-4.5, -2.5),
                                       alpha=(0.3, 0.99))
    n = 3000  # a ground of flat Gaussians below
    g = np.stack([rng.uniform(-1.5, 1.5, n), np.zeros(n), rng.uniform(-1.5, 1.5, n)], 1)
    half = np.sqrt(0.5)
    pos = np.concatenate([mu, g])
    quat = np.concatenate([q, np.tile([half, -half, 0.0, 0.0], (n, 1))])
    sc = np.concatenate([s, np.tile([0.03, 0.03, 0.002], (n, 1))])
    op = np.concatenate([a, np.full(n, 0.95)])
    return GaussianSet(pos, quat, sc, op, np.zeros((len(pos), 1, 3)))


def test_lookups_close_to_exact_and_refined_at_edges():
    scene = _scene()
    cfg = DGSMConfig(sampling="center")
    atlas = StaticSceneSunAtlas(scene, LDIR, cfg, pitch=0.01)
    rng = np.random.default_rng(1)
    # receivers: an avatar-like cloud above the ground, and points 1 cm above it (feet)
    pts = np.concatenate([rng.uniform([-0.8, 0.2, -0.8], [0.8, 1.8, 0.8], (3000, 3)),
                          np.stack([rng.uniform(-1, 1, 1000), np.full(1000, 0.01), rng.uniform(-1, 1, 1000)], 1)])
    got = atlas.transmittance(pts)
    occ, dep = atlas.occ, atlas.dir_dep
    ex = transmittance_directional(light_basis(LDIR)[2], pts, occ, dep)
    err = np.abs(got - ex)
    assert err.mean() < 0.01 and np.quantile(err, 0.99) < 0.1
    assert (ex < 0.5).mean() > 0.05  # real shadows are exercised
    # the feet just above the ground: the coarse depth bins blend the ground's full depth in, the
    # refinement restores them
    feet = slice(3000, 4000)
    assert np.abs(got[feet] - ex[feet]).max() < 0.05
    # a second lookup reuses the columns: the same values, nothing new computed
    n = atlas.computed_pixels
    np.testing.assert_array_equal(atlas.transmittance(pts), got)
    assert atlas.computed_pixels == n


def test_columns_do_not_depend_on_what_else_is_computed():
    scene = _scene(2)
    cfg = DGSMConfig(sampling="center")
    a = StaticSceneSunAtlas(scene, LDIR, cfg, pitch=0.01)
    b = StaticSceneSunAtlas(scene, LDIR, cfg, pitch=0.01)
    rng = np.random.default_rng(3)
    p1 = rng.uniform([-0.8, 0.2, -0.8], [0.0, 1.8, 0.0], (1500, 3))
    p2 = rng.uniform([-0.4, 0.2, -0.4], [0.8, 1.8, 0.8], (1500, 3))
    a.transmittance(p1)
    a.transmittance(p2)  # frame by frame
    b.transmittance(np.concatenate([p2, p1]))  # all at once, another order
    assert a.computed_pixels == b.computed_pixels
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(a.transmittance(p1), b.transmittance(p1))


def test_lattice_columns_equal_exact_voxels():
    scene = _scene(4)
    cfg = DGSMConfig(sampling="center", k_sigma=8.0)
    at = StaticSceneSunAtlas(scene, LDIR, cfg, pitch=0.02, K=16)
    ij = np.array([[i, j] for i in range(-30, 30, 7) for j in range(-30, 30, 5)], np.int64)
    vals, pairs = lattice_columns(at.basis, at.occ, at.dir_dep, at.cov6, at.c, at.h, ij, at.tb, at.ds, at.K,
                                  cfg.k_sigma)
    e1, e2, l = at.basis
    s = at.tb + (np.arange(at.K) + 0.5) * at.ds
    base = at.c + ((ij[:, 0] + 0.5) * at.h)[:, None] * e1 + ((ij[:, 1] + 0.5) * at.h)[:, None] * e2
    vox = (base[:, None, :] + s[None, :, None] * l).reshape(-1, 3)
    ex = transmittance_directional(l, vox, at.occ, at.dir_dep).reshape(len(ij), -1)
    np.testing.assert_allclose(vals, ex, atol=2e-6 + np.exp(-12.0))
    assert pairs > 0 and (ex < 0.5).any()
