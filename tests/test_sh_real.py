"""Real SH basis (RH), 3DGS conversion, cosine-lobe band factors and cube-map geometry."""

from __future__ import annotations

import mpmath
import numpy as np
import pytest

from numba_kernels import cubemap_dirs as cm
from numba_kernels import sh_real
from numba_kernels.reference.sh_real import real_sh_basis as _scipy_real_sh
from numba_kernels.reference.sh_real import sphere_quadrature as _sphere_quadrature
from usd_gs import sh3dgs


def _random_dirs(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_basis_matches_scipy_degree_8():
    d = _random_dirs(300)
    d[0] = [0, 0, 1]  # poles
    d[1] = [0, 0, -1]
    ref = _scipy_real_sh(d, 8)
    np.testing.assert_allclose(sh_real.eval_basis_rh(d, 8), ref, atol=1e-12)
    np.testing.assert_allclose(sh_real.eval_basis_rh_numpy(d, 8), ref, atol=1e-12)


def test_basis_published_constants():
    d = _random_dirs(50, 1)
    x, y, z = d.T
    b = sh_real.eval_basis_rh(d, 2)
    expect = np.stack([np.full_like(x, 0.282095), 0.488603 * y, 0.488603 * z, 0.488603 * x,
                       1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1),
                       1.092548 * x * z, 0.546274 * (x * x - y * y)], axis=1)
    np.testing.assert_allclose(b, expect, atol=2e-6)


def test_orthonormal_degree_8():
    dirs, w = _sphere_quadrature(12, 24)
    b = sh_real.eval_basis_rh(dirs, 8)
    np.testing.assert_allclose((b * w[:, None]).T @ b, np.eye(81), atol=1e-12)


def test_3dgs_basis_is_rh_with_sign_flips():
    d = _random_dirs(200, 2)
    for deg in range(4):
        np.testing.assert_allclose(sh3dgs.eval_basis(d, deg),
                                   sh_real.eval_basis_rh(d, deg) * sh_real.rh_3dgs_signs(deg), atol=1e-14)
    np.testing.assert_array_equal(sh_real.rh_3dgs_signs(1), [1, -1, 1, -1])


def test_rh_to_3dgs_preserves_function_and_is_involution():
    rng = np.random.default_rng(3)
    d = _random_dirs(100, 4)
    a_rh = rng.normal(size=(16, 3))
    a_3 = sh_real.rh_to_3dgs(a_rh)
    np.testing.assert_allclose(sh3dgs.eval_basis(d, 3) @ a_3, sh_real.eval_basis_rh(d, 3) @ a_rh, atol=1e-12)
    np.testing.assert_allclose(sh_real.threedgs_to_rh(a_3), a_rh, atol=0)
    # m != 0 coefficients really change sign (mixing the bases would flip lighting)
    assert np.allclose(a_3[1], -a_rh[1]) and np.allclose(a_3[2], a_rh[2])
    with pytest.raises(ValueError):
        sh_real.rh_to_3dgs(np.zeros((25, 3)))


def test_cosine_lobe_band_factors():
    np.testing.assert_allclose(sh_real.cosine_lobe_band_factors(1.0, 4),
                               [np.pi, 2 * np.pi / 3, np.pi / 4, 0.0, -np.pi / 24], atol=1e-15)
    for q in (0.5, 2.7, 12.0):
        got = sh_real.cosine_lobe_band_factors(q, 8)
        for l in range(9):
            ref = 2 * mpmath.pi * mpmath.quad(lambda t, l=l, q=q: t ** q * mpmath.legendre(l, t), [0, 1])
            assert abs(got[l] - float(ref)) < 1e-12 * max(1.0, abs(float(ref))), (q, l)


