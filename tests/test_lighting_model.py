"""The lighting model of the relighting (issue 18): UsdLux reading, direct terms against analytic
irradiance, colour temperature, sRGB, unobserved-direction fill, blocked lights, no double counting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from usd_gs import sh3dgs
from usd_gs.colorspace import display_factor, srgb_decode, srgb_encode
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.pipeline.options import ProcessOptions
from usd_gs.relight.avatar import relight_factors
from usd_gs.relight.direct import cap_irradiance, direct_irradiance
from usd_gs.usd.lux import ShotLight, blackbody_rgb, read_stage_lights


# ----------------------------------------------------------------------------- direct terms
def _plane(n=50):
    x = np.linspace(-2.0, 2.0, n)
    g = np.stack(np.meshgrid(x, x, indexing="ij"), -1).reshape(-1, 2)
    pts = np.column_stack([g[:, 0], np.zeros(len(g)), g[:, 1]])
    return pts, np.tile([0.0, 1.0, 0.0], (len(pts), 1))


def test_point_light_inverse_square_and_cosine():
    pts, nrm = _plane()
    lt = ShotLight("p", "point", np.array([0.3, 2.0, -0.4]), color=np.array([1.0, 0.5, 0.25]), intensity=8.0)
    e = direct_irradiance(lt, pts, nrm)
    d = lt.position - pts
    r = np.linalg.norm(d, axis=1)
    ref = (8.0 * d[:, 1] / r / r ** 2)[:, None] * lt.color
    np.testing.assert_allclose(e, ref, rtol=1e-12)


def _cap_quadrature(cos_t, sigma, m=400):
    """Irradiance from a unit-radiance cap (angular radius sigma, centre at angle theta from +Z)
    on the plane z = 0 (normal +Z), by midpoint quadrature over the cap."""
    th = np.arccos(cos_t)
    c = np.array([np.sin(th), 0.0, np.cos(th)])
    u = np.array([np.cos(th), 0.0, -np.sin(th)])
    v = np.array([0.0, 1.0, 0.0])
    a = (np.arange(m) + 0.5) / m * sigma
    b = (np.arange(2 * m) + 0.5) / (2 * m) * 2 * np.pi
    aa, bb = np.meshgrid(a, b, indexing="ij")
    w = np.cos(aa)[..., None] * c + np.sin(aa)[..., None] * (np.cos(bb)[..., None] * u + np.sin(bb)[..., None] * v)
    dom = np.sin(aa) * (sigma / m) * (2 * np.pi / (2 * m))
    return float(np.sum(np.maximum(w[..., 2], 0.0) * dom))


@pytest.mark.parametrize("cos_t", [1.0, 0.6, 0.1, 0.0, -0.05])
def test_cap_irradiance_against_quadrature(cos_t):
    """A 10 degree cap, above and across the horizon (Snyder's closed form)."""
    sigma = math.radians(10.0)
    assert cap_irradiance(np.array([cos_t]), math.sin(sigma))[0] == pytest.approx(_cap_quadrature(cos_t, sigma),
                                                                                rel=2e-3, abs=1e-6)


def test_sun_disc_on_a_plane():
    """A 0.53 degree sun of radiance L: E = L pi sin^2(angle / 2) cos above the horizon (a uniform
    disc's exact irradiance), the finite-disc value across it."""
    sun = ShotLight("s", "directional", direction=np.array([0.0, -np.cos(0.4), -np.sin(0.4)]), intensity=2.0e4,
                    shape="distant", angle=0.53)
    pts, nrm = _plane(4)
    e = direct_irradiance(sun, pts, nrm)
    np.testing.assert_allclose(e, 2.0e4 * np.pi * np.sin(np.radians(0.53) / 2) ** 2 * np.cos(0.4), rtol=1e-9)
    # grazing: sun centre exactly on the horizon -> half the disc above, about half the flux x mean cos
    g = ShotLight("g", "directional", direction=np.array([0.0, 0.0, -1.0]), intensity=1.0, shape="distant",
                  angle=10.0)
    got = direct_irradiance(g, np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]]))[0, 0]
    sigma = np.radians(5.0)
    ref = _cap_quadrature(0.0, sigma)
    assert got == pytest.approx(ref, rel=2e-3)


