"""Issue #17 item 3: instanced Gaussian prims are read through their prototypes, with each
instance's transform applied (validate, inspect, export, render, process)."""

from __future__ import annotations

import json

import numpy as np
from pxr import Gf, Usd, UsdGeom, Vt

from usd_gs.cli import main
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import read_gaussian_prim, save_stage_atomic, write_gaussian_prim


def _instanced(tmp_path, nan: bool = False):
    """asset.usda holds /Asset/Splat; shot.usda references it twice as instanceable prims moved
    by +-2 in x, plus a static floor."""
    asset = Usd.Stage.CreateInMemory()
    g = random_gaussians(30, degree=1, seed=4)
    g.positions *= 0.1
    write_gaussian_prim(asset, "/Asset/Splat", g)
    if nan:  # the writer refuses NaN: author it afterwards
        attr = asset.GetPrimAtPath("/Asset/Splat").GetAttribute("positions")
        pos = np.array(attr.Get())
        pos[6] = np.nan
        attr.Set(Vt.Vec3fArray.FromNumpy(pos))
    asset.SetDefaultPrim(asset.GetPrimAtPath("/Asset"))
    save_stage_atomic(asset, tmp_path / "asset.usda")
    shot = Usd.Stage.CreateInMemory()
    floor = random_gaussians(100, degree=1, seed=5)
    floor.positions[:, 1] *= 0.02
    write_gaussian_prim(shot, "/World/Floor", floor)
    for name, x in (("Left", -2.0), ("Right", 2.0)):
        prim = shot.DefinePrim(f"/World/{name}", "Xform")
        prim.GetReferences().AddReference("./asset.usda")
        prim.SetInstanceable(True)
        UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(x, 1, 0))
    shot.SetStartTimeCode(1)
    shot.SetEndTimeCode(1)
    save_stage_atomic(shot, tmp_path / "shot.usda")
    return tmp_path / "shot.usda", g


def test_instances_are_read_with_their_transforms(tmp_path, capsys):
    shot, g = _instanced(tmp_path)
    stage = Usd.Stage.Open(str(shot))
    assert stage.GetPrimAtPath("/World/Left").IsInstance()
    capsys.readouterr()
    assert main(["inspect", str(shot), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["path"] for r in rows] == ["/World/Floor", "/World/Left/Splat", "/World/Right/Splat"]
    left = read_gaussian_prim(stage.GetPrimAtPath("/World/Left/Splat"), Usd.TimeCode(1))
    np.testing.assert_allclose(left.positions, g.positions + np.float32([-2, 1, 0]), atol=1e-6)
    ply = tmp_path / "all.ply"
    assert main(["export", str(shot), "-o", str(ply), "-q"]) == 0
    from usd_gs.io.ply import read_ply

    assert read_ply(ply).count == 160
    assert main(["render", str(shot), "-o", str(tmp_path / "r.png"), "--width", "32", "-q"]) == 0
    out = tmp_path / "out.usdc"
    assert main(["process", str(shot), "-o", str(out), "-q", "--object", "/World/Left/Splat"]) == 0
    res = Usd.Stage.Open(str(out))
    assert not res.GetPrimAtPath("/World/Left").IsInstance()  # de-instanced in the output layer only
    assert Usd.Stage.Open(str(shot)).GetPrimAtPath("/World/Left").IsInstance()
    assert main(["validate", str(out), "-q"]) == 0


def test_validate_sees_nan_in_a_prototype(tmp_path, capsys):
    shot, _ = _instanced(tmp_path, nan=True)
    capsys.readouterr()
    assert main(["validate", str(shot)]) == 1
    out = capsys.readouterr().out
    assert "/World/Left/Splat.positions[6]" in out and "/World/Right/Splat.positions[6]" in out, out
    assert main(["export", str(shot), "-o", str(tmp_path / "x.ply")]) == 2
