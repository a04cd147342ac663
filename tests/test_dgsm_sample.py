"""DGSM lookup: trilinear interpolation, fold continuity, footprint stencils, MC determinism."""

import math

import numpy as np
import pytest
from dgsm_testutil import quat_to_mat, random_occluders, random_rotations

from numba_kernels import octahedral as oc
from numba_kernels.dgsm_build import Atlas, build_point
from numba_kernels.dgsm_exact import transmittance_point
from numba_kernels.dgsm_sample import footprint_points, lookup_point, stencil_offsets, weighted_mean
from numba_kernels.reference import dgsm_sample as reference

LIGHT = np.array([0.3, -0.2, 0.5])


def _atlas_from_function(f, w, K, t_max):
    """A full atlas whose voxel (i, j, k) holds f(direction of pixel centre, t_k)."""
    dirs = oc.pixel_directions(w).reshape(-1, 3)
    tk = (np.arange(K) + 0.5) * t_max / K
    vals = f(dirs[:, None, :], tk[None, :]).astype(np.float32)
    idx = np.arange(w * w, dtype=np.int32)
    return Atlas(w, K, t_max, 0, K - 1, idx, vals, np.arange(w * w), 0, 0)


def _smooth(d, t):
    return 0.5 + 0.2 * d[..., 0] + 0.15 * d[..., 1] * d[..., 2] + 0.1 * d[..., 2] - 0.02 * t


def test_lookup_at_centres_returns_the_voxel():
    w, K, tmax = 16, 8, 4.0
    at = _atlas_from_function(_smooth, w, K, tmax)
    dirs = oc.pixel_directions(w).reshape(-1, 3)
    for k in (0, 3, 7):
        t = (k + 0.5) * tmax / K
        got = lookup_point(at, LIGHT, LIGHT + t * dirs)
        np.testing.assert_allclose(got, at.values[:, k], atol=1e-12)


def test_trilinear_matches_manual_interpolation():
    rng = np.random.default_rng(0)
    w, K, tmax = 16, 8, 4.0
    at = _atlas_from_function(_smooth, w, K, tmax)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0.6, 3.7, 300)
    got = lookup_point(at, LIGHT, LIGHT + t[:, None] * d)
    ref = reference.lookup_point(at, LIGHT, LIGHT + t[:, None] * d)
    np.testing.assert_allclose(got, ref, atol=1e-6)


def test_lookup_matches_the_reference_near_the_light_and_beyond_the_last_bin():
    rng = np.random.default_rng(8)
    w, K, tmax = 8, 6, 3.0
    at = _atlas_from_function(_smooth, w, K, tmax)
    d = rng.normal(size=(400, 3))
    t = np.concatenate([rng.uniform(0.0, tmax / K, 200), rng.uniform(tmax - tmax / K, 1.5 * tmax, 200)])
    pts = LIGHT + t[:, None] * d / np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(lookup_point(at, LIGHT, pts), reference.lookup_point(at, LIGHT, pts), atol=1e-6)


def test_interpolation_is_continuous_across_fold_and_corners():
    w, K, tmax = 32, 4, 2.0
    at = _atlas_from_function(_smooth, w, K, tmax)
    h = 1e-9
    # straddle the equator fold (z = 0), the -z corner, and the lower-hemisphere seams x = 0 / y = 0
    base = np.array([[0.8, 0.6, 0.0], [0.0, 0.0, -1.0], [0.0, 0.7, -0.7], [0.6, 0.0, -0.8], [-0.3, 1e-3, -0.95]])
    for b in base:
        for e in np.eye(3):
            p1 = b + h * e
            p2 = b - h * e
            v = lookup_point(at, np.zeros(3), np.stack([p1, p2]) / np.linalg.norm(b) * 1.0)
            assert abs(v[0] - v[1]) < 1e-6
    # and the interpolant follows the smooth function everywhere (O(pixel^2) error)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = (np.arange(K) + 0.5)[rng.integers(0, K, 4000)] * tmax / K
    got = lookup_point(at, np.zeros(3), t[:, None] * d)
    assert np.abs(got - _smooth(d, t)).max() < 0.02  # pixel pitch ~0.1 rad at W = 32


def test_below_first_bin_interpolates_to_one_and_sparse_table_reads_one():
    w, K, tmax = 8, 4, 4.0
    at = _atlas_from_function(lambda d, t: 0.0 * t + 0.2 + 0 * d[..., 0], w, K, tmax)
    d = np.array([0.0, 0.0, 1.0])
    got = lookup_point(at, np.zeros(3), np.array([0.25 * d, 0.0 * d, 0.5 * d]))
    np.testing.assert_allclose(got, [0.6, 1.0, 0.2], atol=1e-7)  # t=0.25: halfway between 1 (t=0) and bin 0
    sparse = Atlas(w, K, tmax, 0, K - 1, np.full(w * w, -1, np.int32), np.zeros((0, K), np.float32),
                   np.zeros(0, np.int64), 0, 0)
    assert np.all(lookup_point(sparse, np.zeros(3), np.array([[0.3, 0.2, 1.0]])) == 1.0)


