"""GaussianSet data model: shapes, validation, covariance algebra, transforms, concat/subset."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError
from usd_gs.gaussians import GaussianSet, matrix_to_quaternion, quaternion_to_matrix


def make_set(n=200, degree=3, seed=0, label="/World/g"):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return GaussianSet(
        positions=rng.normal(size=(n, 3)),
        orientations=q,
        scales=np.exp(rng.normal(-2, 1, size=(n, 3))),
        opacities=rng.uniform(size=n),
        sh=rng.normal(size=(n, sh3dgs.num_coeffs(degree), 3)),
        log_scales=rng.normal(size=(n, 3)),
        logit_opacities=rng.normal(size=n),
        extras={"nx": rng.normal(size=n).astype(np.float32)},
        label=label,
    )


def usd_matrix(linear_col, translation):
    """USD row-vector 4x4 for p' = linear_col @ p + t."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(linear_col).T
    m[3, :3] = translation
    return m


def test_dtypes_and_shapes():
    g = make_set(10, 2)
    assert g.count == 10 and len(g) == 10
    assert g.sh_degree == 2
    for a in (g.positions, g.orientations, g.scales, g.opacities, g.sh):
        assert a.dtype == np.float32 and a.flags.c_contiguous


@pytest.mark.parametrize(
    "kwargs, msg",
    [
        ({"scales": np.ones((9, 3))}, "'scales' has 9 elements but 'positions' has 10"),
        ({"sh": np.zeros((10, 5, 3))}, "'sh': 5 SH coefficients per channel"),
        ({"positions": np.zeros((10, 2))}, "'positions' must have shape (N, 3)"),
        ({"sh": np.zeros((10, 25, 3))}, "degree 4"),
    ],
)
def test_shape_errors_name_label_and_field(kwargs, msg):
    base = dict(positions=np.zeros((10, 3)), orientations=np.tile([1.0, 0, 0, 0], (10, 1)),
                scales=np.ones((10, 3)), opacities=np.ones(10), sh=np.zeros((10, 1, 3)))
    base.update(kwargs)
    with pytest.raises(GaussianDataError) as exc:
        GaussianSet(**base, label="/World/bad")
    assert "/World/bad" in str(exc.value) and msg in str(exc.value)


def test_problems_report_first_bad_element():
    g = make_set(50, 0)
    assert g.problems() == []
    g.scales[7, 2] = -1.0
    g.scales[9, 0] = 0.0
    g.opacities[3] = 1.5
    g.positions[11, 1] = np.inf
    g.orientations[4] *= 2.0
    probs = " | ".join(g.problems())
    assert "'scales' element 7 is not > 0" in probs and "2 bad elements" in probs
    assert "'opacities' element 3 is outside [0, 1]" in probs
    assert "'positions' element 11 is not finite" in probs
    assert "'orientations' element 4 is not a unit quaternion" in probs
    with pytest.raises(GaussianDataError, match="/World/g"):
        g.check()


def test_quaternion_matrix_round_trip_and_convention():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # include 180-degree rotations about each axis (w = 0), where naive formulas fail
    q[:3] = [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    r = quaternion_to_matrix(q)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    q2 = matrix_to_quaternion(r)
    np.testing.assert_allclose(np.abs(np.sum(q * q2, axis=1)), 1.0, atol=1e-12)
    # (w, x, y, z) order: compare with scipy, which uses (x, y, z, w)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(r, ref, atol=1e-12)


def test_covariance_and_precision_are_inverse():
    g = make_set(100, 0)
    c = g.covariances()
    p = g.precisions()
    eye = np.einsum("nij,njk->nik", c, p)
    np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-8)
    # eigenvalues of the covariance are the squared scales
    ev = np.sort(np.linalg.eigvalsh(c), axis=1)
    np.testing.assert_allclose(ev, np.sort(g.scales.astype(np.float64) ** 2, axis=1), rtol=1e-10)


def test_similarity_transform_moves_covariance_and_sh():
    g = make_set(300, 3)
    rot = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    s, t = 2.5, np.array([1.0, -2.0, 3.0])
    out = g.transformed(usd_matrix(s * rot, t), label="/World/xf")
    assert out.label == "/World/xf"
    np.testing.assert_allclose(out.positions, (g.positions.astype(np.float64) @ (s * rot).T) + t, atol=1e-5)
    expected_cov = s * s * np.einsum("ij,njk,lk->nil", rot, g.covariances(), rot)
    np.testing.assert_allclose(out.covariances(), expected_cov, rtol=2e-5, atol=1e-9)
    np.testing.assert_allclose(out.log_scales, g.log_scales + np.log(s), atol=1e-6)
    np.testing.assert_array_equal(out.opacities, g.opacities)
    # view-dependent colour follows the rotation: colour seen along R d equals the old colour along d
    d = np.random.default_rng(2).normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(sh3dgs.eval_color(out.sh, d @ rot.T), sh3dgs.eval_color(g.sh, d), atol=2e-5)


