"""USD I/O of ParticleField3DGaussianSplat prims: lossless round trips, attribute layout,
float/half rule, time samples, world transforms, every reader error, atomic saves."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from usd_gs.errors import GaussianDataError, InputFormatError, UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import (
    PLY_PREFIX,
    RAW_LOG_SCALES,
    RAW_LOGIT_OPACITIES,
    SH_COEFFS,
    SH_DEGREE,
    describe_gaussian_prim,
    find_gaussian_prims,
    new_stage,
    read_gaussian_prim,
    save_stage_atomic,
    write_gaussian_prim,
)

SPLATS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "splats"


def _bits(a) -> np.ndarray:
    a = np.ascontiguousarray(a)
    return a.view(np.uint32 if a.dtype == np.float32 else np.uint8)


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(_bits(a), _bits(b))


def _with_extras(g: GaussianSet, seed: int = 1) -> GaussianSet:
    rng = np.random.default_rng(seed)
    g.extras = {"nx": rng.standard_normal(g.count).astype(np.float32),
                "label": rng.integers(-300, 300, g.count).astype(np.int16),
                "red": rng.integers(0, 256, g.count).astype(np.uint8)}
    return GaussianSet(g.positions, g.orientations, g.scales, g.opacities, g.sh, g.log_scales, g.logit_opacities,
                       g.extras, label=g.label)


def _assert_lossless(r: GaussianSet, g: GaussianSet) -> None:
    for name in ("positions", "orientations", "scales", "opacities", "sh", "log_scales", "logit_opacities"):
        assert _same_bits(getattr(r, name), getattr(g, name)), name
    assert sorted(r.extras) == sorted(g.extras)
    for key, arr in g.extras.items():
        assert r.extras[key].dtype == arr.dtype and np.array_equal(r.extras[key], arr), key


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("ext", [".usdc", ".usda", ".usd"])
def test_round_trip_bit_exact_through_files(tmp_path, degree, ext):
    g = _with_extras(random_gaussians(57, degree, seed=degree))
    stage = new_stage(default_prim="World")
    write_gaussian_prim(stage, "/World/Splats", g)
    out = save_stage_atomic(stage, tmp_path / f"s{ext}")
    head = out.read_bytes()[:8]
    assert head == (b"#usda 1." if ext == ".usda" else b"PXR-USDC")
    reopened = Usd.Stage.Open(str(out))
    r = read_gaussian_prim(reopened.GetPrimAtPath("/World/Splats"))
    assert r.label == "/World/Splats"
    assert r.sh_degree == degree
    _assert_lossless(r, g)


def test_attribute_layout_matches_design(tmp_path):
    """Quaternion order, particle-major SH, primvar metadata, degree, extent, custom raw attrs."""
    g = random_gaussians(5, 2, seed=3)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/G", g)
    q = prim.GetAttribute("orientations").Get()
    assert isinstance(q[0], Gf.Quatf)
    for i in range(5):  # Gf.Quatf(w, (x, y, z)) holds GaussianSet's (w, x, y, z)
        assert q[i].GetReal() == g.orientations[i, 0]
        assert tuple(q[i].GetImaginary()) == tuple(g.orientations[i, 1:])
    sh_attr = prim.GetAttribute(SH_COEFFS)
    flat = np.asarray(sh_attr.Get())
    assert flat.shape == (5 * 9, 3)
    assert np.array_equal(flat[3 * 9 + 4], g.sh[3, 4])  # particle 3, coefficient 4
    assert sh_attr.GetMetadata("interpolation") == "vertex"
    assert sh_attr.GetMetadata("elementSize") == 9
    deg = prim.GetAttribute(SH_DEGREE)
    assert deg.Get() == 2 and deg.HasAuthoredValue() and deg.GetVariability() == Sdf.VariabilityUniform
    assert prim.GetTypeName() == "ParticleField3DGaussianSplat"
    assert prim.GetAttribute(RAW_LOG_SCALES).IsCustom()
    assert stage.GetPrimAtPath("/G") and stage.GetPrimAtPath("/G").IsDefined()
    ext = np.asarray(prim.GetAttribute("extent").Get())
    assert np.array_equal(ext, g.extent(3.0))


def test_parents_defined_as_xform():
    stage = new_stage()
    write_gaussian_prim(stage, "/A/B/G", random_gaussians(3, 0))
    assert stage.GetPrimAtPath("/A").GetTypeName() == "Xform"
    assert stage.GetPrimAtPath("/A/B").GetTypeName() == "Xform"


def test_extent_analytic_axis_aligned():
    """Identity orientations: the 3 sigma box is exactly min(p - 3s), max(p + 3s)."""
    p = np.array([[0, 0, 0], [1, 2, 3]], np.float32)
    s = np.array([[0.5, 0.25, 1.0], [0.1, 0.2, 0.3]], np.float32)
    g = GaussianSet(p, np.tile([1, 0, 0, 0], (2, 1)), s, [0.5, 0.5], np.zeros((2, 1, 3)))
    expected = np.array([[-1.5, -0.75, -3.0], [1.5, 2.6, 3.9]], np.float32)  # x max: 0 + 1.5 > 1 + 0.3
    np.testing.assert_allclose(g.extent(), expected, rtol=1e-6)


def test_extent_matches_rotation_matrix_reference():
    g = random_gaussians(2000, 0, seed=9)
    g.orientations[:7] = 0.0  # zero quaternions count as identity
    r = g.rotation_matrices()
    half = 3.0 * np.sqrt(np.einsum("nij,nj->ni", r * r, g.scales.astype(np.float64) ** 2))
    p = g.positions.astype(np.float64)
    expected = np.stack([(p - half).min(axis=0), (p + half).max(axis=0)])
    np.testing.assert_allclose(g.extent(), expected, rtol=1e-6, atol=1e-7)
    e = GaussianSet.empty().extent()
    assert e.shape == (2, 3)


def test_half_precision_write_and_rule():
    g = random_gaussians(40, 1, seed=4)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/H", g, precision="half")
    assert not prim.GetAttribute("positions").HasAuthoredValue()
    assert len(prim.GetAttribute("positionsh").Get()) == 40
    r = read_gaussian_prim(prim)
    for name in ("positions", "scales", "opacities", "sh"):
        ref = getattr(g, name).astype(np.float16).astype(np.float32)
        assert np.array_equal(getattr(r, name), ref), name
    # raw attributes stay float32: the lossless values survive half storage
    assert _same_bits(r.log_scales, g.log_scales)
    assert describe_gaussian_prim(prim).precision == "half"


def test_float_preferred_unless_empty_at_earliest_time():
    g = random_gaussians(6, 0, seed=5)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/F", g, keep_raw=False)
    half_pos = (g.positions + 100).astype(np.float16)
    prim.CreateAttribute("positionsh", Sdf.ValueTypeNames.Point3hArray).Set(Vt.Vec3hArray.FromNumpy(half_pos))
    assert np.array_equal(read_gaussian_prim(prim).positions, g.positions)  # float wins
    prim.GetAttribute("positions").Set(Vt.Vec3fArray())  # empty float array -> half is used
    assert np.array_equal(read_gaussian_prim(prim).positions, half_pos.astype(np.float32))
    assert describe_gaussian_prim(prim).precision == "half"


def test_old_tool_prim_from_text_without_api_schemas(tmp_path):
    text = """#usda 1.0