def test_footprint_points_and_weights():
    rng = np.random.default_rng(2)
    m = 5
    mu = rng.normal(size=(m, 3))
    rot = quat_to_mat(random_rotations(rng, m))
    s = np.exp(rng.uniform(-3, -1, size=(m, 3)))
    z, w = stencil_offsets("center", 1, m)
    np.testing.assert_allclose(footprint_points(mu, rot, s, z), mu)
    z, w = stencil_offsets("stencil7", 7, m)
    assert w.shape == (7,) and abs(w.sum() - 1) < 1e-15 and w[0] > w[1] == w[6]
    p = footprint_points(mu, rot, s, z).reshape(m, 7, 3)
    np.testing.assert_allclose(p[:, 0], mu)
    for ax in range(3):
        np.testing.assert_allclose(p[:, 1 + 2 * ax] - mu, rot[:, :, ax] * s[:, ax:ax + 1], atol=1e-14)
        np.testing.assert_allclose(p[:, 2 + 2 * ax] - mu, -rot[:, :, ax] * s[:, ax:ax + 1], atol=1e-14)
    z1, w1 = stencil_offsets("mc", 8, m, seed=3)
    z2, _ = stencil_offsets("mc", 8, m, seed=3)
    z3, _ = stencil_offsets("mc", 8, m, seed=4)
    np.testing.assert_array_equal(z1, z2)
    assert not np.array_equal(z1, z3)
    np.testing.assert_allclose(w1, 1 / 8)
    np.testing.assert_allclose(weighted_mean(np.arange(16.0), np.full(8, 1 / 8)), [3.5, 11.5])
    with pytest.raises(ValueError):
        stencil_offsets("bogus", 1, 1)


def test_atlas_lookup_close_to_exact_on_smooth_shadow():
    rng = np.random.default_rng(3)
    *_, occ, dd, cov6 = random_occluders(rng, 30, centre=(0, 1.0, 0), spread=0.2, log_s=(-2.5, -1.8))
    light = np.array([0.1, 2.5, 0.0])
    pts = np.stack([rng.uniform(-0.6, 0.6, 2000), np.zeros(2000), rng.uniform(-0.6, 0.6, 2000)], 1)
    at = build_point(light, occ, dd, cov6, pts, 128, 64)
    got = lookup_point(at, light, pts)
    ex = transmittance_point(light, pts, occ, dd)
    assert (ex < 0.7).mean() > 0.05
    err = np.abs(got - ex)
    assert err.mean() < 0.01 and err.max() < 0.08
    assert math.isfinite(got.sum())


