"""The cost cuts of the directional DGSM build against the exact transmittance: occluders sorted by support
start, a pixel's cut at its deepest read bin and where its ray turns opaque, the projected-ellipse
test (directional), and the exact per-point directional path (``transmittance_points``)."""

import numpy as np
import pytest
from dgsm_testutil import random_occluders

from numba_kernels.dgsm_build import TAU_OPAQUE, support_starts
from numba_kernels.dgsm_directional import build_directional, lookup_directional, pixel_rays, transmittance_points
from numba_kernels.dgsm_exact import transmittance_directional
from numba_kernels.dgsm_model import pack_gaussians

LDIR = np.array([0.3, -1.0, 0.2])


def _opaque_wall(rng, n=400, y=1.0, half=0.4, s=0.03, alpha=0.999):
    """A dense layer of nearly opaque flat Gaussians at height ``y`` (several per ray)."""
    mu = np.stack([rng.uniform(-half, half, n), y + rng.normal(0, 0.01, n), rng.uniform(-half, half, n)], 1)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    sc = np.tile([s, s * 0.2, s], (n, 1))
    return pack_gaussians(mu, q, sc, np.full(n, alpha), 1.0, "avg")


def _mixed_scene(seed):
    """A wall with holes (some rays opaque, some not), free occluders before it and behind the
    receivers (which must not count), hard scales and opacities near 1."""
    rng = np.random.default_rng(seed)
    occ_w, dd, cov_w = _opaque_wall(rng)
    keep = np.hypot(occ_w[:, 0], occ_w[:, 2]) > 0.12  # a hole in the middle
    *_, occ_f, _, cov_f = random_occluders(rng, 150, centre=(0, 1.5, 0), spread=0.25, log_s=(-5.0, -1.5),
                                           alpha=(0.05, 0.9999))
    *_, occ_b, _, cov_b = random_occluders(rng, 150, centre=(0, -0.6, 0), spread=0.2, log_s=(-4.0, -2.0))
    occ = np.concatenate([occ_w[keep], occ_f, occ_b])
    cov6 = np.concatenate([cov_w[keep], cov_f, cov_b])
    pts = np.stack([rng.uniform(-0.5, 0.5, 2500), rng.uniform(-0.05, 0.3, 2500), rng.uniform(-0.5, 0.5, 2500)], 1)
    return occ, dd, cov6, pts


@pytest.mark.parametrize("seed", [0, 1])
def test_directional_points_equal_exact(seed):
    occ, dd, cov6, pts = _mixed_scene(seed)
    got, pairs = transmittance_points(LDIR, occ, dd, cov6, pts, k_sigma=8.0)
    ex = transmittance_directional(LDIR, pts, occ, dd)
    # truncations: ellipse culling at 8 sigma (exp(-32) of a peak) and the opaque stop (T < exp(-12))
    np.testing.assert_allclose(got, ex, atol=np.exp(-TAU_OPAQUE) + 1e-9)
    assert (ex < 1e-6).mean() > 0.3 and (ex > 0.5).mean() > 0.05  # both regimes are exercised
    assert np.isfinite(got).all() and pairs < len(occ) * len(pts) / 4


@pytest.mark.parametrize("seed", [0, 1])
def test_directional_atlas_voxels_exact_despite_cuts(seed):
    """Every voxel of the atlas equals the exact transmittance at its centre (to the opaque stop):
    the ROI points are repeated deeper along the light, so every pixel's deepest read bin is the
    last one and no voxel is left partial by the per-pixel cut."""
    occ, dd, cov6, pts = _mixed_scene(seed)
    l = LDIR / np.linalg.norm(LDIR)
    at = build_directional(LDIR, occ, dd, cov6, np.concatenate([pts, pts + 2.0 * l]), width=48, K=24, k_sigma=8.0)
    vox, _ = pixel_rays(at)
    ex = transmittance_directional(l, vox, occ, dd).reshape(len(at.pixels), -1)
    np.testing.assert_allclose(at.values, ex, atol=2e-6 + np.exp(-TAU_OPAQUE))
    assert (ex < 1e-6).mean() > 0.2 and (ex > 0.5).mean() > 0.1
    assert at.pairs < 0.5 * len(occ) * len(at.pixels)
    got = lookup_directional(build_directional(LDIR, occ, dd, cov6, pts, width=256, K=32, k_sigma=8.0), pts)
    assert np.abs(got - transmittance_directional(l, pts, occ, dd)).mean() < 0.02  # interpolation only


def test_support_starts_bound_the_depth_added_before_them():
    """No occluder adds depth before its support start on a ray through its k-sigma ellipsoid."""
    rng = np.random.default_rng(5)
    *_, occ, dd, cov6 = random_occluders(rng, 200, spread=0.3, log_s=(-4.0, -1.0), alpha=(0.5, 0.9999))
    l = LDIR / np.linalg.norm(LDIR)
    sig_l = np.sqrt(np.einsum("i,nij,j->n", l, np.stack([
        np.stack([cov6[:, 0], cov6[:, 1], cov6[:, 2]], 1), np.stack([cov6[:, 1], cov6[:, 3], cov6[:, 4]], 1),
        np.stack([cov6[:, 2], cov6[:, 4], cov6[:, 5]], 1)], 1), l))
    st = support_starts(occ[:, :3] @ l, occ, 4.0, sig_l)
    for i in range(0, 200, 7):
        # a point on a ray through the occluder's ellipsoid, at the support start: almost no depth yet
        off = rng.normal(size=3)
        off -= (off @ l) * l
        x = occ[i, :3] + 0.5 * off / np.linalg.norm(off) * sig_l[i] + (st[i] - occ[i, :3] @ l) * l
        t = transmittance_directional(l, x[None], occ[i:i + 1], dd)[0]
        full = transmittance_directional(l, (x + 10.0 * l)[None], occ[i:i + 1], dd)[0]
        assert -np.log(t) <= 1e-6 * max(-np.log(full), 1e-300) + 1e-300
