"""Exact DGSM transmittance: eqs. 1-5 against quadrature, mpmath, analytic results and hard cases."""

import math

import mpmath
import numpy as np
import pytest
from dgsm_testutil import precisions, random_occluders, random_rotations

from numba_kernels.dgsm_exact import (
    optical_depth_directional,
    optical_depth_point,
    transmittance_directional,
    transmittance_point,
)
from numba_kernels.dgsm_model import ALPHA_MAX, TAU_STAR_MAX, pack_gaussians, pack_occluders
from numba_kernels.reference import dgsm_exact as reference
from numba_kernels.reference.dgsm_exact import optical_depth_point_mpmath as _tau_mp
from numba_kernels.reference.dgsm_model import segment_depth_mpmath, segment_depth_quad


@pytest.mark.parametrize("mapping", ["avg", "simple", "mass", "diag"])
def test_closed_form_matches_quadrature_of_absorption_field(mapping):
    rng = np.random.default_rng(11)
    mu, q, s, a, occ, dd, _ = random_occluders(rng, 4, spread=0.5, log_s=(-3, -0.5), mapping=mapping)
    light = np.array([0.2, 2.0, -0.1])
    for x in rng.normal(size=(2, 3)) * 0.7:
        t = float(np.linalg.norm(x - light))
        d = (x - light) / t
        for i in range(len(occ)):
            quad = segment_depth_quad(light, d, 0.0, t, occ[i], dd)
            closed = segment_depth_mpmath(light, d, 0.0, t, occ[i], dd)
            got = optical_depth_point(light, x[None], occ[i:i + 1], dd)[0]
            assert abs(closed - quad) <= 1e-9 * abs(quad) + 1e-15
            assert abs(got - quad) <= 1e-9 * abs(quad) + 1e-15


def test_directional_matches_quadrature():
    rng = np.random.default_rng(12)
    *_, occ, dd, _ = random_occluders(rng, 3, spread=0.4, log_s=(-2.5, -1.0))
    ldir = np.array([0.3, -1.0, 0.2])
    ldir /= np.linalg.norm(ldir)
    x = np.array([0.05, -0.6, 0.0])
    for i in range(3):
        quad = segment_depth_quad(x, ldir, -math.inf, 0.0, occ[i], dd)
        got = optical_depth_directional(ldir, x[None], occ[i:i + 1], dd)[0]
        assert abs(got - quad) <= 1e-9 * abs(quad) + 1e-15


def test_isotropic_analytic_avg_mapping():
    # avg: beta = kappa tau* / (sigma sqrt(2 pi)) -> tau(t) = kappa tau* [Phi((t-L)/s) - Phi(-L/s)]
    sigma, L, alpha, kappa = 0.05, 1.3, 0.6, 0.8
    d = np.array([1.0, 2.0, -2.0]) / 3.0
    light = np.array([0.1, 0.2, 0.3])
    occ, dd, _ = pack_gaussians((light + L * d)[None], np.array([[1.0, 0, 0, 0]]), np.full((1, 3), sigma),
                                np.array([alpha]), kappa, "avg")
    ts = kappa * -math.log(1 - alpha)
    for t in (0.5, 1.2, L, 1.31, 1.5, 10.0):
        with mpmath.workdps(40):
            phi = lambda z: (1 + mpmath.erf(mpmath.mpf(z) / mpmath.sqrt(2))) / 2  # noqa: E731
            ref = float(ts * (phi((t - L) / sigma) - phi(-L / sigma)))
        got = optical_depth_point(light, (light + t * d)[None], occ, dd)[0]
        assert abs(got - ref) <= 1e-12 + 1e-10 * ref
    # far behind: the full line integral kappa tau*
    far = optical_depth_point(light, (light + 50 * d)[None], occ, dd)[0]
    assert abs(far - ts) <= 1e-12


