"""validate_stage: one generated stage per rule violation, each reporting the exact
attribute and first bad element; conformant stages (float, half, animated) give none."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import SH_COEFFS, SH_DEGREE, new_stage, write_gaussian_prim
from usd_gs.usd.validate import Problem, validate_prim, validate_stage

N, DEG, K = 12, 1, 4
PATH = "/World/G"


def _stage(precision="float"):
    stage = new_stage()
    write_gaussian_prim(stage, PATH, random_gaussians(N, DEG, seed=5), precision=precision)
    return stage, stage.GetPrimAtPath(PATH)


def _set(prim, name, fn, time=None):
    """Replace attribute ``name`` by ``fn(copy of its numpy value)``."""
    attr = prim.GetAttribute(name)
    value = attr.Get() if time is None else attr.Get(time)
    arr = fn(np.array(np.asarray(value)))
    new = type(value).FromNumpy(np.ascontiguousarray(arr))
    attr.Set(new) if time is None else attr.Set(new, time)


def _only(problems: list[Problem]) -> Problem:
    assert len(problems) == 1, [str(p) for p in problems]
    assert problems[0].prim_path == PATH
    return problems[0]


@pytest.mark.parametrize("precision", ["float", "half"])
def test_conformant_stage_has_no_problems(precision):
    stage, _ = _stage(precision)
    assert validate_stage(stage) == []


def test_conformant_animated_stage_has_no_problems():
    stage = new_stage()
    for t in (1, 2, 3):
        write_gaussian_prim(stage, PATH, random_gaussians(N, DEG, seed=t), time=t)
    assert validate_stage(stage) == []


@pytest.mark.parametrize("name", ["positions", "orientations", "scales", "opacities", SH_COEFFS, "extent"])
def test_missing_attribute(name):
    stage, prim = _stage()
    prim.GetAttribute(name).Clear()
    problems = validate_stage(stage)
    p = problems[0]
    assert (p.attribute, p.element) == (name, None) and "has no value" in p.message
    if name != "positions":  # without positions the extent containment cannot be checked either
        assert len(problems) == 1


def test_degree_not_authored():
    stage, prim = _stage()
    prim.GetAttribute(SH_DEGREE).Clear()
    problems = validate_stage(stage)
    assert problems[0].attribute == SH_DEGREE and "not authored" in problems[0].message
    # the fallback (3) then disagrees with elementSize and the coefficient count
    assert {p.attribute for p in problems[1:]} == {SH_COEFFS}


@pytest.mark.parametrize("name,delta", [("scales", -1), ("orientations", 1), ("opacities", -3)])
def test_length_mismatch(name, delta):
    stage, prim = _stage()
    _set(prim, name, lambda a: np.concatenate([a, a[:delta]]) if delta > 0 else a[:delta])
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == (name, None)
    assert p.message == f"has {N + delta} elements but 'positions' has {N}"


def test_sh_length_mismatch():
    stage, prim = _stage()
    _set(prim, SH_COEFFS, lambda a: a[:-2])
    p = _only(validate_stage(stage))
    assert p.attribute == SH_COEFFS and f"has {N * K - 2} elements" in p.message and f"= {N * K}" in p.message


def test_opacity_out_of_range_first_element():
    stage, prim = _stage()

    def bad(a):
        a[7] = 1.5
        a[9] = -0.1
        return a
    _set(prim, "opacities", bad)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("opacities", 7)
    assert "1.5 is outside [0, 1] (2 bad elements)" in p.message


@pytest.mark.parametrize("value", [0.0, -0.01])
def test_scale_not_positive(value):
    stage, prim = _stage()

    def bad(a):
        a[4, 1] = value
        return a
    _set(prim, "scales", bad)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("scales", 4) and "is not > 0" in p.message


def test_quaternion_not_unit():
    stage, prim = _stage()

    def bad(a):
        a[6] *= 1.0 + 2e-3  # |q| = 1.002: outside 1 +/- 1e-3
        a[8] *= 1.0 + 5e-4  # inside the tolerance: fine
        return a
    _set(prim, "orientations", bad)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("orientations", 6) and "|q| = 1.002" in p.message


def test_degree_out_of_range():
    stage, prim = _stage()
    prim.GetAttribute(SH_DEGREE).Set(4)
    p = _only(validate_stage(stage))
    assert p.attribute == SH_DEGREE and p.message == "is 4, not in 0..3"


def test_interpolation_not_vertex():
    stage, prim = _stage()
    prim.GetAttribute(SH_COEFFS).SetMetadata("interpolation", "constant")
    p = _only(validate_stage(stage))
    assert p.attribute == SH_COEFFS and "interpolation is 'constant'" in p.message
    prim.GetAttribute(SH_COEFFS).ClearMetadata("interpolation")
    assert "interpolation is not authored" in _only(validate_stage(stage)).message


def test_element_size_wrong():
    stage, prim = _stage()
    prim.GetAttribute(SH_COEFFS).SetMetadata("elementSize", 9)
    p = _only(validate_stage(stage))
    assert p.attribute == SH_COEFFS and p.message == "elementSize is 9, must be (d+1)^2 = 4 for degree 1"


@pytest.mark.parametrize("name,index,value", [("positions", 3, np.nan), ("scales", 10, np.inf),
                                              ("orientations", 0, -np.inf), ("opacities", 11, np.nan),
                                              (SH_COEFFS, 5 * K + 2, np.nan), ("extent", 1, np.inf)])
def test_non_finite_first_element(name, index, value):
    stage, prim = _stage()

    def bad(a):
        a[index] = value
        return a
    _set(prim, name, bad)
    problems = validate_stage(stage)
    finite = [p for p in problems if "not finite" in p.message]
    assert len(finite) == 1 and (finite[0].attribute, finite[0].element) == (name, index)
    # nothing else is reported for the same attribute (range checks skip non-finite values)
    assert [p for p in problems if p.attribute == name] == finite


def test_raw_attribute_non_finite():
    stage, prim = _stage()

    def bad(a):
        a[2] = np.nan
        return a
    _set(prim, "usdgs:rawLogitOpacities", bad)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("usdgs:rawLogitOpacities", 2) and p.message.startswith("is NaN")

    def saturated(a):  # +-inf logits are valid raw PLY data (sigmoid 1 / 0)
        a[2] = np.inf
        return a
    _set(prim, "usdgs:rawLogitOpacities", saturated)
    assert validate_stage(stage) == []


def test_extent_not_containing_positions():
    stage, prim = _stage()
    pos = np.asarray(prim.GetAttribute("positions").Get())
    i = int(np.argmax(pos[:, 0]))
    _set(prim, "extent", lambda e: np.array([e[0], [pos[i, 0] - 0.01, e[1, 1], e[1, 2]]], np.float32))
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("extent", i) and "does not contain position" in p.message


def test_non_similarity_transform_names_culprit():
    stage, _ = _stage()
    UsdGeom.Xformable(stage.GetPrimAtPath("/World")).AddScaleOp().Set(Gf.Vec3f(1, 1, 3))
    p = _only(validate_stage(stage))
    assert p.attribute == "xformOpOrder" and "non-uniform scale" in p.message and "/World)" in p.message


def test_non_finite_transform():
    stage, prim = _stage()
    UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(0, float("nan"), 0))
    p = _only(validate_stage(stage))
    assert p.attribute == "xformOpOrder" and "is not finite" in p.message


def test_every_time_sample_checked_and_reported_once():
    stage = new_stage()
    for t in (1, 2, 3):
        write_gaussian_prim(stage, PATH, random_gaussians(N, DEG, seed=t), time=t)
    prim = stage.GetPrimAtPath(PATH)
    for t in (2, 3):
        def bad(a):
            a[7] = 2.0
            return a
        _set(prim, "opacities", bad, time=t)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element, p.time) == ("opacities", 7, 2.0)
    assert validate_prim(prim, time=1) == []
    assert _only(validate_prim(prim, time=3)).time == 3.0


def test_animated_transform_checked_at_its_samples():
    stage, _ = _stage()
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/World")).AddScaleOp()
    op.Set(Gf.Vec3f(1, 1, 1), 0)
    op.Set(Gf.Vec3f(1, 1, 1), 10)
    op.Set(Gf.Vec3f(2, 1, 1), 20)
    p = _only(validate_stage(stage))
    assert p.attribute == "xformOpOrder" and p.time == 20.0


def test_half_attributes_named_in_problems():
    stage, prim = _stage("half")

    def bad(a):
        a[3] = -1
        return a
    _set(prim, "opacitiesh", bad)
    p = _only(validate_stage(stage))
    assert (p.attribute, p.element) == ("opacitiesh", 3)


def test_problem_str():
    p = Problem("/A", "scales", "is not > 0", 4, 2.0)
    assert str(p) == "/A.scales element 4 at time 2: is not > 0"


def test_only_gaussian_prims_checked():
    stage = Usd.Stage.CreateInMemory()
    stage.DefinePrim("/Mesh", "Mesh")
    stage.DefinePrim("/Empty", "ParticleField3DGaussianSplat").CreateAttribute(
        "positions", Sdf.ValueTypeNames.Point3fArray).Set(Vt.Vec3fArray(2))
    problems = validate_stage(stage)
    assert {p.prim_path for p in problems} == {"/Empty"}
    assert {p.attribute for p in problems} >= {"orientations", "scales", SH_COEFFS, SH_DEGREE, "extent"}


def test_a_referenced_splat_typed_xform_is_named(tmp_path, capsys):
    """``def Xform "Seal" (references = @splat@)`` types the splat prim as an Xform: validate names it
    (exit 1), process says why there is nothing to process (exit 2) and warns when others remain."""
    from usd_gs.cli import main
    from usd_gs.usd.gaussian_prim import retyped_gaussian_prims, save_stage_atomic

    splat = new_stage()
    write_gaussian_prim(splat, "/World/G", random_gaussians(N, DEG, seed=5))
    save_stage_atomic(splat, tmp_path / "splat.usdc")
    shot = tmp_path / "shot.usda"
    shot.write_text('#usda 1.0\n(\n    startTimeCode = 1\n    endTimeCode = 2\n)\ndef Xform "World"\n{\n'
                    '    def Xform "Seal" (prepend references = @splat.usdc@</World/G>) {}\n'
                    '    def "Ok" (prepend references = @splat.usdc@</World/G>) {}\n}\n')
    stage = Usd.Stage.Open(str(shot))
    assert retyped_gaussian_prims(stage) == [("/World/Seal", "Xform")]
    problems = validate_stage(stage)
    assert [(p.prim_path, p.attribute) for p in problems] == [("/World/Seal", "typeName")]
    assert "typed Xform by a stronger opinion" in problems[0].message
    assert main(["validate", str(shot)]) == 1
    assert "/World/Seal.typeName: " in capsys.readouterr().out
    assert main(["inspect", str(shot)]) == 0
    assert "warning: /World/Seal: a ParticleField3DGaussianSplat prim typed Xform" in capsys.readouterr().out
    assert main(["process", str(shot), "-o", str(tmp_path / "out.usdc"), "--frames", "1", "--json"]) == 0
    import json

    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert any(w.startswith("/World/Seal: a ParticleField3DGaussianSplat prim typed Xform") for w in warnings)
    none = tmp_path / "none.usda"  # (a new file: the first is in USD's layer registry)
    none.write_text(shot.read_text().replace('def "Ok"', 'def Scope "Ok"'))
    assert main(["process", str(none), "-o", str(tmp_path / "out2.usdc"), "--frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "no ParticleField3DGaussianSplat prims to process (/World/Ok: " in err and "1 more such prim(s)" in err
