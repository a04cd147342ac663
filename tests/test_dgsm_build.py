"""DGSM build: ROI voxels, exactness at pixel/bin centres, culling bound, bin skipping."""

import math

import numpy as np
import pytest
from dgsm_testutil import random_occluders

from numba_kernels import octahedral as oc
from numba_kernels.dgsm_build import EPS_PAIR, TILE, _bin_tiles_chunked, build_point, roi_voxels, t_max_for
from numba_kernels.dgsm_exact import optical_depth_point, transmittance_point
from numba_kernels.dgsm_model import pack_gaussians
from numba_kernels.reference import dgsm_build as reference

LIGHT = np.array([0.2, 2.0, 0.1])


def _scene(rng, n=120, log_s=(-4, -2.3)):
    mu, q, s, a, occ, dd, cov6 = random_occluders(rng, n, centre=(0, 0.8, 0), spread=0.25, log_s=log_s)
    pts = np.stack([rng.uniform(-1, 1, 3000), np.zeros(3000), rng.uniform(-1, 1, 3000)], 1)
    return occ, dd, cov6, pts


def _centre_points(atlas, light):
    w = atlas.width
    dirs = oc.pixel_directions(w).reshape(-1, 3)[atlas.pixels]
    ks = np.arange(atlas.kmin, atlas.kmax + 1)
    tk = (ks + 0.5) * atlas.t_max / atlas.K
    return (light + dirs[:, None, :] * tk[None, :, None]).reshape(-1, 3)


def test_roi_voxels_are_the_trilinear_stencils():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(500, 3))
    w, K = 32, 16
    t_max = t_max_for(np.linalg.norm(pts - LIGHT, axis=1).max(), K)
    pix, kmin, kmax = roi_voxels(LIGHT, pts, w, K, t_max)
    # independent numpy construction
    v = pts - LIGHT
    uv = oc.encode(v)
    f = (uv + 1) * w / 2 - 0.5
    i0 = np.floor(f).astype(int)
    cand = np.concatenate([i0 + [di, dj] for di in (0, 1) for dj in (0, 1)])
    wr = oc.wrap(cand, w)
    expect = np.unique(wr[:, 0] * w + wr[:, 1])
    np.testing.assert_array_equal(pix, expect)
    fk = np.minimum(np.linalg.norm(v, axis=1) * K / t_max - 0.5, K - 1)
    assert kmin == max(int(np.floor(fk).min()), 0)
    assert kmax == min(int(np.floor(fk).max()) + 1, K - 1)


@pytest.mark.parametrize("use_tiles", [False, True])
def test_table_is_one_outside_and_exact_inside(use_tiles):
    rng = np.random.default_rng(2)
    occ, dd, cov6, pts = _scene(rng)
    at = build_point(LIGHT, occ, dd, cov6, pts, width=32, K=16, k_sigma=10.0, use_tiles=use_tiles)
    dense = at.dense()
    inside = np.zeros((32 * 32, 16), bool)
    inside[at.pixels, at.kmin:at.kmax + 1] = True
    assert np.all(dense.reshape(-1, 16)[~inside] == 1.0)
    assert len(at.pixels) < 32 * 32 and (at.kmin > 0 or at.kmax < 15)  # the ROI really prunes
    ex = transmittance_point(LIGHT, _centre_points(at, LIGHT), occ, dd).reshape(len(at.pixels), -1)
    np.testing.assert_allclose(at.values, ex, atol=2e-6, rtol=0)
    assert (ex < 0.9).any()  # shadowed voxels exist


def test_tile_culling_error_within_k_sigma_bound():
    rng = np.random.default_rng(3)
    occ, dd, cov6, pts = _scene(rng, log_s=(-3, -1.5))  # big Gaussians: truncation visible
    k = 2.0
    full = build_point(LIGHT, occ, dd, cov6, pts, 64, 16, use_tiles=False)
    cull = build_point(LIGHT, occ, dd, cov6, pts, 64, 16, k_sigma=k, use_tiles=True)
    np.testing.assert_array_equal(full.pixels, cull.pixels)
    assert cull.pairs < full.pairs / 2
    # bound: a culled occluder misses its k-sigma ellipsoid, so on that ray it adds at most
    # exp(-k^2/2) of its full-line depth beta sqrt(2 pi / a); skipped tiny pairs add <= 2 EPS_PAIR.
    dirs = oc.pixel_directions(64).reshape(-1, 3)[full.pixels]
    R = occ[:, 3:12].reshape(-1, 3, 3)
    delta = np.einsum("nji,pj->pni", R, dirs) * occ[None, :, 12:15]
    a = np.sum(delta ** 2, axis=2)
    line = occ[None, :, 15] * np.sqrt(2 * np.pi / a)
    bound = line.sum(axis=1) * math.exp(-k * k / 2) + 2 * EPS_PAIR * len(occ) + 2e-7
    diff = np.abs(full.values - cull.values).max(axis=1)
    assert np.all(diff <= bound[:, None].max(axis=1))
    assert diff.max() > 1e-5  # the truncation is real at k = 2 ...
    wide = build_point(LIGHT, occ, dd, cov6, pts, 64, 16, k_sigma=8.0, use_tiles=True)
    np.testing.assert_allclose(wide.values, full.values, atol=1e-6)  # ... and vanishes at k = 8