def test_mappings_formulas():
    rng = np.random.default_rng(5)
    n = 6
    q = random_rotations(rng, n)
    s = np.exp(rng.uniform(-4, 0, size=(n, 3)))
    a = rng.uniform(0, 1, n)
    mu = rng.normal(size=(n, 3))
    A = precisions(q, s)
    ts = -np.log1p(-a)
    kappa = 1.7
    occ_avg, _, _ = pack_gaussians(mu, q, s, a, kappa, "avg")
    np.testing.assert_allclose(occ_avg[:, 15], kappa * ts * np.sqrt(np.trace(A, axis1=1, axis2=2) / 3)
                               / np.sqrt(2 * np.pi), rtol=1e-12)
    r = occ_avg[:, 3:12].reshape(n, 3, 3)
    np.testing.assert_allclose(np.einsum("nij,nj,nkj->nik", r, occ_avg[:, 12:15] ** 2, r), A, rtol=1e-10,
                               atol=1e-12 * np.abs(A).max())
    occ_s, _, _ = pack_gaussians(mu, q, s, a, kappa, "simple")
    np.testing.assert_allclose(occ_s[:, 15], kappa * ts, rtol=1e-14)
    occ_m, _, _ = pack_gaussians(mu, q, s, a, kappa, "mass")
    # the Gaussian's integral over R^3, amp (2 pi)^(3/2) sqrt(det Sigma), is kappa tau*
    np.testing.assert_allclose(occ_m[:, 15] * (2 * np.pi) ** 1.5 * np.prod(s, axis=1), kappa * ts, rtol=1e-12)
    # pack_occluders (from precisions) agrees with pack_gaussians
    for m in ("avg", "simple", "mass", "diag"):
        o1, d1 = pack_occluders(mu, A, a, kappa, m, det_prec=1 / np.prod(s, axis=1) ** 2)
        o2, d2, _ = pack_gaussians(mu, q, s, a, kappa, m)
        assert d1 == d2 == int(m == "diag")
        # same Gaussians (eigen-decomposition may order/sign the axes differently)
        pts = rng.normal(size=(20, 3))
        light = np.array([0.3, 2.0, -0.4])
        np.testing.assert_allclose(o1[:, 15], o2[:, 15], rtol=1e-9)
        np.testing.assert_allclose(optical_depth_point(light, pts, o1, d1), optical_depth_point(light, pts, o2, d2),
                                   rtol=1e-9, atol=1e-14)


def test_diag_mapping_centre_ray_sees_exactly_tau_star():
    rng = np.random.default_rng(8)
    q = random_rotations(rng, 1)
    s = np.array([[0.3, 0.01, 0.002]])
    occ, dd, _ = pack_gaussians(np.zeros((1, 3)), q, s, np.array([0.7]), 1.0, "diag")
    for d in rng.normal(size=(5, 3)):
        d /= np.linalg.norm(d)
        tau = optical_depth_point(-20 * d, (20 * d)[None], occ, dd)[0]
        assert abs(tau - (-math.log(0.3))) <= 1e-12


