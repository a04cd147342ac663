"""Paper 4.1 lighting-consistency metrics against analytic cases (usd_gs.evaluation.lighting_metrics)."""

import numpy as np
import pytest
import trimesh

from usd_gs import sh3dgs
from usd_gs.demo.mesh_avatar import gaussians_on_mesh, sample_surface
from usd_gs.errors import UserError
from usd_gs.evaluation.colorimetry import luminance, rgb_to_lab
from usd_gs.evaluation.lighting_metrics import (
    apf_y,
    emd_2d,
    fit_factorization,
    irradiance,
    lighting_consistency,
    paa_y,
    pseudo_normals,
    scene_lighting,
)

# Two irradiance environments in the RH basis (c_00 = 1): a key light from +y/+x, and one from -z
# with a stronger band 2 (both positive on the whole sphere).
C_A = np.zeros(16)
C_A[[0, 1, 3, 6]] = [1.0, 0.55, 0.25, 0.12]
C_B = np.zeros(16)
C_B[[0, 2, 4, 8]] = [1.0, -0.6, 0.15, -0.2]


def sphere(radius, n, center=(0.0, 0.0, 0.0), seed=0, rgb=(0.5, 0.5, 0.5)):
    m = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    v = np.asarray(m.vertices) + np.asarray(center)
    face, bary = sample_surface(v, m.faces, n, seed)
    return gaussians_on_mesh(v, m.faces, np.asarray(m.vertex_normals), face, bary, rgb)


def with_colors(g, rgb):
    out = g.with_label(g.label)
    out.sh = ((np.asarray(rgb, np.float64) - 0.5) / sh3dgs.C0)[:, None, :].astype(np.float32)
    return out


def radial(g, center=(0.0, 0.0, 0.0)):
    d = g.positions.astype(np.float64) - np.asarray(center)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def shaded(g, normals, coeffs, albedo=0.5, tint=(1.0, 1.0, 1.0)):
    """Grey albedo times E(n; c) (times a tint), as linear RGB colours."""
    y = np.asarray(albedo) * irradiance(normals, coeffs)
    return with_colors(g, y[:, None] * np.asarray(tint)[None, :])


# ----------------------------------------------------------------------------- colorimetry
def test_luminance_and_lab_reference_values():
    assert luminance([1.0, 1.0, 1.0]) == pytest.approx(1.0, abs=1e-6)
    assert luminance([1.0, 0.0, 0.0]) == pytest.approx(0.2126729)
    assert np.allclose(rgb_to_lab([1.0, 1.0, 1.0]), [100.0, 0.0, 0.0], atol=1e-3)
    assert np.allclose(rgb_to_lab([0.0, 0.0, 0.0]), [0.0, 0.0, 0.0], atol=1e-9)
    # sRGB red (linear (1, 0, 0)), D65: the published CIE-Lab value
    assert np.allclose(rgb_to_lab([1.0, 0.0, 0.0]), [53.2408, 80.0925, 67.2032], atol=0.01)
    # linear segment of f: a grey of Y = 0.001 has L* = (29/3)^3 * Y
    assert rgb_to_lab([0.001, 0.001, 0.001])[0] == pytest.approx((29.0 / 3.0) ** 3 * 0.001, rel=1e-4)


# ----------------------------------------------------------------------------- EMD
def test_emd_of_a_shifted_cloud_is_the_shift():
    p = np.random.default_rng(1).normal(size=(400, 2)) * [3.0, 1.0]
    assert emd_2d(p, p) == pytest.approx(0.0, abs=1e-6)
    assert emd_2d(p, p + [3.0, -4.0]) == pytest.approx(5.0, rel=1e-6)
    # subsampled clouds (3000 -> 800 points each) still give the shift within sampling noise
    q = np.random.default_rng(2).normal(size=(3000, 2))
    assert emd_2d(q, q + [0.0, 2.0], max_points=800) == pytest.approx(2.0, abs=0.15)