@pytest.mark.parametrize("n", [0, 5, 3000])
def test_parallel_tile_lists_equal_naive_binning(n):
    rng = np.random.default_rng(n)
    w = 64
    fx, fy = rng.uniform(-4, w + 4, n), rng.uniform(0, w, n)  # some boxes cross the fold
    rp = rng.uniform(0, 12, n)
    is_glob = rng.random(n) < 0.1
    active = rng.random((w // TILE) ** 2) < 0.7
    start, items = _bin_tiles_chunked(fx, fy, rp, is_glob, w, active)
    got = [items[start[t]:start[t + 1]].tolist() for t in range(len(start) - 1)]
    assert got == reference.tile_lists(fx, fy, rp, is_glob, w, active, TILE)


def test_bin_skip_equals_all_bins_and_saves_work():
    rng = np.random.default_rng(4)
    occ, dd, cov6, pts = _scene(rng)
    a = build_point(LIGHT, occ, dd, cov6, pts, 32, 64, bin_skip=True)
    b = build_point(LIGHT, occ, dd, cov6, pts, 32, 64, bin_skip=False)
    np.testing.assert_allclose(a.values, b.values, atol=1e-7)
    assert a.erf_evals < b.erf_evals / 3


def test_no_roi_computes_everything_and_agrees():
    rng = np.random.default_rng(5)
    occ, dd, cov6, pts = _scene(rng, n=40)
    t_max = t_max_for(np.linalg.norm(pts - LIGHT, axis=1).max(), 16)
    roi = build_point(LIGHT, occ, dd, cov6, pts, 16, 16, t_max=t_max)
    full = build_point(LIGHT, occ, dd, cov6, pts, 16, 16, t_max=t_max, use_roi=False)
    assert len(full.pixels) == 256 and (full.kmin, full.kmax) == (0, 15)
    np.testing.assert_allclose(full.dense()[roi.dense() != 1.0], roi.dense()[roi.dense() != 1.0], atol=1e-7)


HARD = [((0, 0.8, 0), (1e-6, 0.3, 0.3), 0.999999), ((0.05, 0.8, 0), (1e-3, 1e-3, 1.0), 1.0),
        ((0, 1.9, 0.1), (0.5, 0.5, 0.5), 0.9),  # the light sits inside this one
        ((0.1, 0.5, -0.1), (1e-6, 1e-6, 1e-6), 0.5), ((0, 0.9, 0), (1e3, 1e3, 1e-3), 1e-8)]


@pytest.mark.parametrize("offset", [0.0, 1e4])
def test_hard_occluders_in_float32_table(offset):
    mu = np.array([h[0] for h in HARD], float) + offset
    s = np.array([h[1] for h in HARD], float)
    a = np.array([h[2] for h in HARD])
    q = np.tile([math.cos(0.4), 0.0, math.sin(0.4), 0.0], (len(HARD), 1))
    occ, dd, cov6 = pack_gaussians(mu, q, s, a)
    light = LIGHT + offset
    rng = np.random.default_rng(6)
    pts = np.stack([rng.uniform(-1, 1, 500), np.zeros(500), rng.uniform(-1, 1, 500)], 1) + offset
    pts = np.concatenate([pts, light[None], light[None] + 1e-7])  # receivers at and next to the light
    at = build_point(light, occ, dd, cov6, pts, 32, 16)
    assert np.all(np.isfinite(at.values)) and np.all((at.values >= 0) & (at.values <= 1))
    ex = np.exp(-optical_depth_point(light, _centre_points(at, light), occ, dd)).reshape(len(at.pixels), -1)
    np.testing.assert_allclose(at.values, ex, atol=1e-4)


def test_bad_input_rejected():
    rng = np.random.default_rng(7)
    occ, dd, cov6, pts = _scene(rng, n=5)
    bad = pts.copy()
    bad[17, 0] = np.nan
    with pytest.raises(ValueError, match="'ROI points' element 17"):
        build_point(LIGHT, occ, dd, cov6, bad, 16, 8)
    with pytest.raises(ValueError, match="multiple of 8"):
        build_point(LIGHT, occ, dd, cov6, pts, 12, 8)


def test_far_distance_is_numpys_formula_bit_for_bit():
    from numba_kernels.dgsm_build import far_distance

    rng = np.random.default_rng(21)
    for n, s in ((1, 1.0), (7, 1e-3), (100_000, 40.0)):
        pts = rng.normal(size=(n, 3)) * s
        assert far_distance(LIGHT, pts) == float(np.sqrt(np.max(np.sum((pts - LIGHT) ** 2, axis=1))))
    f32 = rng.normal(size=(500, 3)).astype(np.float32)  # other dtypes are widened first
    assert far_distance(LIGHT, f32) == float(np.sqrt(np.max(np.sum((f32.astype(np.float64) - LIGHT) ** 2, axis=1))))
    assert far_distance(LIGHT, np.zeros((0, 3))) == 0.0
    bad = rng.normal(size=(10, 3))
    bad[4, 1] = np.nan
    assert math.isnan(far_distance(LIGHT, bad))


def test_bin_tiles_reads_the_centres_from_the_packed_occluders():
    from numba_kernels.dgsm_build import bin_tiles

    rng = np.random.default_rng(22)
    occ, dd, cov6, _ = _scene(rng, n=400)
    w = 64
    active = np.ones((w // TILE) ** 2, np.bool_)
    got = bin_tiles(LIGHT, occ, cov6, w, 3.0, active)
    want = bin_tiles(LIGHT, np.ascontiguousarray(occ[:, :3]), cov6, w, 3.0, active)
    assert len(got[1]) > 400
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
