"""A per-frame prim with nothing time-sampled (an inserted object that holds one pose) is read
once per run, not at every frame (``ShotProcessor._read``), with the output of reading it at every
frame."""

from farm_compare import stage_differences
from hardening_util import tiny_shot

import usd_gs.pipeline.shot as shot
from usd_gs.cli import main


def _shot(path):
    from pxr import Gf, UsdGeom

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim

    tiny_shot(path, n_scene=1200, n_avatar=250, frames=3)
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    box = random_gaussians(300, degree=2, seed=4)
    box.positions *= 0.2
    write_gaussian_prim(stage, "/World/Box", box)
    xf = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Box"))
    xf.AddTranslateOp().Set(Gf.Vec3d(0.4, 0.5, 0.1))  # no time samples: the same pose every frame
    xf.AddRotateYOp().Set(35.0)
    xf.AddScaleOp().Set(Gf.Vec3f(0.5, 0.5, 0.5))
    save_stage_atomic(stage, path)
    return path


def test_constant_object_is_read_once_with_the_same_output(tmp_path, monkeypatch):
    stage = _shot(tmp_path / "shot.usda")
    reads = []
    plain = shot.read_gaussian_prim

    def counted(prim, *a, **k):
        reads.append(str(prim.GetPath()))
        return plain(prim, *a, **k)

    monkeypatch.setattr(shot, "read_gaussian_prim", counted)
    argv = ["process", str(stage), "--avatar", "/World/Avatar", "--object", "/World/Box", "--precision", "float",
            "--sh-tolerance", "0", "-q"]
    assert main([*argv, "-o", str(tmp_path / "once.usdc")]) == 0
    once = reads.count("/World/Box")
    moving = reads.count("/World/Avatar")
    # the object (per-frame: relit and cast every frame) once in world space and once in its own frame
    # (the SH its attribute holds, unrotated, for the output); the avatar at every frame
    assert once == 2
    assert moving >= 3
    reads.clear()
    opened = shot.ShotProcessor._open

    def every_frame(self):  # as before: no prim counts as constant
        opened(self)
        self._constant = set()

    monkeypatch.setattr(shot.ShotProcessor, "_open", every_frame)
    assert main([*argv, "-o", str(tmp_path / "each.usdc")]) == 0
    assert reads.count("/World/Box") == 6
    diffs = stage_differences(tmp_path / "once.usdc", tmp_path / "each.usdc", [1, 2, 3])
    assert diffs == []
    from pxr import Usd

    out = Usd.Stage.Open(str(tmp_path / "once.usdc"))
    sh = out.GetPrimAtPath("/World/Box").GetAttribute("radiance:sphericalHarmonicsCoefficients")
    assert sh.GetTimeSamples() == [1.0, 2.0, 3.0]  # relit at every frame (the avatar moves beside it)