# ----------------------------------------------------------------------------- normals and fits
def test_pseudo_normals_of_a_sphere_are_radial():
    g = sphere(0.5, 3000)
    out = pseudo_normals(g)  # outward: agree with the smallest-axis normals
    assert np.min(np.einsum("ij,ij->i", out, radial(g))) > 0.97
    inward = pseudo_normals(g, toward=(0.0, 0.0, 0.0))
    assert np.min(np.einsum("ij,ij->i", inward, -radial(g))) > 0.97


def test_factorization_recovers_known_sh_irradiance():
    g = sphere(0.5, 3000)
    n = radial(g)
    for c in (C_A, 2.7 * C_B):  # the scale drops out: coefficients come back with c_00 = 1
        y = 0.4 * irradiance(n, c)
        fit = fit_factorization(y, n)
        assert np.abs(fit.coeffs - c / c[0]).sum() < 1e-3
        assert np.allclose(fit.scales * irradiance(n, fit.coeffs), y, atol=1e-4)
    # random albedo (uncorrelated with the normals) and 3 % outliers: recovered within 0.1 (L1 of 16)
    rng = np.random.default_rng(0)
    y = rng.uniform(0.3, 0.7, len(n)) * irradiance(n, C_A)
    y[rng.choice(len(y), len(y) // 33, replace=False)] = 3.0
    fit = fit_factorization(y, n)
    assert paa_y(fit.coeffs, C_A) < 0.1
    assert paa_y(fit_factorization(y, n, alpha_prior=np.inf).coeffs, C_A) < 0.1


def test_factorization_rejects_too_few_gaussians():
    with pytest.raises(UserError, match="at least 16"):
        fit_factorization(np.ones(10), np.tile([0.0, 0.0, 1.0], (10, 1)))


def test_apf_is_zero_for_exactly_affine_luminance():
    g = sphere(0.5, 2000)
    n = radial(g)
    y = 0.3 * irradiance(n, C_A) + 0.05
    apf, s, b = apf_y(y, n, C_A)
    assert apf < 1e-6 and s == pytest.approx(0.3, rel=1e-5) and b == pytest.approx(0.05, abs=1e-6)
    apf_b, _, _ = apf_y(y, n, C_B)  # the wrong lighting cannot explain it
    assert apf_b > 0.02


# ----------------------------------------------------------------------------- the metrics together
def scene_shell(coeffs, tint=(1.0, 1.0, 1.0)):
    """Scene Gaussians on a sphere of radius 1.3 m around the avatar, facing it, shaded by ``coeffs``."""
    g = sphere(1.3, 6000, seed=3)
    return shaded(g, -radial(g), coeffs, albedo=0.6, tint=tint)


def test_paa_zero_for_the_same_lighting_and_measurable_for_another():
    avatar = sphere(0.4, 3000)
    n = radial(avatar)
    sc = scene_lighting(scene_shell(C_A), (0.0, 0.0, 0.0), 1.5)
    assert paa_y(sc.fit.coeffs, C_A) < 0.01  # the scene's lighting is recovered from its own Gaussians
    lit_a = luminance(shaded(avatar, n, C_A).sh[:, 0] * sh3dgs.C0 + 0.5)
    lit_b = luminance(shaded(avatar, n, C_B).sh[:, 0] * sh3dgs.C0 + 0.5)
    assert paa_y(fit_factorization(lit_a, n).coeffs, sc.fit.coeffs) < 0.02
    expected = paa_y(C_A, C_B)  # = 1.97
    assert paa_y(fit_factorization(lit_b, n).coeffs, sc.fit.coeffs) == pytest.approx(expected, rel=0.05)
    with pytest.raises(UserError, match=r"\[1, 2\]"):
        scene_lighting(scene_shell(C_A), (0.0, 0.0, 0.0), 2.5)


def test_relit_avatar_improves_all_three_metrics():
    tint = (1.0, 0.8, 0.55)  # warm light: the scene's chromaticity shifts
    scene = scene_shell(C_A, tint)
    avatar = sphere(0.4, 3000)
    orig = shaded(avatar, radial(avatar), C_B, albedo=0.4)  # as captured: another (white) light
    relit = shaded(avatar, radial(avatar), C_A, albedo=0.8, tint=tint)
    r = lighting_consistency(orig, relit, scene, radius_m=1.5)
    assert r["n_scene"] == 6000 and r["n_avatar"] == 3000
    assert r["relit"]["paa_y"] < 0.05 and r["orig"]["paa_y"] > 0.5
    assert r["relit"]["apf_y"] < 5e-3 and r["orig"]["apf_y"] > 0.05  # pseudo-normals: PCA, not exact
    assert r["relit"]["ncm_ab"] < 0.5 * r["orig"]["ncm_ab"]
    for m in ("paa_y", "apf_y", "ncm_ab"):
        assert r["delta"][m] == pytest.approx(r["relit"][m] - r["orig"][m])
        assert r["improvement"][m] == pytest.approx(-r["delta"][m]) and r["improvement"][m] > 0


# ----------------------------------------------------------------------------- stage entry point
def test_lighting_consistency_for_stage(tmp_path):
    """A hand-made 'usdgs process'-style output: the relit SH and lightScale are overs in a layer
    that sublayers the input; the original colours come from the input layer."""
    from pxr import Sdf, Usd, Vt

    from usd_gs.evaluation.lighting_stage import lighting_consistency_for_stage
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
    from usd_gs.usd.output_author import LIGHT_SCALE, SH_COEFFS
    from usd_gs.usd.schema import apply_role

    tint = (1.0, 0.8, 0.55)
    avatar = sphere(0.4, 2000)
    orig = shaded(avatar, radial(avatar), C_B, albedo=0.4)
    stage = new_stage(tmp_path / "shot.usda")
    apply_role(write_gaussian_prim(stage, "/World/Room", scene_shell(C_A, tint)), "scene")
    relit = {}
    for f in (1.0, 2.0):  # the avatar moves by 0.1 m per frame
        g = orig.transformed(np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.1 * f, 0, 0, 1.0]]))
        prim = write_gaussian_prim(stage, "/World/Walker", g, time=f)
        relit[f] = shaded(g, radial(g, (0.1 * f, 0, 0)), C_A, albedo=0.8, tint=tint).sh
    apply_role(prim, "avatar")
    save_stage_atomic(stage, tmp_path / "shot.usda")
    out = Usd.Stage.CreateNew(str(tmp_path / "shot.lit.usda"))
    out.GetRootLayer().subLayerPaths.append("./shot.usda")
    over = out.OverridePrim("/World/Walker")
    sh_attr = over.CreateAttribute(SH_COEFFS, Sdf.ValueTypeNames.Float3Array)
    ls_attr = over.CreateAttribute(LIGHT_SCALE, Sdf.ValueTypeNames.Color3fArray)
    for f, sh in relit.items():
        sh_attr.Set(Vt.Vec3fArray.FromNumpy(sh.reshape(-1, 3)), f)
        ls_attr.Set(Vt.Vec3fArray.FromNumpy(np.ones((sh.shape[0], 3), np.float32)), f)
    out.GetRootLayer().Save()

    r = lighting_consistency_for_stage(tmp_path / "shot.lit.usda")
    assert r["avatars"] == ["/World/Walker"] and r["frames"] == [1.0, 2.0]
    assert r["input"].endswith("shot.usda")
    for f in (1.0, 2.0):
        res = r["per_frame"]["/World/Walker"][f]
        assert np.allclose(res["centre"], [0.1 * f, 0, 0], atol=0.02)
        assert res["relit"]["paa_y"] < 0.05 and res["orig"]["paa_y"] == pytest.approx(paa_y(C_A, C_B), rel=0.05)
    s = r["overall"]
    assert all(s["improvement"][m] > 0 for m in ("paa_y", "apf_y", "ncm_ab"))
    assert s["delta"]["paa_y"] == pytest.approx(s["relit"]["paa_y"] - s["orig"]["paa_y"])
    with pytest.raises(UserError, match="no sublayer"):
        lighting_consistency_for_stage(tmp_path / "shot.usda")


