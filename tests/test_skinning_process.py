"""The main job on a skinned Gaussian avatar (UsdSkel binding): treated as moving (relit, casting and
receiving every frame), the output authors relit SH / transmittance only, not skinned positions, and
reading the output back gives the skinned Gaussians with the relit colour."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Usd, UsdSkel

from usd_gs.gaussians import matrix_to_quaternion
from usd_gs.usd import skel as uskel
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic, write_gaussian_prim
from usd_gs.usd.schema import apply_role


def _rig_stage(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from lights_scene import make_emitter_test_scene

    from usd_gs.synthetic import random_gaussians

    room = make_emitter_test_scene(spacing=0.25).gaussians
    avatar = random_gaussians(300, 1, seed=5)
    avatar.positions[:] = avatar.positions * 0.05 + np.array([0.0, 1.0, 0.0], np.float32)
    stage = new_stage()
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    write_gaussian_prim(stage, "/World/Room", room)
    UsdSkel.Root.Define(stage, "/World/Rig")
    bind = np.stack([np.eye(4), np.eye(4)])
    bind[1, :3, 3] = [0, 1, 0]
    rest = bind.copy()
    sk = uskel.author_skeleton(stage, "/World/Rig/Skel", ["a", "a/b"], bind, rest)
    rot = np.stack([np.eye(3), np.array(Gf.Matrix3d(Gf.Rotation(Gf.Vec3d(0, 0, 1), 60))).T])
    q = matrix_to_quaternion(np.stack([np.eye(3), np.eye(3), np.eye(3), rot[1]])).reshape(2, 2, 4)
    tr = np.array([[[0, 0, 0], [0, 1, 0]], [[0.8, 0, 0], [0, 1, 0]]], np.float64)
    uskel.author_animation(stage, "/World/Rig/Skel/Anim", sk, ["a", "a/b"], [1.0, 2.0], tr, q)
    prim = write_gaussian_prim(stage, "/World/Rig/Avatar", avatar)
    apply_role(prim, "avatar")
    w = np.clip((avatar.positions[:, 1] - 0.98) / 0.04, 0, 1)
    uskel.bind_prim(prim, sk, np.tile([0, 1], (avatar.count, 1)), np.stack([1 - w, w], axis=1))
    return save_stage_atomic(stage, tmp_path / "shot.usda"), avatar


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    from usd_gs.cli import main

    tmp_path = tmp_path_factory.mktemp("skinned_shot")
    src, avatar = _rig_stage(tmp_path)
    out = tmp_path / "shot.lit.usda"
    assert main(["process", str(src), "--lights", "2", "--frames", "1-2", "-o", str(out), "-q"]) == 0
    return src, out, avatar


def _sh_attr(prim):
    """(name, attribute) of the SH the output authored (float, or half when the float one is blocked)."""
    for name in ("radiance:sphericalHarmonicsCoefficients", "radiance:sphericalHarmonicsCoefficientsh"):
        attr = prim.GetAttribute(name)
        if attr and attr.GetTimeSamples():
            return attr
    return None


def test_process_skinned_avatar(processed):
    src, out, avatar = processed
    lit = Usd.Stage.Open(str(out))
    prim = lit.GetPrimAtPath("/World/Rig/Avatar")
    # moving: relit (probe) and authored at every frame
    assert lit.GetPrimAtPath("/UsdGs/Probes/Avatar")
    sh = _sh_attr(prim)
    assert sh is not None and sh.GetTimeSamples() == [1.0, 2.0]
    # only SH / transmittance / light scale authored on the avatar, no skinned positions or orientations
    spec = lit.GetRootLayer().GetPrimAtPath("/World/Rig/Avatar")
    authored = set(spec.attributes.keys()) if spec else set()
    assert authored and not authored & {"positions", "orientations", "scales", "positionsh", "orientationsh"}
    # the room's shadow follows the avatar (moved 0.8 m in x between the frames)
    room_sh = _sh_attr(lit.GetPrimAtPath("/World/Room"))
    assert room_sh is not None and set(room_sh.GetTimeSamples()) == {1.0, 2.0}
    assert not np.array_equal(np.asarray(room_sh.Get(1.0)), np.asarray(room_sh.Get(2.0)))
    # read back: the skinned positions of the input
    src_stage = Usd.Stage.Open(str(src))
    for f in (1.0, 2.0):
        got = read_gaussian_prim(prim, f)
        orig = read_gaussian_prim(src_stage.GetPrimAtPath("/World/Rig/Avatar"), f)
        np.testing.assert_array_equal(got.positions, orig.positions)
    assert abs(float(np.median(read_gaussian_prim(prim, 2.0).positions[:, 0] - avatar.positions[:, 0])) - 0.8) < 1e-5


def test_relit_sh_authored_in_bind_space(processed):
    """Relighting is a per-Gaussian colour factor: in the bind-pose SH attribute, band 1 of the relit
    output stays parallel to band 1 of the input (the factor scales it); rotated SH would not be."""
    src, out, avatar = processed
    lit = Usd.Stage.Open(str(out))
    src_stage = Usd.Stage.Open(str(src))
    out_b = read_gaussian_prim(lit.GetPrimAtPath("/World/Rig/Avatar"), 2.0, skin=False).sh[:, 1:4, :]
    in_b = read_gaussian_prim(src_stage.GetPrimAtPath("/World/Rig/Avatar"), 2.0, skin=False).sh[:, 1:4, :]
    cross = np.cross(out_b.transpose(0, 2, 1), in_b.transpose(0, 2, 1))
    rel = np.linalg.norm(cross, axis=2) / np.maximum(
        np.linalg.norm(out_b, axis=1) * np.linalg.norm(in_b, axis=1), 1e-12)
    assert np.max(rel) < 2e-3


def test_bake_skinning_authors_the_skinned_gaussians(tmp_path):
    """--bake-skinning: the output holds the skinned positions as time samples and blocks the binding,
    so a reader that knows nothing of UsdSkel sees the motion; the values equal the skinned read of
    the unbaked output at every frame."""
    from usd_gs.cli import main
    from usd_gs.usd.skel import has_skel_binding

    src, _ = _rig_stage(tmp_path)
    plain, baked = tmp_path / "plain.lit.usda", tmp_path / "baked.lit.usda"
    for out, extra in ((plain, []), (baked, ["--bake-skinning"])):
        assert main(["process", str(src), "--lights", "2", "--frames", "1-2", "-o", str(out), "-q", *extra]) == 0
    sa, sb = Usd.Stage.Open(str(plain)), Usd.Stage.Open(str(baked))
    a, b = sa.GetPrimAtPath("/World/Rig/Avatar"), sb.GetPrimAtPath("/World/Rig/Avatar")
    assert has_skel_binding(a) and not has_skel_binding(b)
    assert b.GetAttribute("positions").GetTimeSamples() == [1.0, 2.0]
    for f in (1.0, 2.0):
        ga, gb = read_gaussian_prim(a, f), read_gaussian_prim(b, f)
        np.testing.assert_allclose(gb.positions, ga.positions, atol=1e-5)
        np.testing.assert_allclose(gb.sh, ga.sh, atol=2e-3)  # half-precision relit SH, rotated per band
