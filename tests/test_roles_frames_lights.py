"""Role resolution, --frames parsing and UsdLux light reading/writing."""

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdLux

from usd_gs.errors import UserError
from usd_gs.usd.frames import parse_frames
from usd_gs.usd.gaussian_prim import GaussianPrimInfo
from usd_gs.usd.lux import ShotLight, read_stage_lights, write_estimated_lights
from usd_gs.usd.roles import resolve_roles
from usd_gs.usd.schema import RoleInfo


def info(path, animated=False, role="auto"):
    return GaussianPrimInfo(path, 10, 0, "float", None, animated, RoleInfo(role=role), None)


def test_roles_schema_then_flags_then_auto():
    infos = [info("/W/Room"), info("/W/CesiumMan", True), info("/W/Ball", True), info("/W/Prop", True, "scene"),
             info("/W/Static")]
    roles, warnings = resolve_roles(infos, object_paths=["/W/Static"], avatar_paths=["/W/Prop"])
    got = {r.path: (r.role, r.source) for r in roles}
    assert got == {"/W/Room": ("scene", "auto"), "/W/CesiumMan": ("avatar", "auto"), "/W/Ball": ("object", "auto"),
                   "/W/Prop": ("scene", "schema"), "/W/Static": ("object", "flag")}
    assert len(warnings) == 1 and "/W/Prop" in warnings[0] and "--avatar ignored" in warnings[0]


def test_roles_flag_errors():
    infos = [info("/W/A"), info("/W/B")]
    with pytest.raises(UserError, match="--avatar /W/Nope: not a ParticleField3DGaussianSplat prim"):
        resolve_roles(infos, avatar_paths=["/W/Nope"])
    with pytest.raises(UserError, match="given both as --scene and --object"):
        resolve_roles(infos, scene_paths=["/W/A"], object_paths=["/W/A"])


@pytest.mark.parametrize("spec, expected", [
    (None, [1.0, 2.0, 3.0, 4.0]),
    ("2-3", [2.0, 3.0]),
    ("1:10:4", [1.0, 5.0, 9.0]),
    ("-2:0", [-2.0, -1.0, 0.0]),
    ("7", [7.0]),
    ("1-2,2,10:12:2", [1.0, 2.0, 10.0, 12.0]),
    ("1.5:2.5:0.5", [1.5, 2.0, 2.5]),
])
def test_parse_frames(spec, expected):
    assert parse_frames(spec, 1, 4) == expected


@pytest.mark.parametrize("spec, msg", [("5-1", "before start"), ("a-b", "not a number"), ("1:5:0", "step must be > 0"),
                                       ("1:2:3:4", "A:B or A:B:STEP"), ("1,,2", "empty item"),
                                       ("0:1e7", "more than")])
def test_parse_frames_errors(spec, msg):
    with pytest.raises(UserError, match=msg):
        parse_frames(spec, 1, 4)


def test_read_stage_lights_world_space_and_kinds():
    stage = Usd.Stage.CreateInMemory()
    xf = UsdGeom.Xform.Define(stage, "/Rig")
    xf.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    s = UsdLux.SphereLight.Define(stage, "/Rig/Key")
    s.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
    s.CreateIntensityAttr(10.0)
    s.CreateExposureAttr(1.0)
    s.CreateColorAttr(Gf.Vec3f(1, 0.5, 0.25))
    s.CreateRadiusAttr(0.2)
    d = UsdLux.DistantLight.Define(stage, "/Sun")
    d.AddRotateXOp().Set(-90.0)  # local -Z turned to point down (-Y)
    r = UsdLux.RectLight.Define(stage, "/Panel")
    r.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    UsdLux.DomeLight.Define(stage, "/Env")
    lights, warnings = read_stage_lights(stage, Usd.TimeCode.Default())
    by = {lt.name: lt for lt in lights}
    np.testing.assert_allclose(by["/Rig/Key"].position, [1, 3, 3])
    assert by["/Rig/Key"].intensity == pytest.approx(20.0) and by["/Rig/Key"].radius == pytest.approx(0.2)
    np.testing.assert_allclose(by["/Rig/Key"].color, [1, 0.5, 0.25])
    assert by["/Sun"].kind == "directional"
    np.testing.assert_allclose(by["/Sun"].direction, [0, -1, 0], atol=1e-12)
    assert by["/Panel"].kind == "point" and any("RectLight is approximated" in w for w in warnings)
    assert "/Env" not in by and any("/Env" in w for w in warnings)


def test_write_estimated_lights_round_trip():
    stage = Usd.Stage.CreateInMemory()
    est = [ShotLight("a", "point", np.array([1.0, 2.0, 3.0]), color=np.array([1.0, 0.9, 0.8]), intensity=3.0,
                     score=0.75)]
    paths = write_estimated_lights(stage, est)
    assert paths == ["/UsdGs/Lights/Light_0"]
    prim = stage.GetPrimAtPath(paths[0])
    assert prim.GetCustomDataByKey("usdgs:score") == pytest.approx(0.75)
    back, _ = read_stage_lights(stage, Usd.TimeCode.Default())
    np.testing.assert_allclose(back[0].position, [1, 2, 3])
    assert back[0].intensity == pytest.approx(3.0)
    np.testing.assert_allclose(back[0].color, [1.0, 0.9, 0.8], rtol=1e-6)


def test_role_table_groups_bricks():
    from usd_gs.usd.roles import role_table

    infos = [info(f"/W/Room/Brick_{i:04d}") for i in range(5)] + [info("/W/Man", True)]
    roles, _ = resolve_roles(infos)
    table = role_table(roles, {r.path: 10 for r in roles})
    lines = table.splitlines()
    assert len(lines) == 3
    assert lines[1].startswith("/W/Room/* (5 prims)") and lines[1].rstrip().endswith("50")
    assert lines[2].startswith("/W/Man") and " avatar " in lines[2]
