"""SH probe fit (paper eq. 7), probe storage basis, environment I/O and the real-HDR ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from numba_kernels import cubemap_dirs as cm
from numba_kernels import sh_real
from numba_kernels.probe_fit import CubeProbeFitter, fit_sh_lstsq, normal_equations
from numba_kernels.reference import probe_fit as reference
from usd_gs import sh3dgs
from usd_gs.errors import InputFormatError, UserError
from usd_gs.io import envmap
from usd_gs.relight.probe import SHProbe, fit_probe, hdr_dome_gaussians, probe_from_latlong

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
HDRIS = sorted((DATA / "hdri").glob("*"))


def _faces_from_sh(coeffs_rh, size):
    d = cm.cube_face_directions(size)
    return sh_real.eval_basis_rh_numpy(d, sh_real.degree_from_num_coeffs(coeffs_rh.shape[0])) @ coeffs_rh


@pytest.mark.parametrize("degree", [0, 3, 8])
def test_band_limited_radiance_is_recovered_exactly(degree):
    rng = np.random.default_rng(degree)
    a = rng.normal(size=(sh_real.num_coeffs(degree), 3))
    a[0] += 5.0
    faces = _faces_from_sh(a, 24)
    np.testing.assert_allclose(CubeProbeFitter(24, degree, 0.0).fit(faces), a, atol=1e-9)


def test_normal_equations_match_numpy_ridge_reference():
    rng = np.random.default_rng(1)
    n, degree, lam = 3000, 4, 0.3
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w = rng.random(n) * 0.01
    y = rng.normal(size=(n, 3))
    g, r = normal_equations(d, w, y, degree)
    g_ref, r_ref = reference.normal_equations(d, w, y, degree)
    np.testing.assert_allclose(g, g_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(r, r_ref, rtol=1e-12, atol=1e-14)
    # eq. 7 as an augmented least-squares problem: [W^1/2 B; sqrt(lam) I] A = [W^1/2 Y; 0]
    np.testing.assert_allclose(fit_sh_lstsq(d, w, y, degree, lam), reference.fit_sh_lstsq(d, w, y, degree, lam),
                               atol=1e-10)


def test_cached_fitter_equals_generic_solver_with_ridge():
    rng = np.random.default_rng(2)
    faces = rng.random((6, 16, 16, 3))
    ref = fit_sh_lstsq(cm.cube_face_directions(16).reshape(-1, 3), cm.cube_face_solid_angles(16).reshape(-1),
                       faces.reshape(-1, 3), 3, 0.05)
    np.testing.assert_allclose(CubeProbeFitter(16, 3, 0.05).fit(faces), ref, atol=1e-12)


def test_probe_is_stored_in_3dgs_basis_up_to_degree_3():
    rng = np.random.default_rng(3)
    a_rh = rng.normal(size=(16, 3))
    a_rh[0] += 4
    p = fit_probe(_faces_from_sh(a_rh, 16), degree=3, lam=0.0)
    assert p.basis == "3dgs" and p.degree == 3
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # evaluating the stored coefficients with the 3DGS basis gives the fitted radiance
    np.testing.assert_allclose(sh3dgs.eval_basis(d, 3) @ p.coeffs, sh_real.eval_basis_rh(d, 3) @ a_rh, atol=1e-9)
    np.testing.assert_allclose(p.rh(), a_rh, atol=1e-9)
    p8 = fit_probe(np.ones((6, 16, 16, 3)), degree=6, lam=0.0)
    assert p8.basis == "rh" and p8.degree == 6
    np.testing.assert_allclose(p8.coeffs[0], np.sqrt(4 * np.pi), rtol=1e-9)
    np.testing.assert_allclose(p8.coeffs[1:], 0, atol=1e-10)
    with pytest.raises(ValueError):
        SHProbe(np.zeros((25, 3)), "3dgs")


def test_mask_excludes_texels():
    a = np.zeros((4, 3))
    a[0] = 1.0
    a[2] = 0.5
    faces = _faces_from_sh(a, 12)
    mask = np.ones((6, 12, 12))
    faces[0] = 1e6  # garbage on face +X, masked out
    mask[0] = 0
    np.testing.assert_allclose(fit_probe(faces, 1, lam=0.0, mask=mask).rh(), a, atol=1e-9)


def test_bad_faces_are_user_errors():
    faces = np.zeros((6, 8, 8, 3))
    faces[2, 3, 4, 1] = np.nan
    with pytest.raises(UserError, match=r"face 2 pixel \(row 3, column 4\)"):
        fit_probe(faces)
    with pytest.raises(UserError, match="shape"):
        fit_probe(np.zeros((5, 8, 8, 3)))


@pytest.mark.parametrize("path", HDRIS, ids=[p.name for p in HDRIS])
def test_real_hdr_probe_matches_direct_projection(path):
    img = envmap.read_envmap(path)
    img = img[: img.shape[0] // 8 * 8, : img.shape[0] // 8 * 16]
    lo = envmap.downsample_latlong(img, 8)  # 64 x 128
    faces = envmap.latlong_to_cube_faces(lo, 32, supersample=4)
    for degree in range(4):
        gt = envmap.project_latlong_to_sh(lo, degree, "rh")
        fit = fit_probe(faces, degree).rh()
        err = np.linalg.norm(fit - gt) / np.linalg.norm(gt)
        assert err <= (0.05 if degree <= 2 else 0.10), (path.name, degree, err)
    # and the stored 3DGS-basis probe agrees with the direct projection converted explicitly
    np.testing.assert_allclose(probe_from_latlong(lo, 3).coeffs, sh_real.rh_to_3dgs(gt), atol=1e-12)


def test_latlong_convention_and_solid_angles():
    d = envmap.latlong_directions(4, 8)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-15)
    assert d[0, 0, 1] > 0.9 and d[-1, 0, 1] < -0.9  # top row looks up (+Y)
    assert np.argmax(d[2, :, 0]) in (3, 4)  # image centre looks along +X
    assert abs(envmap.latlong_solid_angles(64, 128).sum() - 4 * np.pi) < 1e-12
    row, col = envmap.directions_to_latlong_pixel(d, 4, 8)
    np.testing.assert_allclose(row, np.broadcast_to(np.arange(4)[:, None], row.shape), atol=1e-12)
    np.testing.assert_allclose(col, np.broadcast_to(np.arange(8)[None, :], col.shape), atol=1e-12)


def test_cube_latlong_round_trip_of_smooth_function(tmp_path):
    a = np.zeros((9, 3))
    a[0] = [2.0, 1.0, 0.5]
    a[3] = [0.4, 0.0, -0.2]
    a[6] = [0.3, 0.3, 0.1]
    faces = _faces_from_sh(a, 64)
    ll = envmap.cube_faces_to_latlong(faces, 32, 64)
    ref = sh_real.eval_basis_rh(envmap.latlong_directions(32, 64), 2) @ a
    np.testing.assert_allclose(ll, ref, atol=4e-3)  # bilinear, clamped at face edges
    # lat-long of the reconstructed probe and of the raw faces, written and read back as OpenEXR
    p = fit_probe(faces, 2)
    out = p.write_latlong_exr(tmp_path / "probe.exr", 32, 64)
    np.testing.assert_allclose(envmap.read_exr(out), ref, atol=1e-3)
    out2 = envmap.write_cube_faces_latlong(tmp_path / "faces.exr", faces, 32, 64)
    np.testing.assert_array_equal(envmap.read_exr(out2), ll)


def _write_hdr(path, img, rle):
    """Tiny RGBE encoder (test helper): flat or new-style RLE with literal runs only + one run."""
    m, e = np.frexp(img.max(axis=-1))
    scale = np.where(img.max(axis=-1) > 1e-32, m * 256.0 / img.max(axis=-1).clip(1e-32), 0.0)
    rgbe = np.zeros(img.shape[:2] + (4,), dtype=np.uint8)
    rgbe[..., :3] = np.floor(img * scale[..., None]).clip(0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(img.max(axis=-1) > 1e-32, e + 128, 0).astype(np.uint8)
    h, w = img.shape[:2]
    body = bytearray()
    for y in range(h):
        if not rle:
            body += rgbe[y].tobytes()
            continue
        body += bytes([2, 2, w >> 8, w & 255])
        for ch in range(4):
            row = rgbe[y, :, ch]
            body += bytes([128 + 3, int(row[0])])  # a run of 3 copies of pixel 0 ...
            rest = row[3:]
            for s in range(0, len(rest), 128):
                chunk = rest[s:s + 128]
                body += bytes([len(chunk)]) + chunk.tobytes()
    rgbe_run = rgbe.copy()
    if rle:
        rgbe_run[:, 1:3] = rgbe[:, :1]
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode() + bytes(body))
    f = np.where(rgbe_run[..., 3] > 0, np.ldexp(1.0, rgbe_run[..., 3].astype(int) - 136), 0.0)
    return rgbe_run[..., :3] * f[..., None]


@pytest.mark.parametrize("rle", [False, True])
def test_hdr_reader_decodes_rgbe(tmp_path, rle):
    rng = np.random.default_rng(5)
    img = rng.random((5, 140, 3)) * 10 ** rng.uniform(-3, 3, (5, 140, 1))
    expect = _write_hdr(tmp_path / "t.hdr", img, rle)
    got = envmap.read_hdr(tmp_path / "t.hdr")
    np.testing.assert_array_equal(got, expect.astype(np.float32))
    # RGBE keeps 8 mantissa bits relative to the brightest channel of each pixel
    tol = img[:, 3:].max(axis=-1, keepdims=True) / 128
    assert np.all(np.abs(got[:, 3:] - img[:, 3:]) <= tol)
    (tmp_path / "bad.hdr").write_bytes(b"P6\n")
    with pytest.raises(InputFormatError, match="bad.hdr"):
        envmap.read_envmap(tmp_path / "bad.hdr")


def test_hdr_dome_gaussians_colour_convention():
    img = np.zeros((32, 64, 3), dtype=np.float32)
    img[:16] = [3.0, 2.0, 1.0]  # upper hemisphere bright
    img[16:] = [0.1, 0.2, 0.3]
    dome = hdr_dome_gaussians(img, radius=5.0, n=400)
    assert dome.count == 16 * 32 and dome.sh_degree == 0  # box-filtered by 2 to >= 400 pixels
    np.testing.assert_allclose(np.linalg.norm(dome.positions, axis=1), 5.0, rtol=1e-6)
    np.testing.assert_allclose(dome.positions / 5.0, envmap.latlong_directions(16, 32).reshape(-1, 3), atol=1e-6)
    col = sh3dgs.eval_color(dome.sh, np.array([0.0, 0.0, 1.0]))  # 0.5 + C0 sh0
    up = dome.positions[:, 1] > 0
    np.testing.assert_allclose(col[up], np.broadcast_to([3.0, 2.0, 1.0], col[up].shape), rtol=1e-5)
    np.testing.assert_allclose(col[~up], np.broadcast_to([0.1, 0.2, 0.3], col[~up].shape), rtol=1e-4)
    # flat splats: thin axis along the radius
    rot = dome.rotation_matrices()
    thin = rot[np.arange(dome.count), :, np.argmin(dome.scales, axis=1)]
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", thin, dome.positions / 5.0)), 1.0, atol=1e-5)
    assert dome.problems() == []


def test_alpha_weighted_fit_ignores_uncovered_texels():
    a = np.zeros((9, 3))
    a[0] = [1.0, 2.0, 0.5]
    a[4] = [0.2, -0.1, 0.1]
    colour = _faces_from_sh(a, 16)
    alpha = np.random.default_rng(4).uniform(0.05, 1.0, (6, 16, 16))
    alpha[1] = 0.0  # face -X saw nothing
    rgb = colour * alpha[..., None]  # premultiplied render over a black background
    np.testing.assert_allclose(fit_probe(rgb, 2, lam=0.0, alpha=alpha).rh(), a, atol=1e-9)
    assert np.abs(fit_probe(rgb, 2, lam=0.0).rh() - a).max() > 0.1  # without it the holes read as black


def test_probe_module_conversion_matches_kernel_and_does_not_import_numba():
    import subprocess
    import sys

    from usd_gs.relight import probe as probe_mod

    a = np.random.default_rng(9).normal(size=(16, 3))
    np.testing.assert_array_equal(probe_mod.rh_to_3dgs(a), sh_real.rh_to_3dgs(a))
    np.testing.assert_array_equal(probe_mod.threedgs_to_rh(probe_mod.rh_to_3dgs(a)), a)
    code = "import sys, usd_gs.io.envmap, usd_gs.relight.probe; sys.exit(1 if 'numba' in sys.modules else 0)"
    root = Path(__file__).resolve().parents[1]
    res = subprocess.run([sys.executable, "-c", code], cwd=root, env={"PYTHONPATH": str(root)}, check=False)
    assert res.returncode == 0, "usd_gs.io.envmap / usd_gs.relight.probe import numba at import time"