def test_sh_rank_counts_the_coefficients_the_normals_determine():
    from usd_gs.evaluation.lighting_metrics import sh_rank

    assert sh_rank(radial(sphere(0.5, 2000))) == 16
    assert sh_rank(np.tile([0.0, 1.0, 0.0], (500, 1))) == 1  # a floor
    two = np.repeat([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], 300, axis=0)  # floor and one wall
    assert sh_rank(two) == 2


# ----------------------------------------------------------------------------- rank-limited scenes
def test_paa_compares_only_what_the_scene_normals_determine():
    from usd_gs.evaluation.lighting_metrics import sh_basis

    everywhere = radial(sphere(0.5, 4000))
    # normals over the whole sphere: the paper's plain L1 distance (k ~ 1, P = I)
    assert paa_y(C_A, C_B, everywhere) == pytest.approx(paa_y(C_A, C_B), rel=0.03)
    floor = np.tile([0.0, 1.0, 0.0], (400, 1))
    assert paa_y(C_A, C_B, floor) == pytest.approx(0.0, abs=1e-12)  # a floor shows only the level
    # floor and one wall (rank 2): the minimum-norm coefficients reproducing the difference of the
    # two level-normalised lightings at the two normals (pseudo-inverse, not the eigen-projector)
    two = np.repeat([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], 300, axis=0)
    b = sh_basis(two)
    y00 = sh_basis(np.array([[0.0, 0.0, 1.0]]))[0, 0]
    v = C_A * y00 / (b @ C_A).mean() - C_B * y00 / (b @ C_B).mean()
    assert paa_y(C_A, C_B, two) == pytest.approx(np.abs(np.linalg.pinv(b, rcond=1e-6) @ (b @ v)).sum(), rel=1e-5)
    assert paa_y(3.0 * C_A, C_B, two) == pytest.approx(paa_y(C_A, C_B, two), rel=1e-9)  # exposure drops out
    assert paa_y(C_A, C_B, two) > 0.05