def ParticleField3DGaussianSplat "Old"
{
    point3f[] positions = [(1, 2, 3), (4, 5, 6)]
    quatf[] orientations = [(1, 0, 0, 0), (0, 0, 1, 0)]
    float3[] scales = [(0.1, 0.2, 0.3), (1, 1, 1)]
    float[] opacities = [0.25, 1]
    uniform int radiance:sphericalHarmonicsDegree = 0
    float3[] radiance:sphericalHarmonicsCoefficients = [(0.5, 0.25, 0), (1, 1, 1)]
}
"""
    path = tmp_path / "old.usda"
    path.write_text(text)
    stage = Usd.Stage.Open(str(path))
    (prim,) = find_gaussian_prims(stage)
    r = read_gaussian_prim(prim)
    np.testing.assert_array_equal(r.positions, [[1, 2, 3], [4, 5, 6]])
    # Gf.Quatf text (0, 0, 1, 0) is w=0, (x, y, z) = (0, 1, 0): a 180 degree turn about y
    np.testing.assert_array_equal(r.orientations, [[1, 0, 0, 0], [0, 0, 1, 0]])
    np.testing.assert_array_equal(r.sh[:, 0], [[0.5, 0.25, 0], [1, 1, 1]])
    assert r.log_scales is None and r.extras == {}


def test_missing_degree_uses_fallback_three_and_missing_opacities_are_one():
    g = random_gaussians(4, 3, seed=6)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/D", g, keep_raw=False)
    prim.GetAttribute(SH_DEGREE).Clear()
    prim.GetAttribute("opacities").Clear()
    r = read_gaussian_prim(prim)
    assert r.sh_degree == 3
    np.testing.assert_array_equal(r.opacities, np.ones(4, np.float32))


def test_find_gaussian_prims_sorted_active_concrete():
    stage = new_stage()
    for p in ("/Z/G", "/A/G2", "/A/G1", "/Off"):
        write_gaussian_prim(stage, p, random_gaussians(2, 0))
    stage.GetPrimAtPath("/Off").SetActive(False)
    cls = stage.CreateClassPrim("/_class")
    cls.SetTypeName("ParticleField3DGaussianSplat")
    stage.DefinePrim("/Mesh", "Mesh")
    assert [str(p.GetPath()) for p in find_gaussian_prims(stage)] == ["/A/G1", "/A/G2", "/Z/G"]


# ----------------------------------------------------------------------------- time samples
def test_time_samples_and_uniform_topology():
    g1 = random_gaussians(8, 1, seed=1)
    g2 = random_gaussians(8, 1, seed=2)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/Anim", g1, time=1)
    write_gaussian_prim(stage, "/Anim", g2, time=2)
    assert prim.GetAttribute("positions").GetTimeSamples() == [1.0, 2.0]
    assert prim.GetAttribute("extent").GetTimeSamples() == [1.0, 2.0]
    assert prim.GetAttribute(RAW_LOG_SCALES).GetTimeSamples() == [1.0, 2.0]
    assert prim.GetAttribute(SH_DEGREE).GetTimeSamples() == []
    _assert_lossless(read_gaussian_prim(prim, time=1), g1)
    _assert_lossless(read_gaussian_prim(prim, time=Usd.TimeCode(2)), g2)
    info = describe_gaussian_prim(prim, time=2)
    assert info.time_samples == (1.0, 2.0) and info.animated and info.count == 8 and info.sh_degree == 1
    lo, hi = info.world_bounds
    np.testing.assert_allclose(np.stack([lo, hi]), g2.extent(), rtol=1e-6)


def test_degree_cannot_change_over_time():
    stage = new_stage()
    write_gaussian_prim(stage, "/A", random_gaussians(3, 1), time=1)
    with pytest.raises(UserError, match=r"/A.*radiance:sphericalHarmonicsDegree.*1.*degree 2"):
        write_gaussian_prim(stage, "/A", random_gaussians(3, 2), time=2)


def test_describe_static_and_xform_animated():
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/Root/G", random_gaussians(10, 0))
    info = describe_gaussian_prim(prim)
    assert info.time_samples is None and not info.animated and info.role.role == "auto"
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/Root")).AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 0)
    op.Set(Gf.Vec3d(10, 0, 0), 24)
    info = describe_gaussian_prim(prim, time=24)
    assert info.animated and info.time_samples == (0.0, 24.0)
    lo, hi = info.world_bounds
    lo0, hi0 = describe_gaussian_prim(prim, time=0).world_bounds
    np.testing.assert_allclose(lo - lo0, [10, 0, 0], atol=1e-5)
    np.testing.assert_allclose(hi - hi0, [10, 0, 0], atol=1e-5)


# ----------------------------------------------------------------------------- world space
def _similarity(angle_deg=30.0, axis=(1, 2, 3), scale=2.0, t=(1, -2, 0.5)) -> np.ndarray:
    m = Gf.Matrix4d().SetScale(scale) * Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(*axis), angle_deg))
    m.SetTranslateOnly(Gf.Vec3d(*t))
    return np.array(m)


def test_world_transform_applied():
    g = random_gaussians(30, 2, seed=7)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/X/G", g)
    m = _similarity()
    UsdGeom.Xformable(stage.GetPrimAtPath("/X")).AddTransformOp().Set(Gf.Matrix4d(m.tolist()))
    w = read_gaussian_prim(prim)
    hom = np.concatenate([g.positions.astype(np.float64), np.ones((30, 1))], axis=1) @ m
    np.testing.assert_allclose(w.positions, hom[:, :3], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(w.scales, g.scales * 2.0, rtol=1e-6)
    np.testing.assert_allclose(w.log_scales, g.log_scales + np.log(2.0), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(w.covariances(), np.einsum("ij,njk,lk->nil", m[:3, :3].T, g.covariances(),
                                                          m[:3, :3].T), rtol=1e-4, atol=1e-9)
    loc = read_gaussian_prim(prim, world=False)
    _assert_lossless(loc, g)


def test_non_similarity_transform_rejected():
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/X/G", random_gaussians(3, 0))
    UsdGeom.Xformable(stage.GetPrimAtPath("/X")).AddScaleOp().Set(Gf.Vec3f(1, 2, 1))
    with pytest.raises(GaussianDataError, match=r"/X/G.*non-uniform scale"):
        read_gaussian_prim(prim)
    assert read_gaussian_prim(prim, world=False).count == 3


# ----------------------------------------------------------------------------- reader errors
_KEEP = []  # stages must outlive their prims


def _prim(n=6, degree=1):
    stage = new_stage()
    _KEEP.append(stage)
    return write_gaussian_prim(stage, "/E", random_gaussians(n, degree, seed=11), keep_raw=False)


def test_error_length_mismatch_names_attribute_and_lengths():
    prim = _prim()
    prim.GetAttribute("scales").Set(Vt.Vec3fArray.FromNumpy(np.ones((5, 3), np.float32)))
    with pytest.raises(GaussianDataError, match=r"/E: attribute 'scales' has 5 elements but 'positions' has 6"):
        read_gaussian_prim(prim)


def test_error_sh_count_disagrees_with_degree():
    prim = _prim(degree=1)
    prim.GetAttribute(SH_DEGREE).Set(2)
    prim.GetAttribute(SH_COEFFS).ClearMetadata("elementSize")
    with pytest.raises(GaussianDataError, match=r"'radiance:sphericalHarmonicsCoefficients' has 24 elements but "
                                                r"6 particles with .* 2 need 6 \* 9 = 54"):
        read_gaussian_prim(prim)


def test_error_element_size_disagrees_with_degree():
    prim = _prim(degree=1)
    prim.GetAttribute(SH_COEFFS).SetMetadata("elementSize", 3)
    with pytest.raises(GaussianDataError, match=r"/E: attribute '.*Coefficients' has elementSize 3 .* = 4"):
        read_gaussian_prim(prim)


def test_error_degree_out_of_range():
    prim = _prim()
    prim.GetAttribute(SH_DEGREE).Set(4)
    with pytest.raises(GaussianDataError, match=r"sphericalHarmonicsDegree' is 4"):
        read_gaussian_prim(prim)


@pytest.mark.parametrize("name,index,value", [("positions", 3, np.nan), ("opacities", 0, np.inf),
                                              ("orientations", 5, -np.inf)])
def test_error_non_finite_names_first_bad_element(name, index, value):
    prim = _prim()
    arr = np.array(np.asarray(prim.GetAttribute(name).Get()))
    arr[index] = value
    if index + 1 < len(arr):
        arr[index + 1] = value
    prim.GetAttribute(name).Set(type(prim.GetAttribute(name).Get()).FromNumpy(arr))
    with pytest.raises(GaussianDataError, match=rf"/E: attribute '{name}' element {index} is not finite"):
        read_gaussian_prim(prim)


def test_deferred_finite_checks_are_made_by_check_deferred_and_not_for_a_transformed_prim():
    """``read_gaussian_prim(defer_finite=[...])`` leaves a prim's finite checks to the caller where its
    values are used as authored: no error at the read, ``check_deferred`` raises the read's own
    named error; a prim with a transform checks them at the read as before (its world values are
    computed from them)."""
    from pxr import Gf, UsdGeom

    from usd_gs.usd.gaussian_prim import check_deferred

    prim = _prim()
    arr = np.array(np.asarray(prim.GetAttribute("scales").Get()))
    arr[4] = np.nan
    prim.GetAttribute("scales").Set(Vt.Vec3fArray.FromNumpy(arr))
    with pytest.raises(GaussianDataError) as plain:
        read_gaussian_prim(prim)
    deferred = []
    g = read_gaussian_prim(prim, defer_finite=deferred)
    assert np.isnan(g.scales[4]).all() and len(deferred) == 1
    with pytest.raises(GaussianDataError) as later:
        check_deferred(deferred)
    assert str(later.value) == str(plain.value) and "'scales' element 4 is not finite" in str(plain.value)
    check_deferred([])  # (nothing left: no error)
    UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(1.0, 0.0, 0.0))
    deferred.clear()
    with pytest.raises(GaussianDataError, match="'scales' element 4 is not finite"):
        read_gaussian_prim(prim, defer_finite=deferred)
    assert deferred == []


def test_error_sh_nan_reports_flat_element():
    prim = _prim(degree=1)
    arr = np.array(np.asarray(prim.GetAttribute(SH_COEFFS).Get()))
    arr[9, 2] = np.nan
    prim.GetAttribute(SH_COEFFS).Set(Vt.Vec3fArray.FromNumpy(arr))
    with pytest.raises(GaussianDataError, match=r"Coefficients' element 9 is not finite"):
        read_gaussian_prim(prim)


def test_error_missing_attributes_and_wrong_type():
    prim = _prim()
    prim.GetAttribute("orientations").Clear()
    with pytest.raises(InputFormatError, match=r"/E: attribute 'orientations' \(or 'orientationsh'\) has no value"):
        read_gaussian_prim(prim)
    prim.GetAttribute("positions").Clear()
    with pytest.raises(InputFormatError, match=r"'positions'.*has no value"):
        read_gaussian_prim(prim)
    mesh = prim.GetStage().DefinePrim("/M", "Mesh")
    with pytest.raises(InputFormatError, match=r"/M: prim type 'Mesh'"):
        read_gaussian_prim(mesh)


def test_error_time_mentioned_in_message():
    stage = new_stage()
    g = random_gaussians(4, 0)
    prim = write_gaussian_prim(stage, "/T", g, time=5)
    prim.GetAttribute("scales").Set(Vt.Vec3fArray.FromNumpy(np.ones((3, 3), np.float32)), 5)
    with pytest.raises(GaussianDataError, match=r"/T \(time 5\): attribute 'scales' has 3 elements"):
        read_gaussian_prim(prim, time=5)


def test_stale_raw_attributes_are_dropped_with_warning():
    g = random_gaussians(10, 0, seed=2)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/R", g)
    new_scales = (g.scales * 2).astype(np.float32)  # another tool edited scales only
    prim.GetAttribute("scales").Set(Vt.Vec3fArray.FromNumpy(new_scales))
    with pytest.warns(UserWarning, match=r"/R: 'usdgs:rawLogScales' does not match"):
        r = read_gaussian_prim(prim)
    assert r.log_scales is None
    assert _same_bits(r.logit_opacities, g.logit_opacities)
    prim.GetAttribute("scales").Set(Vt.Vec3fArray.FromNumpy(g.scales))
    prim.GetAttribute(RAW_LOGIT_OPACITIES).Set(Vt.FloatArray.FromNumpy(np.zeros(3, np.float32)))
    with pytest.warns(UserWarning, match=r"rawLogitOpacities' has shape \(3,\)"):
        assert read_gaussian_prim(prim).logit_opacities is None


# ----------------------------------------------------------------------------- writer errors
def test_writer_rejects_bad_input():
    stage = new_stage()
    g = random_gaussians(3, 0)
    with pytest.raises(UserError, match="precision"):
        write_gaussian_prim(stage, "/A", g, precision="double")
    bad = random_gaussians(3, 0)
    bad.positions[1, 2] = np.nan
    with pytest.raises(GaussianDataError, match=r"/A: cannot write Gaussians: attribute 'positions' element 1"):
        write_gaussian_prim(stage, "/A", bad)
    stage.DefinePrim("/Mesh", "Mesh")
    with pytest.raises(UserError, match=r"/Mesh: a prim of type 'Mesh' exists"):
        write_gaussian_prim(stage, "/Mesh", g)
    g.extras = {"bad name": np.zeros(3, np.float32)}
    with pytest.raises(UserError, match="'bad name' is not a valid USD attribute name"):
        write_gaussian_prim(stage, "/B", g)
    write_gaussian_prim(stage, "/C", random_gaussians(3, 0))
    with pytest.raises(UserError, match=r"/C: attribute 'positions' has float values"):
        write_gaussian_prim(stage, "/C", random_gaussians(3, 0), precision="half")


def test_no_raw_when_keep_raw_false():
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/N", _with_extras(random_gaussians(4, 0)), keep_raw=False)
    assert not prim.GetAttribute(RAW_LOG_SCALES)
    assert not [a for a in prim.GetAttributes() if a.GetName().startswith(PLY_PREFIX)]


# ----------------------------------------------------------------------------- stages and saving
def test_new_stage_metadata():
    stage = new_stage(up_axis="Z", meters_per_unit=0.01, default_prim="World")
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert stage.GetRootLayer().defaultPrim == "World"
    assert stage.GetRootLayer().anonymous
    with pytest.raises(UserError, match="up axis"):
        new_stage(up_axis="X")
    with pytest.raises(UserError, match=r"\.usd, \.usdc or \.usda"):
        new_stage("out.ply")


def test_save_atomic_failure_leaves_nothing_and_keeps_existing(tmp_path):
    stage = new_stage()
    write_gaussian_prim(stage, "/G", random_gaussians(5, 0))
    out = tmp_path / "out.usdc"

    def failing_export(layer, tmp, args):
        Path(tmp).write_bytes(b"PXR-USDC partial")  # half-written temp file, then a crash
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        save_stage_atomic(stage, out, _export=failing_export)
    assert os.listdir(tmp_path) == []
    save_stage_atomic(stage, out, durable=True)
    before = out.read_bytes()
    with pytest.raises(RuntimeError):
        save_stage_atomic(new_stage(), out, _export=failing_export)
    assert out.read_bytes() == before and os.listdir(tmp_path) == ["out.usdc"]
    reopened = Usd.Stage.Open(str(out))
    assert read_gaussian_prim(reopened.GetPrimAtPath("/G")).count == 5


def test_save_requires_existing_directory(tmp_path):
    with pytest.raises(UserError, match="does not exist"):
        save_stage_atomic(new_stage(), tmp_path / "missing" / "x.usda")


# ----------------------------------------------------------------------------- real capture
def test_biker_ply_usd_ply_round_trip_bit_exact(tmp_path):
    import plyfile

    from usd_gs.io.ply import read_ply, write_ply

    src = SPLATS / "biker.ply"
    g = read_ply(src)
    stage = new_stage(default_prim="biker")
    write_gaussian_prim(stage, "/biker", g)
    usd = save_stage_atomic(stage, tmp_path / "biker.usdc")
    reopened = Usd.Stage.Open(str(usd))
    r = read_gaussian_prim(reopened.GetPrimAtPath("/biker"))
    out = tmp_path / "back.ply"
    write_ply(out, r)
    a = plyfile.PlyData.read(str(src))["vertex"].data
    b = plyfile.PlyData.read(str(out))["vertex"].data
    assert len(a) == len(b) == 152746
    for name in a.dtype.names:
        if name.startswith("rot_"):
            continue
        assert name in b.dtype.names, name
        assert _same_bits(np.ascontiguousarray(a[name]), np.ascontiguousarray(b[name])), name
    qa = np.stack([a[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qb = np.stack([b[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qa /= np.linalg.norm(qa, axis=1, keepdims=True)
    qb /= np.linalg.norm(qb, axis=1, keepdims=True)
    np.testing.assert_allclose(qb, qa, rtol=0, atol=1e-7)


def test_no_warnings_on_clean_round_trip():
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/G", random_gaussians(20, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_gaussian_prim(prim)


def test_empty_set_and_multi_column_extras_round_trip():
    stage = new_stage()
    empty = write_gaussian_prim(stage, "/Empty", GaussianSet.empty(2))
    r = read_gaussian_prim(empty)
    assert r.count == 0 and r.sh.shape == (0, 9, 3)
    assert describe_gaussian_prim(empty).world_bounds is None
    g = random_gaussians(7, 0, seed=8)
    feat = np.arange(14, dtype=np.float64).reshape(7, 2) / 3.0
    g = GaussianSet(g.positions, g.orientations, g.scales, g.opacities, g.sh, g.log_scales, g.logit_opacities,
                    {"feat": feat})
    prim = write_gaussian_prim(stage, "/Feat", g)
    assert len(prim.GetAttribute(PLY_PREFIX + "feat").Get()) == 14
    back = read_gaussian_prim(prim).extras["feat"]
    assert back.shape == (7, 2) and back.dtype == np.float64 and np.array_equal(back, feat)


def test_describe_reports_applied_role():
    from usd_gs.usd.schema import apply_role

    stage = new_stage()
    prim = write_gaussian_prim(stage, "/Av", random_gaussians(3, 0))
    apply_role(prim, "avatar", relight=False)
    role = describe_gaussian_prim(prim).role
    assert (role.role, role.relight, role.applied) == ("avatar", False, True)


def test_raw_values_at_float32_limits_are_kept():
    """Saturated logits (+-inf, +-100) and log-scales below the float32 range (ply_io clamps
    exp to the smallest normal float32) are consistent raw data and survive the round trip."""
    tiny = np.finfo(np.float32).tiny
    log_s = np.array([[-200.0, -1.0, 0.0], [0.5, -3.0, -95.0]], np.float32)
    logit = np.array([np.inf, -100.0], np.float32)
    g = GaussianSet(np.zeros((2, 3)), np.tile([1, 0, 0, 0], (2, 1)), np.maximum(np.exp(log_s.astype(np.float64)), tiny),
                    [1.0, 0.0], np.zeros((2, 1, 3)), log_s, logit)
    stage = new_stage()
    prim = write_gaussian_prim(stage, "/L", g)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = read_gaussian_prim(prim)
    assert _same_bits(r.log_scales, log_s) and _same_bits(r.logit_opacities, logit)