def _lambert_polygon(x, n, corners):
    """Irradiance from a unit-radiance polygon at ``x`` about ``n`` (Lambert's formula, polygon fully
    above the horizon): E = 1/2 sum_i theta_i (n . gamma_i)."""
    v = corners - x
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    e = 0.0
    for i in range(len(v)):
        a, b = v[i], v[(i + 1) % len(v)]
        g = np.cross(a, b)
        g /= np.linalg.norm(g)
        e += np.arccos(np.clip(a @ b, -1, 1)) * (g @ n)
    return 0.5 * abs(e)


def test_rect_light_against_lambert_polygon():
    """A 0.6 x 0.4 m RectLight 1.5 m up facing down (emits along -Z, turned to -Y): 16 samples
    within 1 % of Lambert's exact polygon irradiance."""
    ax = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # columns x, y, z: z = +Y (emits -Y)
    lt = ShotLight("r", "point", np.array([0.0, 1.5, 0.0]), intensity=3.0, shape="rect", width=0.6, height=0.4,
                   axes=ax)
    pts = np.array([[0.0, 0.0, 0.0], [0.8, 0.0, 0.3], [-1.0, 0.2, -0.5]])
    nrm = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.3, 0.9, 0.1]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    got = direct_irradiance(lt, pts, nrm)[:, 0]
    hw, hh = 0.3, 0.2
    corners = np.array([lt.position + sx * hw * ax[:, 0] + sy * hh * ax[:, 1]
                        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    ref = np.array([3.0 * _lambert_polygon(p, n, corners) for p, n in zip(pts, nrm, strict=True)])
    np.testing.assert_allclose(got, ref, rtol=0.01)
    # nothing behind the emitting side
    assert direct_irradiance(lt, np.array([[0.0, 3.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]))[0, 0] == 0.0


def test_sphere_light_far_field_is_the_point_light():
    s = ShotLight("s", "point", np.array([0.0, 4.0, 0.0]), intensity=5.0, radius=0.1)
    p = ShotLight("p", "point", np.array([0.0, 4.0, 0.0]), intensity=5.0 * np.pi * 0.01)
    pts, nrm = _plane(5)
    np.testing.assert_allclose(direct_irradiance(s, pts, nrm), direct_irradiance(p, pts, nrm), rtol=1e-9)


# ----------------------------------------------------------------------------- colour
def test_colour_temperature_matches_published_chromaticities():
    """2856 K is CIE illuminant A (x, y) = (0.44757, 0.40745); 6500 K on the Planckian locus is
    (0.3135, 0.3237) (CIE 15:2004 tables); also close to usd-core's own blackbody table."""
    from usd_gs.evaluation.colorimetry import RGB_TO_XYZ

    for t, xy in ((2856.0, (0.44757, 0.40745)), (6500.0, (0.3135, 0.3237))):
        xyz = RGB_TO_XYZ @ blackbody_rgb(t)
        assert xyz[1] == pytest.approx(1.0, abs=1e-6)
        assert xyz[0] / xyz.sum() == pytest.approx(xy[0], abs=1.5e-3)
        assert xyz[1] / xyz.sum() == pytest.approx(xy[1], abs=1.5e-3)
    usd = np.array(UsdLux.BlackbodyTemperatureAsRgb(6500.0))
    np.testing.assert_allclose(blackbody_rgb(6500.0), usd / (RGB_TO_XYZ[1] @ usd), atol=0.02)


def test_srgb_round_trip_and_published_points():
    x = np.linspace(0.0, 4.0, 2001)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    # IEC 61966-2-1: encoded 0.5 is linear 0.2140, 0.04045 the knee (linear 0.0031308)
    assert srgb_decode(0.5) == pytest.approx(0.21404, abs=1e-5)
    assert srgb_encode(0.0031308) == pytest.approx(0.04045, abs=1e-5)
    c = np.array([[0.5, 0.2, 0.01]])
    k = np.array([[2.0, 0.5, 3.0]])
    f = display_factor(c, k, "srgb")
    np.testing.assert_allclose(srgb_decode(f * c), srgb_decode(c) * k, rtol=1e-10)
    np.testing.assert_allclose(display_factor(c, k, "linear"), k)


# ----------------------------------------------------------------------------- UsdLux reading
def _stage():
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    return stage


def test_read_all_usdlux_kinds(tmp_path):
    from usd_gs.io import envmap

    stage = _stage()
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.CreateAngleAttr(2.0)
    sun.CreateIntensityAttr(100.0)
    sun.CreateExposureAttr(-1.0)
    sun.CreateEnableColorTemperatureAttr(True)
    sun.CreateColorTemperatureAttr(2856.0)
    rect = UsdLux.RectLight.Define(stage, "/Win")
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(1.0)
    rect.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
    rect.AddScaleOp().Set(Gf.Vec3f(1.5, 1.0, 1.0))
    disk = UsdLux.DiskLight.Define(stage, "/Spot")
    disk.CreateRadiusAttr(0.25)
    pt = UsdLux.SphereLight.Define(stage, "/Bulb")
    pt.CreateTreatAsPointAttr(True)
    img = np.zeros((8, 16, 3), np.float32)
    img[:4] = (1.0, 2.0, 3.0)  # upper hemisphere only
    tex = envmap.write_exr(tmp_path / "sky.exr", img)
    dome = UsdLux.DomeLight_1.Define(stage, "/Sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath(str(tex)))
    dome.CreateIntensityAttr(0.5)
    UsdLux.DomeLight.Define(stage, "/Grey")
    lights, warns = read_stage_lights(stage, Usd.TimeCode.Default(), include_domes=True)
    by = {lt.name: lt for lt in lights}
    assert by["/Sun"].angle == pytest.approx(2.0) and by["/Sun"].intensity == pytest.approx(50.0)
    np.testing.assert_allclose(by["/Sun"].color, blackbody_rgb(2856.0), rtol=1e-6)
    assert by["/Win"].form == "rect" and by["/Win"].width == pytest.approx(3.0) and by["/Win"].height == 1.0
    assert by["/Spot"].form == "disk" and by["/Spot"].radius == pytest.approx(0.25)
    assert by["/Bulb"].form == "point" and by["/Bulb"].radius == 0.0
    sky = by["/Sky"]
    assert sky.kind == "dome" and sky.env.shape == (8, 16, 3) and sky.env[0, 0, 2] == pytest.approx(3.0)
    assert by["/Grey"].kind == "dome" and by["/Grey"].env is None
    # without include_domes the domes are skipped with a warning (shadow and evaluation callers)
    plain, warns = read_stage_lights(stage, Usd.TimeCode.Default())
    assert {lt.kind for lt in plain} == {"point", "directional"} and any("/Sky" in w for w in warns)


@pytest.mark.parametrize("what", ["missing", "unreadable", "negative", "nan"])
def test_bad_lights_name_prim_and_attribute(tmp_path, what):
    stage = _stage()
    if what in ("missing", "unreadable"):
        path = tmp_path / "sky.exr"
        if what == "unreadable":
            path.write_bytes(b"not an exr")
        d = UsdLux.DomeLight.Define(stage, "/Sky")
        d.CreateTextureFileAttr(Sdf.AssetPath(str(path)))
        msg = "/Sky: inputs:texture:file"
    elif what == "negative":
        UsdLux.SphereLight.Define(stage, "/Lamp").CreateIntensityAttr(-2.0)
        msg = "/Lamp: inputs:intensity is negative"
    else:
        UsdLux.DistantLight.Define(stage, "/Sun").AddTranslateOp().Set(Gf.Vec3d(float("nan"), 0, 0))
        msg = "/Sun: its transform"
    with pytest.raises(UserError, match=msg):
        read_stage_lights(stage, Usd.TimeCode.Default(), include_domes=True)


# ----------------------------------------------------------------------------- relight_factors
def _patch(n=64, y=1.0):
    """A small flat avatar patch facing +Y at height ``y``, colour 0.5 (display)."""
    rng = np.random.default_rng(0)
    pos = np.column_stack([rng.uniform(-0.1, 0.1, n), np.full(n, y), rng.uniform(-0.1, 0.1, n)])
    q = np.tile([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0], (n, 1))  # local z -> +y
    sh = np.zeros((n, 1, 3), np.float32)
    return GaussianSet(pos, q, np.full((n, 3), 0.01), np.full(n, 0.9), sh, label="patch")


def _grey_floor(value=0.5):
    x = np.linspace(-6, 6, 60)
    g = np.stack(np.meshgrid(x, x, indexing="ij"), -1).reshape(-1, 2)
    pos = np.column_stack([g[:, 0], np.zeros(len(g)), g[:, 1]])
    sh = np.full((len(pos), 1, 3), (value - 0.5) / sh3dgs.C0, np.float32)
    return GaussianSet(pos, np.tile([1.0, 0, 0, 0], (len(pos), 1)), np.tile([0.15, 0.15, 0.01], (len(pos), 1)),
                       np.full(len(pos), 0.99), sh, label="floor")


def _factors(avatar, scene, lights=(), visibility=None, mask=None, **kw):
    opts = ProcessOptions(probe_points=1, **kw)
    every = GaussianSet.concatenate([scene, avatar])
    m = np.ones(every.count, bool)
    m[scene.count:] = False
    if mask is not None:
        m[:scene.count] &= mask
    nrm = np.tile([0.0, 1.0, 0.0], (avatar.count, 1))
    f, probe = relight_factors(avatar, every, m, avatar.positions.mean(0), nrm, None, opts, lights=lights,
                               visibility=visibility)
    return f, probe


def test_blocked_light_leaves_the_indirect_term():
    """A sun fully blocked (visibility 0) gives exactly the factor without the sun: the indirect
    term, not black; unblocked it adds E_sun / pi (linear)."""
    av, floor = _patch(), _grey_floor()
    sun = ShotLight("s", "directional", direction=np.array([0.0, -1.0, 0.0]), intensity=3.0, shape="distant")
    dome = ShotLight("d", "dome", intensity=0.8, shape="dome")
    f_none, _ = _factors(av, floor, [dome], color_space="linear")
    f_blk, _ = _factors(av, floor, [sun, dome], visibility=[np.zeros(av.count), None], color_space="linear")
    f_lit, _ = _factors(av, floor, [sun, dome], visibility=[np.ones(av.count), None], color_space="linear")
    np.testing.assert_allclose(f_blk, f_none, rtol=1e-6)
    assert f_none.min() > 0.5  # the dome above, through the probe: ~0.8 (facing up, floor below unseen)
    np.testing.assert_allclose(f_lit - f_blk, 3.0 / np.pi, rtol=1e-5)


def test_unobserved_directions_filled_by_dome_or_mean():
    """Only a floor below: facing up the probe saw nothing. With a uniform dome of radiance 0.8 the
    factor is ~0.8; without one the observed mean (the floor's 0.5) fills the sky."""
    av, floor = _patch(), _grey_floor()
    dome = ShotLight("d", "dome", intensity=0.8, shape="dome")
    f_dome, probe = _factors(av, floor, [dome], color_space="linear")
    f_mean, _ = _factors(av, floor, [], color_space="linear")
    assert np.median(f_dome) == pytest.approx(0.8, rel=0.06)
    assert np.median(f_mean) == pytest.approx(0.5, rel=0.06)
    assert probe.radiance(np.array([0.0, 1.0, 0.0]))[0] > 0.7


@pytest.mark.parametrize("space", ["linear", "srgb"])
def test_without_lights_the_captured_mean_brightness_is_kept(space):
    """No light at all, a dark floor (0.05) below and a grey ceiling (0.3) above: the absolute rule
    makes the patch dark; ``keep_level`` scales the relit linear colours to the captured ones'
    opacity-weighted mean luminance, and the probe's shading between directions stays (down-facing
    Gaussians, which see the floor, against up-facing ones, which see the fill)."""
    av, floor = _patch(), _grey_floor(0.05)
    backdrop = _grey_floor(0.3)
    backdrop.positions[:, 1] = 3.0  # a ceiling above: the up-facing Gaussians see it
    av.opacities[::3] = 0.4
    nrm = np.tile([0.0, 1.0, 0.0], (av.count, 1))
    nrm[::2] = [0.0, -1.0, 0.0]
    scene = GaussianSet.concatenate([floor, backdrop])
    every = GaussianSet.concatenate([scene, av])
    m = np.ones(every.count, bool)
    m[scene.count:] = False
    opts = ProcessOptions(probe_points=1, color_space=space)
    args = (av, every, m, av.positions.mean(0), nrm, None, opts)
    f_abs, _ = relight_factors(*args)
    f_keep, _ = relight_factors(*args, keep_level=True)
    c = 0.5  # the patch's displayed colour
    dec = (lambda x: x) if space == "linear" else srgb_decode
    lum = np.array([0.2126, 0.7152, 0.0722])
    relit = dec(np.clip(c * f_keep, 0, None)) @ lum
    w = av.opacities.astype(np.float64)
    assert float(w @ relit) / w.sum() == pytest.approx(float(dec(c)), rel=1e-4)
    assert float(np.median(dec(c * f_abs) @ lum)) < 0.2 * float(dec(c))  # the absolute rule: dark
    # the directions' ratio is the absolute rule's
    r_abs = np.median(dec(c * f_abs[1::2]) @ lum) / np.median(dec(c * f_abs[::2]) @ lum)
    r_keep = np.median(relit[1::2]) / np.median(relit[::2])
    assert r_keep == pytest.approx(r_abs, rel=1e-4) and r_abs > 2.0  # up-facing over down-facing: ceiling, floor


def test_srgb_relighting_is_linear_in_light():
    """Colour 0.5 (display) under a uniform sky of radiance 2: the linear colour doubles, so the
    displayed value is encode(2 decode(0.5)), not 1.0."""
    av, floor = _patch(), _grey_floor()
    floor.opacities[:] = 0.0  # nothing drawn: only the sky
    dome = ShotLight("d", "dome", intensity=2.0, shape="dome")
    f_srgb, _ = _factors(av, floor, [dome], color_space="srgb")
    f_lin, _ = _factors(av, floor, [dome], color_space="linear")
    want = float(srgb_encode(2.0 * srgb_decode(0.5)))
    np.testing.assert_allclose(0.5 * f_srgb, want, rtol=0.01)
    np.testing.assert_allclose(f_lin, 2.0, rtol=0.01)


def test_emitter_gaussians_left_out_of_the_probe(tmp_path):
    """A lamp captured as bright Gaussians and modelled by an authored SphereLight: the main job's
    probe render leaves the lamp's Gaussians out (the probe sees no lamp above), so the lamp is
    counted once, by its direct term (the light scale of the patch facing it is the floor's
    indirect term plus E_lamp / pi)."""
    from usd_gs.cli import main
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    floor = _grey_floor(0.3)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lamp = GaussianSet(np.array([0.0, 2.0, 0.0]) + 0.1 * d, np.tile([1.0, 0, 0, 0], (300, 1)), np.full((300, 3), 0.03),
                       np.full(300, 0.99), np.full((300, 1, 3), (20.0 - 0.5) / sh3dgs.C0, np.float32), label="lamp")
    av = _patch(64, y=1.0)
    stage = new_stage()
    write_gaussian_prim(stage, "/World/Room", GaussianSet.concatenate([floor, lamp], label="room"))
    write_gaussian_prim(stage, "/World/Patch", av)
    light = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    light.AddTranslateOp().Set(Gf.Vec3d(0.0, 2.0, 0.0))
    light.CreateTreatAsPointAttr(True)
    light.CreateIntensityAttr(2.0)
    src = save_stage_atomic(stage, tmp_path / "shot.usda")
    out = tmp_path / "shot.lit.usdc"
    assert main(["process", str(src), "--avatar", "/World/Patch", "--lights", "stage", "--color-space", "linear",
                 "--probe-points", "1", "--aovs", "lightScale", "-o", str(out), "-q"]) == 0
    lit = Usd.Stage.Open(str(out))
    coeffs = np.array(lit.GetPrimAtPath("/UsdGs/Probes/Patch").GetAttribute("usdgs:probe:shCoefficients").Get(
        lit.GetStartTimeCode()))
    up = sh3dgs.eval_basis(np.array([[0.0, 1.0, 0.0]]), 3) @ coeffs
    assert up.max() < 1.0  # the lamp (radiance 20) is not in the probe
    scale = np.array(lit.GetPrimAtPath("/World/Patch").GetAttribute("primvars:usdgs:lightScale").Get(
        lit.GetStartTimeCode()), np.float64)
    # direct: 2 / 1^2 (facing the lamp 1 m above) / pi ~ 0.64; indirect: the floor's 0.3 below is behind the
    # patch, the unobserved sky filled with the observed mean (0.3): ~0.3
    assert np.median(scale) == pytest.approx(2.0 / np.pi + 0.3, rel=0.1)


def test_zh_appearance_through_the_direct_term():
    """A ZH prim whose transfer is a pure cosine lobe about its normal reproduces albedo x E / pi for a
    sun from the normal (the ZH transfer of a delta light), gamma 1, linear."""
    from numba_kernels.zh_transfer import zonal_to_rgca

    av = _patch(16)
    n = av.count
    # clamped cosine / pi about +Z in zonal SH c_l: A_l / pi * Y_l0 normalisation -> ZH on the normal axis
    a_l = np.array([np.pi, 2 * np.pi / 3, np.pi / 4, 0.0])
    y_l0 = np.sqrt((2 * np.arange(4) + 1) / (4 * np.pi))
    zc = np.zeros((n, 3, 4, 3))
    zc[:, 2, :, :] = zonal_to_rgca(a_l / np.pi * y_l0)[None, :, None]
    zm = np.zeros((n, 3, 5))
    zm[:, 2, 0] = zonal_to_rgca(np.array([0, 0, 0, 0, -np.pi / 24 / np.pi * np.sqrt(9 / (4 * np.pi))]))[4]
    app = {"zh_albedo": np.full((n, 3), 0.6, np.float32), "zh_color": zc.astype(np.float32),
           "zh_mono": zm.astype(np.float32)}
    sun = ShotLight("s", "directional", direction=np.array([0.0, -1.0, 0.0]), intensity=2.0, shape="distant")
    floor = _grey_floor()
    floor.opacities[:] = 0.0
    opts = ProcessOptions(probe_points=1, color_space="linear")
    every = GaussianSet.concatenate([floor, av])
    m = np.zeros(every.count, bool)
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    f, _ = relight_factors(av, every, m, av.positions.mean(0), nrm, None, opts, lights=[sun], appearance=app)
    col = 0.5 * f  # captured colour 0.5
    np.testing.assert_allclose(col, 0.6 * 2.0 / np.pi, rtol=0.04)  # ZH truncated at l = 4: -3 %


def test_albedo_primvar_read_and_relit_as_albedo_times_e():
    """``primvars:usdgs:albedo`` is read per particle (a wrong length is a UserError naming it) and a
    prim carrying it is relit as albedo x E / pi, whatever its captured colour."""
    from usd_gs.relight.appearance import ALBEDO, read_appearance

    stage = _stage()
    prim = stage.DefinePrim("/P", "Xform")
    n = 16
    attr = prim.CreateAttribute(ALBEDO, Sdf.ValueTypeNames.Color3fArray)
    attr.Set([Gf.Vec3f(0.2, 0.4, 0.6)] * n)
    app = read_appearance(prim, Usd.TimeCode.Default(), n)
    np.testing.assert_allclose(app["albedo"], np.tile([0.2, 0.4, 0.6], (n, 1)), rtol=1e-6)
    assert read_appearance(stage.DefinePrim("/Q", "Xform"), Usd.TimeCode.Default(), n) is None
    with pytest.raises(UserError, match="primvars:usdgs:albedo"):
        read_appearance(prim, Usd.TimeCode.Default(), n + 1)
    av, floor = _patch(n), _grey_floor()
    floor.opacities[:] = 0.0
    dome = ShotLight("d", "dome", intensity=1.5, shape="dome")
    opts = ProcessOptions(probe_points=1)
    every = GaussianSet.concatenate([floor, av])
    m = np.zeros(every.count, bool)
    f, _ = relight_factors(av, every, m, av.positions.mean(0), np.tile([0.0, 1.0, 0.0], (n, 1)), None, opts,
                           lights=[dome], appearance=app)
    # uniform sky of radiance 1.5: E = 1.5 pi, relit linear = albedo * 1.5, displayed sRGB-encoded
    np.testing.assert_allclose(0.5 * f, np.tile(srgb_encode(np.array([0.2, 0.4, 0.6]) * 1.5), (n, 1)), rtol=0.01)


@pytest.mark.parametrize("space", ["linear", "srgb"])
def test_transfer_terms_computed_ahead_give_the_same_factors(space):
    """``probe_transfer`` (the main job runs it beside the shadow tasks) carries each light's
    unshadowed irradiance and the captured colours in linear units; ``relight_factors`` from it
    gives bit for bit the factors of the same transfer without them (computed after the shadows),
    for a partly shadowed sun, a sphere light and a dome, with and without ``keep_level``; and
    those terms are ``direct_irradiance`` and ``to_linear`` of the prim."""
    from dataclasses import replace

    from usd_gs.colorspace import to_linear
    from usd_gs.relight.avatar import dc_colors, probe_transfer
    from usd_gs.relight.direct import direct_irradiance

    av, floor = _patch(), _grey_floor()
    av.sh[::2, 0] = 0.7  # two colours
    sun = ShotLight("s", "directional", direction=np.array([0.3, -1.0, 0.2]), intensity=3.0, shape="distant")
    lamp = ShotLight("l", "point", position=np.array([0.5, 2.0, 0.0]), intensity=40.0, radius=0.1, shape="sphere")
    dome = ShotLight("d", "dome", intensity=0.8, shape="dome")
    lights = [sun, lamp, dome]
    every = GaussianSet.concatenate([floor, av])
    m = np.ones(every.count, bool)
    m[floor.count:] = False
    nrm = np.tile([0.0, 1.0, 0.0], (av.count, 1))
    opts = ProcessOptions(probe_points=1, color_space=space)
    args = (av, every, m, av.positions.mean(0), nrm, None, opts)
    vis = [np.linspace(0.0, 1.0, av.count), np.full(av.count, 0.25), None]
    pt = probe_transfer(*args, lights=lights)
    assert pt.irradiance[2] is None
    for i in (0, 1):
        assert np.array_equal(pt.irradiance[i], direct_irradiance(lights[i], av.positions, nrm))
    assert np.array_equal(pt.captured_linear, to_linear(dc_colors(av), space))
    bare = replace(pt, irradiance=None, captured_linear=None)
    for keep in (False, True):
        f_ahead, _ = relight_factors(*args, lights=lights, visibility=vis, transfer=pt, keep_level=keep)
        f_after, _ = relight_factors(*args, lights=lights, visibility=vis, transfer=bare, keep_level=keep)
        assert np.array_equal(f_ahead.view(np.uint32), f_after.view(np.uint32))
        assert not np.allclose(f_ahead[0], f_ahead[-1])  # (the sun's visibility varies along the patch)