def test_visible_from_hides_what_a_ball_covers():
    """A floor patch under a ball, seen from above: hidden = the segment to the eye crosses the
    ball (analytic ray-sphere test), for the floor and for the ball's own far side."""
    from usd_gs.evaluation.point_visibility import visible_from
    from usd_gs.gaussians import GaussianSet

    plane = trimesh.Trimesh([[-1.5, 0, -1.5], [1.5, 0, -1.5], [1.5, 0, 1.5], [-1.5, 0, 1.5]], [[0, 2, 1], [0, 3, 2]])
    face, bary = sample_surface(plane.vertices, plane.faces, 30000, 1)
    floor = gaussians_on_mesh(plane.vertices, plane.faces, np.tile([0.0, 1.0, 0.0], (4, 1)), face, bary,
                              (0.5, 0.5, 0.5))
    centre, r = np.array([0.2, 0.5, 0.0]), 0.3
    ball = sphere(r, 6000, center=centre, seed=2)
    g = GaussianSet.concatenate([floor, ball])
    eye = np.array([0.0, 1.6, 0.3])
    p = g.positions.astype(np.float64)
    d = p - eye
    t = np.linalg.norm(d, axis=1)
    u = d / t[:, None]
    oc = eye - centre
    bq = np.einsum("ij,j->i", u, oc)
    disc = bq * bq - (oc @ oc - r * r)
    t_hit = -bq - np.sqrt(np.maximum(disc, 0.0))
    hidden = (disc > 0) & (t_hit > 0) & (t_hit < t - 0.02)
    seen = visible_from(g, eye)
    assert 0.1 < hidden.mean() < 0.5
    assert np.mean(seen == ~hidden) > 0.96
    # every disagreement lies along the ball's silhouette (splat tails, texels of 1.4 degrees)
    to_ball = (centre - eye) / np.linalg.norm(centre - eye)
    off_rim = np.degrees(np.arccos(np.clip(u @ to_ball, -1, 1))) - np.degrees(np.arcsin(r / np.linalg.norm(oc)))
    wrong = seen == hidden
    assert (np.abs(off_rim[wrong]) < 4.0).all() and np.percentile(np.abs(off_rim[wrong]), 95) < 2.5


