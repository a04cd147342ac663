"""Directional-light DGSM against the exact parallel-ray transmittance."""

import numpy as np
import pytest
from dgsm_testutil import random_occluders

from numba_kernels.dgsm_directional import build_directional, light_basis, lookup_directional, pixel_rays
from numba_kernels.dgsm_exact import transmittance_directional
from numba_kernels.reference import dgsm_directional as reference

LDIR = np.array([0.3, -1.0, 0.2])


def _scene(seed):
    rng = np.random.default_rng(seed)
    *_, occ, dd, cov6 = random_occluders(rng, 80, centre=(0, 0.8, 0), spread=0.2, log_s=(-3.5, -2.2))
    pts = np.stack([rng.uniform(-1, 1, 3000), np.zeros(3000), rng.uniform(-1, 1, 3000)], 1)
    return occ, dd, cov6, pts


def test_basis_is_orthonormal_with_light_direction_last():
    B = light_basis(LDIR)
    np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(B[2], LDIR / np.linalg.norm(LDIR))
    assert np.linalg.det(B) > 0


@pytest.mark.parametrize("use_tiles", [False, True])
def test_voxels_equal_exact_parallel_rays(use_tiles):
    occ, dd, cov6, pts = _scene(1)
    at = build_directional(LDIR, occ, dd, cov6, pts, width=32, K=8, k_sigma=10.0, use_tiles=use_tiles)
    vox, l = pixel_rays(at)
    ex = transmittance_directional(l, vox, occ, dd).reshape(len(at.pixels), -1)
    np.testing.assert_allclose(at.values, ex, atol=2e-6)
    assert (ex < 0.8).any()
    dense = at.dense().reshape(-1, 8)
    inside = np.zeros_like(dense, bool)
    inside[at.pixels, at.kmin:at.kmax + 1] = True
    assert np.all(dense[~inside] == 1.0)


def test_voxels_equal_the_numpy_reference():
    """Voxel centres and values against ``reference.dgsm_directional`` (its own geometry, numpy depth)."""
    occ, dd, cov6, pts = _scene(3)
    at = build_directional(LDIR, occ, dd, cov6, pts, width=16, K=8, k_sigma=10.0)
    np.testing.assert_allclose(pixel_rays(at)[0], reference.voxel_centres(at).reshape(-1, 3), rtol=0, atol=1e-12)
    want = reference.voxel_transmittance(at, occ, dd)
    np.testing.assert_allclose(at.values, want, atol=2e-6)
    assert (want < 0.8).any()


def test_lookup_close_to_exact_and_tiles_cut_work():
    occ, dd, cov6, pts = _scene(2)
    at = build_directional(LDIR, occ, dd, cov6, pts, width=256, K=16)
    full = build_directional(LDIR, occ, dd, cov6, pts, width=256, K=16, use_tiles=False)
    assert at.pairs < full.pairs / 10
    # k_sigma = 3 truncation bound: each culled occluder adds < exp(-9/2) of its full-line depth
    l = LDIR / np.linalg.norm(LDIR)
    delta = np.einsum("nji,j->ni", occ[:, 3:12].reshape(-1, 3, 3), l) * occ[:, 12:15]
    bound = np.sum(occ[:, 15] * np.sqrt(2 * np.pi / np.sum(delta ** 2, axis=1))) * np.exp(-4.5)
    assert np.abs(at.values - full.values).max() <= bound + 1e-6
    got = lookup_directional(at, pts)
    ex = transmittance_directional(LDIR, pts, occ, dd)
    assert (ex < 0.7).mean() > 0.02
    err = np.abs(got - ex)
    assert err.mean() < 0.01 and err.max() < 0.1