def test_uniform_scale_keeps_the_sh_bit_for_bit():
    """A transform without rotation (uniform scale and translation) leaves the SH as they are
    (``rotate_coefficients``' identity case) and scales the scales."""
    g = make_set(50, 3)
    out = g.transformed(usd_matrix(0.5 * np.eye(3), [1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(out.sh, g.sh)
    np.testing.assert_allclose(out.scales, 0.5 * g.scales, rtol=1e-6)
    np.testing.assert_allclose(out.positions, 0.5 * g.positions.astype(np.float64) + [1.0, 2.0, 3.0], atol=1e-6)
    rot = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    mats = sh3dgs.rotation_matrices_per_band(rot, 3)
    got = sh3dgs.rotate_coefficients(g.sh, rot)
    for i in (0, 17, 49):  # each Gaussian's bands times the band matrices, one at a time
        want = np.concatenate([m @ g.sh[i, b * b:(b + 1) * (b + 1)].astype(np.float64) for b, m in enumerate(mats)])
        np.testing.assert_allclose(got[i], want, rtol=1e-6, atol=1e-7)


def test_reflection_is_a_valid_similarity():
    g = make_set(100, 2)
    flip = np.diag([1.0, -1.0, 1.0])
    out = g.transformed(usd_matrix(flip, [0, 0, 0]))
    np.testing.assert_allclose(out.covariances(), np.einsum("ij,njk,lk->nil", flip, g.covariances(), flip),
                               rtol=1e-5, atol=1e-9)
    assert np.all(np.abs(np.linalg.norm(out.orientations, axis=1) - 1) < 1e-6)
    d = np.random.default_rng(3).normal(size=(100, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(sh3dgs.eval_color(out.sh, d @ flip.T), sh3dgs.eval_color(g.sh, d), atol=2e-5)


@pytest.mark.parametrize("linear", [np.diag([1.0, 2.0, 1.0]), np.array([[1, 0.3, 0], [0, 1, 0], [0, 0, 1.0]])])
def test_non_similarity_transform_names_prim(linear):
    with pytest.raises(GaussianDataError, match=r"/World/sheared: transform has a non-uniform scale or shear"):
        make_set(5).transformed(usd_matrix(linear, [0, 0, 0]), label="/World/sheared")


def test_singular_and_projective_transforms_rejected():
    g = make_set(5)
    with pytest.raises(GaussianDataError, match="singular"):
        g.transformed(usd_matrix(np.zeros((3, 3)), [0, 0, 0]))
    m = np.eye(4)
    m[0, 3] = 0.1
    with pytest.raises(GaussianDataError, match="projective"):
        g.transformed(m)


def test_concatenate_pads_sh_and_keeps_common_raw_fields():
    a = make_set(10, 1, seed=1)
    b = make_set(20, 3, seed=2)
    b.extras.pop("nx")
    c = GaussianSet.concatenate([a, b], label="all")
    assert c.count == 30 and c.sh_degree == 3
    np.testing.assert_array_equal(c.sh[:10, :4], a.sh)
    assert np.all(c.sh[:10, 4:] == 0)
    np.testing.assert_array_equal(c.sh[10:], b.sh)
    np.testing.assert_array_equal(c.log_scales[10:], b.log_scales)
    assert "nx" not in c.extras
    b.log_scales = None
    assert GaussianSet.concatenate([a, b]).log_scales is None


def test_concatenate_in_threads_copies_every_row(monkeypatch):
    """A result above PARALLEL_COPY_BYTES is filled in row ranges on threads: the same arrays as
    the fields concatenated one by one (ranges cutting through sets, empty sets, padded SH)."""
    import numba

    import usd_gs.gaussians as gaussians

    sets = [make_set(n, d, seed=i) for i, (n, d) in enumerate([(70_000, 0), (0, 3), (5, 3), (90_000, 1), (1, 2)])]
    monkeypatch.setattr(gaussians, "PARALLEL_COPY_BYTES", 1)
    threads = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        c = GaussianSet.concatenate(sets, label="all")
    finally:
        numba.set_num_threads(threads)
    for name in ("positions", "orientations", "scales", "opacities"):
        np.testing.assert_array_equal(getattr(c, name), np.concatenate([getattr(g, name) for g in sets]))
    want = np.zeros((c.count, 16, 3), np.float32)
    at = 0
    for g in sets:
        want[at:at + g.count, :g.sh.shape[1]] = g.sh
        at += g.count
    np.testing.assert_array_equal(c.sh, want)


def test_subset_mask_and_index():
    g = make_set(40, 2)
    m = g.opacities > 0.5
    s = g.subset(m)
    assert s.count == int(m.sum())
    np.testing.assert_array_equal(s.sh, g.sh[m])
    np.testing.assert_array_equal(s.extras["nx"], g.extras["nx"][m])
    np.testing.assert_array_equal(g.subset(np.array([3, 1])).positions, g.positions[[3, 1]])


def test_extent_contains_three_sigma_of_rotated_ellipsoids():
    g = make_set(50, 0)
    ext = g.extent(3.0)
    # sample points on each 3-sigma ellipsoid surface: they must lie inside the box
    rng = np.random.default_rng(5)
    u = rng.normal(size=(50, 64, 3))
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    pts = g.positions[:, None, :] + np.einsum("nij,nkj->nki", g.rotation_matrices(), 3.0 * g.scales[:, None, :] * u)
    assert np.all(pts >= ext[0] - 1e-5) and np.all(pts <= ext[1] + 1e-5)


def test_sh_rotation_matrices_are_orthogonal_and_compose():
    r1 = Rotation.from_euler("zyx", [10, 20, 30], degrees=True).as_matrix()
    r2 = Rotation.from_euler("zyx", [-40, 5, 70], degrees=True).as_matrix()
    d1 = sh3dgs.rotation_matrices_per_band(r1, 3)
    d2 = sh3dgs.rotation_matrices_per_band(r2, 3)
    d12 = sh3dgs.rotation_matrices_per_band(r2 @ r1, 3)
    for a, b, ab in zip(d1, d2, d12, strict=True):
        np.testing.assert_allclose(a @ a.T, np.eye(a.shape[0]), atol=1e-10)
        np.testing.assert_allclose(b @ a, ab, atol=1e-10)


def test_sh_band1_matches_3dgs_sign_convention():
    # DESIGN.md: band 1 is (-C1*y, +C1*z, -C1*x)
    b = sh3dgs.eval_basis(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]), 1)
    c1 = sh3dgs.C1
    np.testing.assert_allclose(b[:, 1:], [[0, 0, -c1], [-c1, 0, 0], [0, c1, 0]])
    # orthonormality of the degree-3 basis on the sphere (Monte Carlo-free: Fibonacci + many points)
    d = sh3dgs._fibonacci_sphere(20000)
    y = sh3dgs.eval_basis(d, 3)
    gram = 4 * np.pi * y.T @ y / len(d)
    np.testing.assert_allclose(gram, np.eye(16), atol=2e-3)


def test_pure_translation_keeps_everything_but_positions_bit_exact():
    g = make_set(50, 3)
    out = g.transformed(usd_matrix(np.eye(3), [0.5, 0.0, -2.0]))
    for name in ("orientations", "scales", "opacities", "sh", "log_scales", "logit_opacities"):
        np.testing.assert_array_equal(getattr(out, name), getattr(g, name))
    np.testing.assert_array_equal(out.positions, (g.positions.astype(np.float64) + [0.5, 0.0, -2.0]).astype(np.float32))
    same = g.transformed(np.eye(4))
    np.testing.assert_array_equal(same.positions, g.positions)
    assert same.positions is not g.positions


@pytest.mark.parametrize("threaded", [False, True])
def test_concatenate_reports_whether_every_value_is_finite(monkeypatch, threaded):
    """``GaussianSet.concatenate(finite=[])`` appends True for finite inputs and False for an input
    with one NaN or infinity in any attribute (SH of a lower degree padded with zeros), in the
    serial and the threaded fill; the result is the same set either way."""
    from dataclasses import replace

    import usd_gs.gaussians as gaussians_module
    from usd_gs.synthetic import random_gaussians

    if threaded:
        monkeypatch.setattr(gaussians_module, "PARALLEL_COPY_BYTES", 1)
    a, b = random_gaussians(700, 1, seed=1), random_gaussians(900, 3, seed=2)
    flags = []
    whole = GaussianSet.concatenate([a, b], finite=flags)
    plain = GaussianSet.concatenate([a, b])
    assert flags == [True]
    assert all(np.array_equal(getattr(whole, f), getattr(plain, f))
               for f in ("positions", "orientations", "scales", "opacities", "sh"))
    for field, index, value in (("positions", (5, 1), np.nan), ("orientations", (650, 0), np.inf),
                                ("scales", (3, 2), -np.inf), ("opacities", 699, np.nan), ("sh", (2, 3, 0), np.nan)):
        bad = replace(a, **{field: getattr(a, field).copy()})
        getattr(bad, field)[index] = value
        flags.clear()
        GaussianSet.concatenate([b, bad], finite=flags)
        assert flags == [False], field