def test_numba_matches_numpy_reference_point_and_directional():
    rng = np.random.default_rng(2)
    for mapping in ("avg", "diag"):
        *_, occ, dd, _ = random_occluders(rng, 40, log_s=(-3, -1), mapping=mapping)
        pts = rng.normal(size=(30, 3))
        light = np.array([0.0, 3.0, 0.5])
        np.testing.assert_allclose(optical_depth_point(light, pts, occ, dd),
                                   reference.optical_depth_point(light, pts, occ, dd), rtol=1e-12, atol=1e-14)
        ldir = np.array([0.1, -1.0, 0.3]) / np.linalg.norm([0.1, -1.0, 0.3])
        np.testing.assert_allclose(optical_depth_directional(ldir, pts, occ, dd),
                                   reference.optical_depth_directional(ldir, pts, occ, dd), rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------ hard cases
def _one(mu, scales, alpha=0.8, quat=(1.0, 0, 0, 0), mapping="avg"):
    return pack_gaussians(np.array([mu], float), np.array([quat], float), np.array([scales], float),
                          np.array([alpha]), 1.0, mapping)


HARD_SHAPES = [
    (1e-6, 1e-6, 1e-6), (1e3, 1e3, 1e3), (1e-6, 1.0, 1.0), (1.0, 1.0, 1e-6), (1e-6, 1e-6, 1.0), (1.0, 1e-6, 1e-6),
    (1e-3, 1e-3, 1e3), (1e3, 1e-3, 1e3),
]


@pytest.mark.parametrize("scales", HARD_SHAPES)
@pytest.mark.parametrize("mapping", ["avg", "mass", "diag"])
def test_hard_shapes_needles_pancakes(scales, mapping):
    q = (math.cos(0.3), math.sin(0.3) * 0.6, math.sin(0.3) * 0.8, 0.0)
    occ, dd, _ = _one((0.0, 0.0, 0.0), scales, 0.9, q, mapping)
    light = np.array([0.0, 0.0, 2.0])
    pts = np.array([[0, 0, 0.0], [0, 0, -1e-7], [0, 0, -2.0], [1e-7, 0, -3.0], [0.3, 0.2, -1.0], [0, 0, 1e-3],
                    [2e-6, -1e-6, -5.0]])
    T = transmittance_point(light, pts, occ, dd)
    assert np.all(np.isfinite(T)) and np.all((T >= 0) & (T <= 1))
    ref = np.array([math.exp(-_tau_mp(light, x, occ, dd)) for x in pts])
    np.testing.assert_allclose(T, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("alpha", [0.0, 1e-8, 0.999999, 1.0])
def test_opacity_extremes(alpha):
    occ, dd, _ = _one((0, 0, 0), (0.1, 0.1, 0.1), alpha)
    light = np.array([0, 0, 5.0])
    far = np.array([[0, 0, -5.0]])
    tau = optical_depth_point(light, far, occ, dd)[0]
    expected = -math.log1p(-min(alpha, ALPHA_MAX))
    assert abs(tau - expected) <= 1e-12 * max(expected, 1e-300) + 1e-300
    if alpha == 1.0:
        assert tau == pytest.approx(TAU_STAR_MAX, rel=1e-12)
        assert 0 < math.exp(-tau) < 1e-6
    if alpha == 0.0:
        assert transmittance_point(light, far, occ, dd)[0] == 1.0


def test_light_inside_gaussian_and_receivers_near_light():
    occ, dd, _ = _one((0.0, 0.0, 0.0), (0.5, 0.2, 0.1), 0.9, (0.9, 0.1, 0.3, 0.2))
    light = np.array([0.01, -0.02, 0.03])  # inside the Gaussian
    pts = np.array([light, light + [1e-7, 0, 0], light + [0, 0, 1e-7], [0.0, 0.0, 0.0], [0.2, 0.1, -0.3],
                    [3.0, 1.0, -2.0]])
    T = transmittance_point(light, pts, occ, dd)
    assert T[0] == 1.0  # distance 0: empty path
    assert np.all(np.isfinite(T)) and np.all((T >= 0) & (T <= 1))
    ref = np.array([math.exp(-_tau_mp(light, x, occ, dd)) for x in pts])
    np.testing.assert_allclose(T, ref, rtol=0, atol=1e-12)
    assert 1 - T[1] < 1e-5  # 1e-7 m of absorption


def test_receivers_behind_at_past_centre_and_far_from_origin():
    for off in (np.zeros(3), np.array([1e4, -1e4, 1e4])):
        occ, dd, _ = _one(off + [0, 1.0, 0], (0.05, 0.01, 0.03), 0.95, (0.8, 0.0, 0.6, 0.0))
        light = off + np.array([0.0, 3.0, 0.0])
        ts = [0.5, 1.9, 1.99, 2.0, 2.01, 2.1, 2.5, 10.0]
        pts = np.array([light + [0, -t, 0] for t in ts])
        T = transmittance_point(light, pts, occ, dd)
        ref = np.array([math.exp(-_tau_mp(light, x, occ, dd)) for x in pts])
        np.testing.assert_allclose(T, ref, rtol=0, atol=1e-9)
        assert np.all(np.diff(T) <= 1e-15)  # monotone along the ray
        assert abs(T[3] - math.sqrt(T[-1])) < 1e-9  # at the centre: half the full depth (symmetry)


def test_directional_hard_cases():
    occ, dd, _ = _one((1e4, 0, -1e4), (1e-6, 1.0, 1.0), 0.999999)
    ldir = np.array([1.0, 0.0, 0.0])
    pts = np.array([[1e4 + 1, 0, -1e4], [1e4, 0, -1e4], [1e4 - 1, 0, -1e4], [1e4 + 1, 0.5, -1e4]])
    T = transmittance_directional(ldir, pts, occ, dd)
    ref = np.array([math.exp(-segment_depth_mpmath(x, ldir, -math.inf, 0.0, occ[0], dd)) for x in pts])
    np.testing.assert_allclose(T, ref, rtol=0, atol=1e-9)
    assert np.all((T >= 0) & (T <= 1))


def test_nan_inf_rejected_with_element_named():
    mu = np.zeros((4, 3))
    q = np.tile([1.0, 0, 0, 0], (4, 1))
    s = np.full((4, 3), 0.1)
    a = np.full(4, 0.5)
    bad = mu.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="'positions' element 2"):
        pack_gaussians(bad, q, s, a)
    bad_s = s.copy()
    bad_s[3, 0] = np.inf
    with pytest.raises(ValueError, match="'scales' element 3"):
        pack_gaussians(mu, q, bad_s, a)
    bad_a = a.copy()
    bad_a[1] = np.nan
    with pytest.raises(ValueError, match="'opacities' element 1"):
        pack_gaussians(mu, q, s, bad_a)
    bad_a[1] = 1.5
    with pytest.raises(ValueError, match="'opacities' element 1 is outside"):
        pack_gaussians(mu, q, s, bad_a)
    bad_s[3, 0] = 0.0
    with pytest.raises(ValueError, match="'scales' element 3 is not > 0"):
        pack_gaussians(mu, q, bad_s, a)
    occ, dd, _ = pack_gaussians(mu, q, s, a)
    pts = np.ones((5, 3))
    pts[4, 2] = -np.inf
    with pytest.raises(ValueError, match="'receiver points' element 4"):
        optical_depth_point(np.array([0, 5.0, 0]), pts, occ, dd)
    with pytest.raises(ValueError, match="'light position' component 1"):
        optical_depth_point(np.array([0, np.nan, 0]), pts[:4], occ, dd)
    with pytest.raises(ValueError, match="'light direction'"):
        optical_depth_directional(np.array([0, 0, 0.0]), pts[:4], occ, dd)


def test_depth_from_light_shortcuts_match_mpmath():
    """The refinement's saturated-erfc shortcuts (light before / inside / past the support,
    receivers before, inside and past it) agree with the 50-digit closed form."""
    from numba_kernels.dgsm_model import depth_from_light

    rng = np.random.default_rng(21)
    mu, q, s, a, occ, dd, _ = random_occluders(rng, 6, spread=0.3, log_s=(-3, -1))
    light = np.array([0.0, 1.5, 0.0])
    occ = np.vstack([occ, pack_gaussians([[0.0, 1.45, 0.0]], [[1, 0, 0, 0]], [[0.2, 0.1, 0.3]], [0.7])[0]])
    worst = 0.0
    for i in range(len(occ)):
        c = occ[i, :3]
        dist = float(np.linalg.norm(c - light))
        d = (c - light) / max(dist, 1e-12)
        for t1 in (0.0, 1e-7, 0.5 * dist, dist - 0.01, dist, dist + 0.01, dist + 1.0, 50.0):
            ref = segment_depth_mpmath(light, d, 0.0, t1, occ[i], dd)
            got = depth_from_light(occ, i, *light, *d, t1, dd)
            assert np.isfinite(got) and got >= 0.0
            worst = max(worst, abs(got - ref) / max(abs(ref), 1e-300) if ref > 1e-12 else abs(got - ref))
    assert worst < 1e-9