def test_fast_footprints_match_generic_path_and_hash_normals_are_normal():
    from numba_kernels.dgsm_sample import STENCIL7, footprint_points_gaussians, roi_box

    rng = np.random.default_rng(9)
    n = 200
    pos = rng.normal(size=(n, 3)).astype(np.float32)
    q = random_rotations(rng, n).astype(np.float32)
    s = np.exp(rng.uniform(-3, -1, size=(n, 3))).astype(np.float32)
    idx = np.array([3, 17, 150])
    rot = quat_to_mat(q[idx].astype(np.float64))
    p7, w7 = footprint_points_gaussians(pos, q, s, idx, "stencil7", 7)
    ref = footprint_points(pos[idx], rot, s[idx], np.broadcast_to(STENCIL7, (3, 7, 3)))
    np.testing.assert_allclose(p7, ref, atol=1e-6)
    # the centre sample is the Gaussian's centre, widened to float64 (zero quaternions included)
    q0 = q.copy()
    q0[17] = 0.0
    pc, wc = footprint_points_gaussians(pos, q0, s, idx, "center", 1)
    np.testing.assert_array_equal(pc, pos[idx].astype(np.float64))
    np.testing.assert_array_equal(wc, [1.0])
    a, _ = footprint_points_gaussians(pos, q, s, np.arange(n), "mc", 64, seed=1)
    b, _ = footprint_points_gaussians(pos, q, s, np.arange(n), "mc", 64, seed=1)
    c, _ = footprint_points_gaussians(pos, q, s, np.arange(n), "mc", 64, seed=2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # a receiver's samples do not depend on which other receivers are sampled
    sub, _ = footprint_points_gaussians(pos, q, s, np.array([17]), "mc", 64, seed=1)
    np.testing.assert_array_equal(sub, a.reshape(n, 64, 3)[17])
    # offsets, whitened back to the unit frame, are standard normal (mean 0, var 1, 3 dims)
    rot_all = quat_to_mat(q.astype(np.float64) / np.linalg.norm(q, axis=1, keepdims=True))
    z = np.einsum("nji,nsj->nsi", rot_all, a.reshape(n, 64, 3) - pos[:, None, :]) / s[:, None, :]
    z = z.reshape(-1, 3)
    assert np.abs(z.mean(axis=0)).max() < 0.03 and np.abs(z.var(axis=0) - 1).max() < 0.05
    # roi_box vs numpy
    P = rng.uniform(-3, 3, size=(5000, 3)).astype(np.float32)
    P[123, 1] = np.nan
    got, bad = roi_box(P, np.array([0.5, 0.0, -0.2]), 1.0, 1, -0.5, 1.5)
    with np.errstate(invalid="ignore"):
        m = (np.abs(P[:, 0] - 0.5) <= 1) & (np.abs(P[:, 2] + 0.2) <= 1) & (P[:, 1] >= -0.5) & (P[:, 1] <= 1.5)
    np.testing.assert_array_equal(got, np.flatnonzero(m))
    assert bad == 123


@pytest.mark.parametrize("use_tiles", [True, False])
def test_refined_lookup_is_exact_at_edges_and_plain_elsewhere(use_tiles):
    from numba_kernels.dgsm_sample import lookup_point_refined

    rng = np.random.default_rng(10)
    # small, opaque occluders: shadow edges much sharper than a pixel of a W = 32 atlas
    *_, occ, dd, cov6 = random_occluders(rng, 40, centre=(0, 1.0, 0), spread=0.15, log_s=(-4.5, -3.5),
                                         alpha=(0.9, 0.99))
    light = np.array([0.05, 2.5, 0.0])
    pts = np.stack([rng.uniform(-0.5, 0.5, 4000), np.zeros(4000), rng.uniform(-0.5, 0.5, 4000)], 1)
    at = build_point(light, occ, dd, cov6, pts, 32, 16, k_sigma=8.0, use_tiles=use_tiles)
    plain = lookup_point(at, light, pts)
    got, refined = lookup_point_refined(at, light, pts, occ, dd, contrast=0.05)
    ex = transmittance_point(light, pts, occ, dd)
    assert 0 < refined.mean() < 0.95  # fragmented shadow at W = 32: most lookups straddle an edge
    np.testing.assert_array_equal(got[~refined], plain[~refined])
    np.testing.assert_allclose(got[refined], ex[refined], atol=1e-9)  # k_sigma = 8: truncation ~1e-14
    assert np.abs(plain[refined] - ex[refined]).max() > 0.2  # the plain lookup was far off there


def test_refined_lookup_from_stencils_is_the_lookup_bit_for_bit():
    """lookup_point_refined(stencils=point_stencils(...)) reads each point's pixels, bins and weights
    from its stencil instead of computing them again: the same values and flags, bit for bit, for
    points at the light, before the first bin centre, beyond the last one, on the octahedral
    map's seams and poles, and the build's own ROI stencils (atlas.stencils)."""
    from numba_kernels.dgsm_build import point_stencils
    from numba_kernels.dgsm_sample import lookup_point_refined

    rng = np.random.default_rng(11)
    *_, occ, dd, cov6 = random_occluders(rng, 60, centre=(0, 1.0, 0), spread=0.3, log_s=(-4.0, -2.5),
                                         alpha=(0.5, 0.99))
    light = np.array([0.05, 2.5, 0.0])
    pts = np.stack([rng.uniform(-1.5, 1.5, 5000), rng.uniform(-0.5, 2.4, 5000), rng.uniform(-1.5, 1.5, 5000)], 1)
    at = build_point(light, occ, dd, cov6, pts, 32, 16, k_sigma=4.0)
    assert at.stencils is not None and at.stencils.k0.shape == (5000,)
    want, want_ref = lookup_point_refined(at, light, pts, occ, dd, contrast=0.05)
    got, got_ref = lookup_point_refined(at, light, pts, occ, dd, contrast=0.05, stencils=at.stencils)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)) and np.array_equal(got_ref, want_ref)
    assert 0.02 < want_ref.mean() < 0.95
    # hard points in the same atlas: the light itself, just off it (before the first bin centre),
    # beyond t_max, straight up and down (poles), on the seams of the fold (x = 0 or z = 0 below the light)
    hard = np.array([light, light + [1e-9, 0, 0], light + [0, -1e-3, 0], light + [0, -50.0, 0],
                     light + [0, 1.0, 0], light + [0, -1.0, 0], light + [0.0, -1.0, 0.7], light + [0.7, -1.0, 0.0],
                     light + [-0.7, -1.0, 0.0], light + [0.0, -1.0, -0.7], light + [1e-12, -1.0, 1e-12]])
    st = point_stencils(light, hard, at.width, at.K, at.t_max)
    assert st.k0[0] == -2 and st.k0[2] == -1 and st.k0[3] == at.K - 1
    want, want_ref = lookup_point_refined(at, light, hard, occ, dd, contrast=0.05)
    got, got_ref = lookup_point_refined(at, light, hard, occ, dd, contrast=0.05, stencils=st)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)) and np.array_equal(got_ref, want_ref)
    assert got[0] == 1.0
    with pytest.raises(ValueError, match="stencils of 11 points for 5000"):
        lookup_point_refined(at, light, pts, occ, dd, stencils=st)
