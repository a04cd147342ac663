"""A per-frame prim with nothing time-sampled (an inserted object that holds one pose): read once
per run (``ShotProcessor._read``); as a caster under lights that do not move, packed once, and its
shadows on the static receivers, its own self-shadows, the sky it hides and the static scene's
shadows on it computed once (``_caster_task``, ``_self_task``, ``_sky_task``,
``_scene_shadow_task``). The static receivers' values come from a DGSM of theirs alone, so a farm
run's chunks give the whole run's output, and they stay within the atlas error of the shared
per-frame DGSM the prim got before."""

import numpy as np
import pytest
from farm_compare import stage_differences
from hardening_util import tiny_shot

import usd_gs.pipeline.shot as shot
from usd_gs.cli import main

FRAMES = [1, 2, 3]


def _shot(path):
    from pxr import Gf, Usd, UsdGeom

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim

    tiny_shot(path, n_scene=1200, n_avatar=250, frames=3)
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


def _every_frame(mp) -> None:
    """Process as before: no prim counts as holding one pose (``mp``: a pytest MonkeyPatch)."""
    opened = shot.ShotProcessor._open

    def every_frame(self):
        opened(self)
        self._constant = set()

    mp.setattr(shot.ShotProcessor, "_open", every_frame)


ARGS = ["--avatar", "/World/Avatar", "--object", "/World/Box", "--precision", "float", "--sh-tolerance", "0",
        "--aovs", "transmittance", "-q"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The shot, and its output with the held values, chunked, and computed at every frame as before."""
    tmp = tmp_path_factory.mktemp("constant")
    stage = _shot(tmp / "shot.usda")
    mp = pytest.MonkeyPatch()
    reads = []
    plain = shot.read_gaussian_prim

    def counted(prim, *a, **k):
        reads.append(str(prim.GetPath()))
        return plain(prim, *a, **k)

    mp.setattr(shot, "read_gaussian_prim", counted)
    casts = []
    plain_cast = shot.shared_transmittance

    def cast(g, parts, *a, **k):
        casts.append((g.count, [None if p is None else len(p[0]) for p in parts]))
        return plain_cast(g, parts, *a, **k)

    mp.setattr(shot, "shared_transmittance", cast)
    scene = []
    plain_scene = shot._scene_task

    def scene_task(block, drecv, light, cfg, bias, atlas, candidates=None):
        scene.append(drecv.gaussians.count if candidates is None else len(candidates))
        return plain_scene(block, drecv, light, cfg, bias, atlas, candidates)

    mp.setattr(shot, "_scene_task", scene_task)
    try:
        assert main(["process", str(stage), "-o", str(tmp / "held.usdc"), *ARGS]) == 0
        counts = {"reads": list(reads), "casts": list(casts), "scene": list(scene)}
        assert main(["process", str(stage), "-o", str(tmp / "chunked.usdc"), "--chunk-size", "1", *ARGS]) == 0
        reads.clear()
        _every_frame(mp)
        assert main(["process", str(stage), "-o", str(tmp / "each.usdc"), *ARGS]) == 0
        counts["reads before"] = list(reads)
    finally:
        mp.undo()
    return tmp, counts


def test_constant_object_is_read_and_cast_once(runs):
    _, counts = runs
    reads = counts["reads"]
    # the object (per-frame: relit and cast every frame) once in world space and once in its own frame
    # (the SH its attribute holds, unrotated, for the output); the avatar at every frame
    assert reads.count("/World/Box") == 2 and reads.count("/World/Avatar") >= 3
    assert counts["reads before"].count("/World/Box") == 6
    # the box (300 Gaussians) as a caster: a DGSM of its static receivers once, then one of the moving
    # receivers (the avatar's 250 Gaussians) per frame, never the shared two-part DGSM of before
    box = [parts for n, parts in counts["casts"] if n == 300]
    assert len(box) == 1 + len(FRAMES) and all(len(p) == 1 and p[0] for p in box), box
    assert box[1:] == [[250]] * len(FRAMES)
    # the static scene's shadows on the moving receivers: the avatar's 250 every frame, the box's 300 once
    assert counts["scene"] == [250, 300] + [250] * (len(FRAMES) - 1)


def test_farm_chunks_give_the_whole_run(runs):
    tmp, _ = runs
    assert stage_differences(tmp / "held.usdc", tmp / "chunked.usdc", FRAMES) == []


def test_values_within_the_atlas_error_of_the_shared_dgsm(runs):
    from pxr import Usd

    tmp, _ = runs
    held, each = (Usd.Stage.Open(str(tmp / n)) for n in ("held.usdc", "each.usdc"))
    worst, shadowed = 0.0, 0
    for prim in held.Traverse():
        attr = prim.GetAttribute("primvars:usdgs:transmittance")
        if not attr or not attr.GetTimeSamples():
            continue
        other = each.GetPrimAtPath(prim.GetPath()).GetAttribute("primvars:usdgs:transmittance")
        for t in FRAMES:
            a, b = np.asarray(attr.Get(t)), np.asarray(other.Get(t))
            worst = max(worst, float(np.abs(a - b).max()))
            shadowed += int(np.count_nonzero(a < 0.99))
    assert shadowed > 100  # the box and the avatar do shadow the room
    # another ROI and bin range than the shared DGSM's: within the DGSM's per-receiver max error (0.05,
    # usd_gs.shadows.dgsm's defaults)
    assert worst < 0.05


def test_sky_a_constant_caster_hides_is_computed_once(tmp_path, monkeypatch):
    """Under a sun and a sky: the sky the box hides from the static receivers once per run, with
    the values of computing it at every frame."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    from usd_gs.usd.gaussian_prim import save_stage_atomic

    stage_path = _shot(tmp_path / "sky.usda")
    stage = Usd.Stage.Open(str(stage_path))
    stage.RemovePrim("/World/Lamp")
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-55.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.5)
    save_stage_atomic(stage, stage_path)
    calls, reached = [], []
    plain = shot.caster_hidden_parts

    def parts(caster, *a, **k):
        got = plain(caster, *a, **k)
        calls.append(caster.count)
        reached.append(sum(len(i) for i, _ in got) if caster.count == 300 else 0)
        return got

    monkeypatch.setattr(shot, "caster_hidden_parts", parts)
    argv = ["process", str(stage_path), "--lights", "stage", *ARGS]
    assert main([*argv, "-o", str(tmp_path / "held.usdc")]) == 0
    assert calls.count(300) == 1 and calls.count(250) == len(FRAMES)  # the box once, the avatar every frame
    assert max(reached) > 100  # the box does hide sky from the room's receivers around it
    _every_frame(monkeypatch)
    assert main([*argv, "-o", str(tmp_path / "each.usdc")]) == 0
    assert calls.count(300) == 1 + len(FRAMES)
    assert stage_differences(tmp_path / "held.usdc", tmp_path / "each.usdc", FRAMES) == []


