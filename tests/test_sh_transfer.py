"""SH lighting transfer (paper eqs. 9-10): closed form vs quadrature, analytic cases, relit SH."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels import sh_real
from numba_kernels.reference import sh_transfer as reference
from numba_kernels.sh_transfer import (
    latlong_quadrature,
    relight_sh_coefficients,
    transfer_scale_quadrature,
    transfer_scale_sh,
)
from usd_gs import sh3dgs
from usd_gs.errors import UserError
from usd_gs.relight.probe import SHProbe
from usd_gs.relight.transfer import relight_sh


def _unit(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _probe(degree, seed):
    a = np.random.default_rng(seed).normal(size=(sh_real.num_coeffs(degree), 3)) * 0.3
    a[0] += [3.0, 2.0, 1.5]
    return a


def test_quadrature_kernel_is_eq10_literally():
    """The numba reference equals eq. 10 written out with numpy for a few Gaussians."""
    n = _unit(7, 0).astype(np.float32).astype(np.float64)  # the kernels read float32 normals
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    a = _probe(3, 1)
    q, eps = 2.5, 0.01
    dirs, w = latlong_quadrature(40, 80)
    ref = reference.transfer_scale_quadrature(n, a, q, 100.0, eps, dirs, w)
    got = transfer_scale_quadrature(n, a, q=q, t_max=100.0, eps=eps, n_theta=40, n_phi=80)
    np.testing.assert_allclose(got, ref, rtol=1e-11)


@pytest.mark.parametrize("q,degree", [(1.0, 3), (3.5, 3), (20.0, 8), (0.5, 2)])
def test_closed_form_matches_quadrature_at_large_m(q, degree):
    n = _unit(200, 2)
    a = _probe(degree, 3)
    fast = transfer_scale_sh(n, a, q=q, t_max=100.0, eps=1e-6)
    ref = transfer_scale_quadrature(n, a, q=q, t_max=100.0, eps=1e-6, n_theta=256, n_phi=512)
    assert np.abs(fast - ref).max() / np.abs(ref).max() < 1e-3
    big = np.abs(ref) > 0.05 * np.abs(ref).max()
    assert np.all(np.abs(fast - ref)[big] <= 1e-3 * np.abs(ref)[big])


def test_analytic_linear_environment_lambert():
    """L(w) = a + <b, w>: int L max(0,<w,n>) dw / pi = a + 2/3 <b, n> (q = 1)."""
    a_dc, b = np.array([1.0, 2.0, 0.5]), np.array([[0.3, -0.2, 0.1], [0.0, 0.25, 0.0], [-0.1, 0.1, 0.2]])
    # b[:, c] is the gradient for channel c; RH band 1 is c1 * (y, z, x)
    c0, c1 = 0.28209479177387814, 0.4886025119029199
    coeffs = np.zeros((4, 3))
    coeffs[0] = a_dc / c0
    coeffs[1], coeffs[2], coeffs[3] = b[1] / c1, b[2] / c1, b[0] / c1
    n = _unit(50, 4)
    expect = a_dc[None, :] + 2.0 / 3.0 * n @ b
    np.testing.assert_allclose(transfer_scale_sh(n, coeffs, q=1.0, eps=0.0), expect, rtol=1e-6)
    # constant environment: every normal, every exponent gets the radiance (eps -> 0)
    const = np.zeros((9, 3))
    const[0] = [0.7, 0.8, 0.9] / np.float64(c0)
    for q in (0.3, 1.0, 40.0):
        np.testing.assert_allclose(transfer_scale_sh(n, const, q=q, eps=0.0),
                                   np.broadcast_to([0.7, 0.8, 0.9], (50, 3)), rtol=1e-6)


def test_clip_eps_and_degenerate_normals():
    a = np.zeros((4, 3))
    a[0] = [1.0, -1.0, 50.0]  # negative and very bright channels
    n = np.array([[0, 0, 1.0], [0, 0, 0], [np.nan, 0, 0]], dtype=np.float32)
    s = transfer_scale_sh(n, a, q=1.0, t_max=4.0, eps=0.0)
    y00 = 1.0 / np.sqrt(4 * np.pi)
    np.testing.assert_allclose(s[0], [y00, 0.0, 4.0], rtol=1e-6)
    np.testing.assert_allclose(s[1], [y00, 0.0, 4.0], rtol=1e-6)  # zero normal: mean radiance
    assert np.isfinite(s).all()
    eps = 0.5
    np.testing.assert_allclose(transfer_scale_sh(n[:1], a, q=1.0, t_max=100, eps=eps)[0, 0],
                               y00 * np.pi / (np.pi + eps), rtol=1e-6)
    with pytest.raises(ValueError):
        transfer_scale_sh(n, a, q=-1.0)


def test_relit_colour_is_scaled_colour_for_every_view():
    rng = np.random.default_rng(5)
    n_g = 64
    sh = rng.normal(size=(n_g, 16, 3)).astype(np.float32) * 0.3
    scale = rng.uniform(0.2, 3.0, size=(n_g, 3)).astype(np.float32)
    gamma = 1.3
    new = relight_sh_coefficients(sh, scale, gamma)
    for seed in range(3):
        d = _unit(n_g, 10 + seed)
        c = sh3dgs.eval_color(sh, d)
        c_new = sh3dgs.eval_color(new, d)
        np.testing.assert_allclose(c_new, gamma * scale * c, rtol=2e-5, atol=2e-5)
        # the paper's clamp max(0, gamma c s) is the usual clamp of the evaluated colour
        np.testing.assert_allclose(np.maximum(0, c_new), np.maximum(0, gamma * c * scale), rtol=2e-5, atol=2e-5)
    # all bands (view dependence) scaled, not only the DC term
    np.testing.assert_allclose(new[:, 1:], gamma * scale[:, None, :] * sh[:, 1:], rtol=1e-6)
    np.testing.assert_allclose(new, reference.relight_sh_coefficients(sh, scale, gamma), rtol=1e-5, atol=1e-6)


def test_relight_sh_wrapper_converts_probe_basis_explicitly():
    rng = np.random.default_rng(6)
    a_rh = _probe(3, 7)
    probe = SHProbe(sh_real.rh_to_3dgs(a_rh), "3dgs")
    n = _unit(20, 8)
    sh = rng.normal(size=(20, 4, 3)).astype(np.float32)
    new1, s1 = relight_sh(sh, n, probe)
    new2, s2 = relight_sh(sh, n, a_rh, probe_basis="rh")
    new3, s3 = relight_sh(sh, n, probe.coeffs, probe_basis="3dgs")
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(s1, s3)
    np.testing.assert_array_equal(new1, new3)
    np.testing.assert_allclose(s1, transfer_scale_quadrature(n, a_rh, n_theta=256, n_phi=512), rtol=1e-3)
    with pytest.raises(UserError):
        relight_sh(sh, n, a_rh)  # array without a basis
    bad = n.copy()
    bad[3, 1] = np.inf
    with pytest.raises(UserError, match="element 3"):
        relight_sh(sh, bad, probe)


def test_relight_gaussians_end_to_end_on_a_sphere():
    """Flat Gaussians on a sphere, probe L(w) = a + <b, w> (RH band 1 = c1 (y, z, x)): the relit
    DC colour is gamma * (a + 2/3 <b, n>) * colour with n the outward sphere normal (q = 1)."""
    from usd_gs.gaussians import GaussianSet, matrix_to_quaternion
    from usd_gs.relight.transfer import relight_gaussians

    rng = np.random.default_rng(11)
    n = 3000
    nrm = _unit(n, 12)
    t = np.cross(nrm, rng.normal(size=(n, 3)))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    rot = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    colour = np.array([0.6, 0.4, 0.2])
    sh = np.zeros((n, 1, 3))
    sh[:, 0] = (colour - 0.5) / sh3dgs.C0
    gs = GaussianSet(nrm * 1.5, matrix_to_quaternion(rot), np.tile([0.05, 0.05, 0.005], (n, 1)), np.full(n, 0.9), sh)
    c0, c1 = 0.28209479177387814, 0.4886025119029199
    a_dc, b = 1.2, np.array([0.0, 0.45, 0.0])  # brighter from +Y, same in all channels
    probe_rh = np.zeros((4, 3))
    probe_rh[0] = a_dc / c0
    probe_rh[1], probe_rh[2], probe_rh[3] = b[1] / c1, b[2] / c1, b[0] / c1
    out, scale, normals = relight_gaussians(gs, SHProbe(sh_real.rh_to_3dgs(probe_rh), "3dgs"), gamma=0.9, eps=0.0,
                                            radius=0.25)
    assert np.einsum("ij,ij->i", normals, nrm).min() > 0.99
    expect_s = a_dc + 2.0 / 3.0 * nrm @ b
    np.testing.assert_allclose(scale, np.repeat(expect_s[:, None], 3, axis=1), rtol=1e-4)
    got = sh3dgs.eval_color(out.sh, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(got, 0.9 * expect_s[:, None] * colour[None, :], rtol=1e-4)


def test_blended_probes_equal_the_weighted_sum_of_single_probe_transfers():
    """transfer_scale_sh with P probes and (N, P) weights = sum_p w_p * (single-probe result p),
    each clipped on its own; zero weights skip a probe; one shared row applies to all."""
    rng = np.random.default_rng(7)
    n = rng.standard_normal((300, 3))
    n[5] = 0.0  # zero normal: isotropic branch
    probes = rng.standard_normal((3, 25, 3)) * 0.3
    probes[:, 0, :] += 1.5
    w = rng.uniform(0.0, 1.0, (300, 3))
    w[rng.uniform(size=(300, 3)) < 0.3] = 0.0
    w[w.sum(axis=1) == 0, 0] = 1.0
    w /= w.sum(axis=1, keepdims=True)
    single = np.stack([transfer_scale_sh(n, probes[p], q=1.0, t_max=0.45) for p in range(3)], axis=1)
    expect = np.einsum("np,npc->nc", w, single.astype(np.float64))
    got = transfer_scale_sh(n, probes, q=1.0, t_max=0.45, blend=w)
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-6)
    assert (single > 0.449).any() and (single < 0.4).any()  # the clip is exercised, not everywhere
    np.testing.assert_allclose(transfer_scale_sh(n, probes[1:2], q=1.0, t_max=0.45, blend=np.ones((300, 1))),
                               single[:, 1], rtol=1e-6)