def test_cube_solid_angles_exact():
    for size in (1, 7, 64):
        w = cm.cube_face_solid_angles(size)
        assert w.shape == (6, size, size)
        assert abs(w.sum() - 4 * np.pi) < 1e-12
    # one texel against direct 2D quadrature of dA / (1 + x^2 + y^2)^(3/2)
    size = 5
    w = cm.cube_face_solid_angles(size)
    e = np.linspace(-1, 1, size + 1)
    x, wx = np.polynomial.legendre.leggauss(40)
    for (i, j) in [(0, 0), (2, 3), (4, 1)]:
        xs = (e[j] + e[j + 1]) / 2 + x * (e[j + 1] - e[j]) / 2
        ys = (e[i] + e[i + 1]) / 2 + x * (e[i + 1] - e[i]) / 2
        X, Y = np.meshgrid(xs, ys)
        val = (np.outer(wx, wx) / (1 + X**2 + Y**2) ** 1.5).sum() * ((e[1] - e[0]) / 2) ** 2
        assert abs(w[3, i, j] - val) < 1e-13


def test_cube_directions_opengl_table():
    size = 4
    d = cm.cube_face_directions(size)
    c = cm.pixel_centres(size)
    i, j = 0, 3
    u, v = c[j], c[i]
    table = [(1, -v, -u), (-1, -v, u), (u, 1, v), (u, -1, -v), (u, -v, 1), (-u, -v, -1)]
    for f in range(6):
        t = np.array(table[f], dtype=float)
        np.testing.assert_allclose(d[f, i, j], t / np.linalg.norm(t), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-15)
    face, uu, vv = cm.direction_to_face_uv(d)
    np.testing.assert_array_equal(face, np.broadcast_to(np.arange(6)[:, None, None], face.shape))
    np.testing.assert_allclose(uu, np.broadcast_to(c[None, None, :], uu.shape), atol=1e-14)
    np.testing.assert_allclose(vv, np.broadcast_to(c[None, :, None], vv.shape), atol=1e-14)


def test_batch_evaluation_matches_scipy():
    d = _random_dirs(37, 6)
    d[5] = [0.0, 0.0, -1.0]
    g = d.shape[0]
    out = np.empty((81, g))
    scratch = [np.empty(g) for _ in range(4)]
    sh_real.sh_eval_batch(d[:, 0].copy(), d[:, 1].copy(), d[:, 2].copy(), 8, sh_real.NORM, out, *scratch)
    np.testing.assert_allclose(out.T, _scipy_real_sh(d, 8), atol=1e-12)
    out3 = np.full((16, g), np.nan)
    sh_real.sh_eval_batch(d[:, 0].copy(), d[:, 1].copy(), d[:, 2].copy(), 3, sh_real.NORM, out3, *scratch)
    np.testing.assert_allclose(out3.T, _scipy_real_sh(d, 3), atol=1e-12)


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 4, 8])
def test_directions_at_once_are_sh_eval_dir_bit_for_bit(degree):
    """``sh_eval_dirs`` (the directions' inner loops, for the probe reprojection) gives
    ``sh_eval_dir``'s values bit for bit, poles and axis directions included, and the reference
    basis within rounding; it writes only the first (degree+1)^2 rows."""
    d = _random_dirs(301, 9 + degree)
    d[:5] = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1e-300, 1.0]]
    nb = (degree + 1) ** 2
    out = np.full((nb + 3, len(d)), 7.0)
    scratch = [np.empty(len(d)) for _ in range(4)]
    sh_real.sh_eval_dirs(d[:, 0].copy(), d[:, 1].copy(), d[:, 2].copy(), degree, sh_real.NORM, out, *scratch)
    one = np.empty(nb)
    for i, (x, y, z) in enumerate(d):
        sh_real.sh_eval_dir(x, y, z, degree, sh_real.NORM, one)
        assert np.array_equal(out[:nb, i].view(np.uint64), one.view(np.uint64)), i
    assert np.all(out[nb:] == 7.0)
    np.testing.assert_allclose(out[:nb].T, _scipy_real_sh(d, degree), atol=1e-12)