def test_scene_lighting_leaves_out_what_the_avatar_does_not_see():
    """A wall behind a box, from the avatar's side: the wall's part behind the box and the box's
    far faces are not in the neighbourhood; without the test they are (visible_only=False)."""
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box.apply_translation((0.0, 0.3, -0.8))
    box.unmerge_vertices()
    face, bary = sample_surface(box.vertices, box.faces, 6000, 4)
    g_box = gaussians_on_mesh(np.asarray(box.vertices), box.faces, np.asarray(box.vertex_normals), face, bary,
                              (0.6, 0.6, 0.6))
    sc_all = scene_lighting(g_box, (0.0, 0.9, 0.0), 1.5, visible_only=False)
    sc = scene_lighting(g_box, (0.0, 0.9, 0.0), 1.5)
    assert sc.hidden + sc.index.size == sc_all.index.size
    box_n = g_box.orientations  # local z = face normal: the box's far (-z) and bottom faces are hidden
    from usd_gs.gaussians import quaternion_to_matrix

    n = quaternion_to_matrix(box_n)[:, :, 2]
    kept = np.zeros(g_box.count, bool)
    kept[sc.index] = True
    # the bottom face, seen edge-on, keeps a band along the front edge within the depth tolerance
    # (3 cm + 5 % + 3 sigma); deeper than 15 cm behind the front face it is gone
    inside = np.zeros(g_box.count, bool)
    inside[sc_all.index] = True
    bottom = (n[:, 1] < -0.9) & (g_box.positions[:, 2] < -0.65)
    assert kept[inside & (n[:, 2] < -0.9)].mean() < 0.02 and kept[inside & bottom].mean() < 0.02
    assert kept[inside & ((n[:, 2] > 0.9) | (n[:, 1] > 0.9))].mean() > 0.97


def test_undetermined_paa_is_nan_and_left_out_of_the_means():
    from usd_gs.evaluation.lighting_metrics import PAA_MIN_RANK, summarize
    from usd_gs.evaluation.lighting_stage import format_report

    avatar = sphere(0.4, 2000)
    plane = trimesh.Trimesh([[-1.5, 0, -1.5], [1.5, 0, -1.5], [1.5, 0, 1.5], [-1.5, 0, 1.5]], [[0, 2, 1], [0, 3, 2]])
    face, bary = sample_surface(plane.vertices, plane.faces, 8000, 1)
    floor = gaussians_on_mesh(plane.vertices, plane.faces, np.tile([0.0, 1.0, 0.0], (4, 1)), face, bary,
                              (0.5, 0.5, 0.5))
    lifted = avatar.transformed(np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0.5, 0, 1.0]]))
    orig = shaded(lifted, radial(lifted, (0, 0.5, 0)), C_B, albedo=0.4)
    relit = shaded(lifted, radial(lifted, (0, 0.5, 0)), C_A, albedo=0.4)
    on_floor = lighting_consistency(orig, relit, floor, radius_m=1.5)
    assert on_floor["scene_sh_rank"] < PAA_MIN_RANK
    assert np.isnan(on_floor["orig"]["paa_y"]) and np.isnan(on_floor["improvement"]["paa_y"])
    assert np.isfinite(on_floor["relit"]["apf_y"]) and np.isfinite(on_floor["relit"]["ncm_ab"])
    in_shell = lighting_consistency(shaded(avatar, radial(avatar), C_B, albedo=0.4),
                                    shaded(avatar, radial(avatar), C_A, albedo=0.4), scene_shell(C_A), radius_m=1.5)
    s = summarize([on_floor, in_shell])
    assert s["count"] == 2 and s["determined"] == {"paa_y": 1, "apf_y": 2, "ncm_ab": 2}
    assert s["relit"]["paa_y"] == pytest.approx(in_shell["relit"]["paa_y"])
    only_floor = summarize([on_floor])
    assert np.isnan(only_floor["relit"]["paa_y"])
    text = format_report({"mean": {"/A": only_floor}, "overall": only_floor})
    assert "n/a" in text and "PAA-Y undetermined in 1 of 1 frames" in text
