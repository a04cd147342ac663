"""ZH radiance transfer (RGCA 3.2.1): exact ZH rotation, brute-force quadrature, SH consistency."""

from __future__ import annotations

import numpy as np

from numba_kernels import sh_real
from numba_kernels.reference import zh_transfer as reference
from numba_kernels.reference.sh_real import sphere_quadrature
from numba_kernels.reference.zh_transfer import zonal_function as _zonal_function
from numba_kernels.sh_transfer import transfer_scale_sh
from numba_kernels.zh_transfer import rgca_to_zonal, zh_diffuse_color, zonal_to_rgca
from usd_gs.gaussians import GaussianSet, quaternion_to_matrix
from usd_gs.relight.transfer import zh_relight_gaussians


def _random_quats(n, seed):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_zh_rotation_is_exact_against_quadrature_projection():
    rng = np.random.default_rng(0)
    z = rng.normal(size=9)
    dirs, w = sphere_quadrature(20, 40, phi_offset=0.5)  # exact for degree < 40 in cos, < 40 in phi
    basis = sh_real.eval_basis_rh(dirs, 8)
    for axis in (np.array([0.0, 0.0, 1.0]), np.array([0.6, -0.48, 0.64]), np.array([-1.0, 0.0, 0.0])):
        proj = basis.T @ (w * _zonal_function(z, axis, dirs))
        rotated = z[sh_real.band_of_index(8)] * sh_real.eval_basis_rh(axis[None], 8)[0]
        np.testing.assert_allclose(rotated, proj, atol=1e-12)


def test_zh_rotation_is_exact_against_band_rotation_matrices():
    """Rotate the +Z-aligned ZH expansion with per-band rotation matrices (Wigner-D in the
    real basis, fitted on sample directions: exact for band-limited functions)."""
    rng = np.random.default_rng(1)
    c = rng.normal(size=9)  # Y_l0 coefficients about +Z
    r = quaternion_to_matrix(_random_quats(1, 2))[0]
    axis = r[:, 2]  # R maps +Z to axis
    samples = rng.normal(size=(200, 3))
    samples /= np.linalg.norm(samples, axis=1, keepdims=True)
    y_world = sh_real.eval_basis_rh(samples, 8)
    y_local = sh_real.eval_basis_rh(samples @ r, 8)  # Y(R^T w)
    local = np.zeros(81)
    local[[l * l + l for l in range(9)]] = c
    rotated = np.zeros(81)
    for l in range(9):
        s = slice(l * l, (l + 1) ** 2)
        d = np.linalg.lstsq(y_world[:, s], y_local[:, s], rcond=None)[0]  # Y_l(R^T w) = Y_l(w) @ d
        rotated[s] = d @ local[s]
    z = zonal_to_rgca(c)
    np.testing.assert_allclose(z[sh_real.band_of_index(8)] * sh_real.eval_basis_rh(axis[None], 8)[0],
                               rotated, atol=1e-11)
    np.testing.assert_allclose(rgca_to_zonal(z), c, atol=1e-15)


def test_zh_colour_matches_brute_force_quadrature():
    rng = np.random.default_rng(3)
    n = 40
    quat = _random_quats(n, 4)
    albedo = rng.uniform(0.2, 1.0, (n, 3))
    zc = rng.normal(size=(n, 3, 4, 3))
    zm = rng.normal(size=(n, 3, 5)) * 0.3
    probe = rng.normal(size=(81, 3)) * 0.2
    probe[0] += 2.0
    gamma = 0.8
    got = zh_diffuse_color(quat, albedo, zc, zm, probe, gamma)
    ref = reference.zh_diffuse_color(quat, albedo, zc, zm, probe, gamma)  # L (deg 8) * d (deg 8) exactly
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=2e-5)


def test_zh_lambert_lobe_equals_sh_transfer_numerator():
    """A cosine lobe stored as ZH along the normal (z_l = A_l / pi, albedo 1) reproduces the
    closed-form SH transfer: colour = s(n) for q = 1, eps = 0 (degree-3 probe)."""
    rng = np.random.default_rng(5)
    n = 30
    quat = _random_quats(n, 6)
    probe = rng.normal(size=(16, 3)) * 0.2
    probe[0] += 3.0
    zc = np.zeros((n, 3, 4, 3))
    zc[:, 2, :, :] = (sh_real.cosine_lobe_band_factors(1.0, 3) / np.pi)[None, :, None]
    col = zh_diffuse_color(quat, np.ones((n, 3)), zc, None, probe)
    normals = quaternion_to_matrix(quat)[:, :, 2]
    np.testing.assert_allclose(col, transfer_scale_sh(normals, probe, q=1.0, t_max=1e9, eps=0.0), rtol=1e-5)
    # monochrome bands above the probe degree have no light to transfer
    zm = rng.normal(size=(n, 3, 5))
    np.testing.assert_allclose(zh_diffuse_color(quat, np.ones((n, 3)), zc, zm, probe), col, rtol=1e-6)


def test_zh_relight_gaussians_writes_dc_colour():
    rng = np.random.default_rng(7)
    n = 10
    gs = GaussianSet(rng.normal(size=(n, 3)), _random_quats(n, 8), np.full((n, 3), 0.1), np.full(n, 0.9),
                     np.zeros((n, 16, 3)), extras={"zh_albedo": rng.uniform(0, 1, (n, 3)),
                                                   "zh_color": rng.normal(size=(n, 3, 4, 3))})
    probe = rng.normal(size=(9, 3))
    probe[0] += 2
    out, col = zh_relight_gaussians(gs, probe, probe_basis="rh")
    assert out.sh_degree == 0
    np.testing.assert_allclose(0.5 + 0.28209479177387814 * out.sh[:, 0].astype(np.float64), col, atol=1e-5)