def _static_shot(path, animated_lamp: bool):
    """The box alone (an object holding one pose) in the room, under a lamp that moves or not."""
    from pxr import Gf, Usd, UsdGeom

    from usd_gs.usd.gaussian_prim import save_stage_atomic

    _shot(path)
    stage = Usd.Stage.Open(str(path))
    stage.RemovePrim("/World/Avatar")
    stage.SetEndTimeCode(4)
    if animated_lamp:
        op = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Lamp")).GetOrderedXformOps()[0]
        for f in (1, 2, 3, 4):
            op.Set(Gf.Vec3d(0.1 * f, 3, 0), Usd.TimeCode(f))
    save_stage_atomic(stage, path)
    return path


@pytest.mark.parametrize("animated_lamp", [False, True])
def test_a_shot_where_nothing_moves_is_processed_once(tmp_path, monkeypatch, animated_lamp):
    """Nothing per-frame time-sampled and the same lights: frames 2-4 hold frame 1's results (the
    composed output of processing every frame, but the probe textures' frame-1 file); a moving
    lamp processes every frame."""
    stage = _static_shot(tmp_path / "static.usda", animated_lamp)
    frames = []
    plain = shot.ShotProcessor._frame

    def counted(self, f, *a, **k):
        frames.append(f)
        return plain(self, f, *a, **k)

    monkeypatch.setattr(shot.ShotProcessor, "_frame", counted)
    argv = ["process", str(stage), "--object", "/World/Box", "--lights", "stage", "--precision", "float",
            "--aovs", "transmittance", "--json"]
    import contextlib
    import io
    import json

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main([*argv, "-o", str(tmp_path / "held.usdc")]) == 0
    held = json.loads(buf.getvalue())
    assert frames == ([1.0, 2.0, 3.0, 4.0] if animated_lamp else [1.0])
    assert held["affected_frames"]["/World/Box"] == 4
    monkeypatch.setattr(shot.ShotProcessor, "_hold_frame", lambda self, f: False)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*argv, "-o", str(tmp_path / "each.usdc")]) == 0
    diffs = stage_differences(tmp_path / "held.usdc", tmp_path / "each.usdc", [1, 2, 3, 4])
    assert [d for d in diffs if "probe:texture" not in d] == []
    from pxr import Usd

    out = Usd.Stage.Open(str(tmp_path / "held.usdc"))
    samples = out.GetPrimAtPath("/World/Box").GetAttribute("radiance:sphericalHarmonicsCoefficients").GetTimeSamples()
    assert samples == ([1.0, 2.0, 3.0, 4.0] if animated_lamp else [1.0])
