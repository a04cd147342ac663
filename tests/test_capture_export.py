"""`usdgs export` for viewers: visible prims merged in world space per frame, processed SH
from an output layer, one .ply/.splat/.spz per frame."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt
from test_capture_formats import random_set

from usd_gs.cli import main
from usd_gs.gaussians import GaussianSet
from usd_gs.io.formats import read_capture
from usd_gs.io.splat import SH_C0
from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

OFFSET = np.array([1.0, 2.0, -3.0])


@pytest.fixture
def shot(tmp_path):
    """/World/A: static, translated by OFFSET; /World/B: 3 frames with counts 7, 9, 8;
    /World/Hidden: invisible. Frames 1..3."""
    stage = new_stage(default_prim="World")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    a = random_set(11, 1, seed=1)
    prim = write_gaussian_prim(stage, "/World/A", a)
    UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(*OFFSET))
    bs = {}
    for f, n in ((1, 7), (2, 9), (3, 8)):
        bs[f] = random_set(n, 0, seed=10 + f)
        write_gaussian_prim(stage, "/World/B", bs[f], time=f)
    hidden = write_gaussian_prim(stage, "/World/Hidden", random_set(5, 0, seed=7))
    UsdGeom.Imageable(hidden).MakeInvisible()
    path = tmp_path / "shot.usdc"
    save_stage_atomic(stage, path)
    return path, a, bs


def test_export_merges_visible_prims_per_frame(tmp_path, capsys, shot):
    path, a, bs = shot
    out = tmp_path / "out_####.ply"
    assert main(["export", str(path), "--frames", "1-3", "-o", str(out)]) == 0
    assert "3 files" in capsys.readouterr().out
    for f in (1, 2, 3):
        g = read_capture(tmp_path / f"out_{f:04d}.ply")
        assert g.count == a.count + bs[f].count       # Hidden left out
        np.testing.assert_allclose(g.positions[:a.count], a.positions + OFFSET, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(g.positions[a.count:], bs[f].positions)
        assert g.sh_degree == 1                        # B's degree-0 SH zero-padded
        np.testing.assert_array_equal(g.sh[a.count:, 1:], 0)
        np.testing.assert_array_equal(g.sh[a.count:, 0], bs[f].sh[:, 0])
    # no --frames and a frame token: the stage's whole range
    assert main(["export", str(path), "--prim", "/World/B", "-o", str(tmp_path / "b_%02d.splat"), "-q"]) == 0
    for f in (1, 2, 3):
        g = read_capture(tmp_path / f"b_{f:02d}.splat")
        np.testing.assert_array_equal(g.positions, bs[f].positions)
        np.testing.assert_allclose(g.opacities, bs[f].opacities, atol=0.5 / 255 + 1e-7)
        np.testing.assert_allclose(g.sh[:, 0], bs[f].sh[:, 0], atol=0.5 / 255 / SH_C0 + 1e-6)


def test_export_processed_sh_from_output_layer(tmp_path, shot):
    """An output stage (sublayers the input, overs the SH as 'usdgs process' does): the
    exported SH is the processed one."""
    path, a, _ = shot
    layer = Sdf.Layer.CreateNew(str(tmp_path / "shot.lit.usda"))
    layer.subLayerPaths = [str(path)]
    stage = Usd.Stage.Open(layer)
    lit = (a.sh * 0.5).reshape(-1, 3)
    stage.OverridePrim("/World/A").GetAttribute("radiance:sphericalHarmonicsCoefficients").Set(
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(lit)))
    layer.Save()
    out = tmp_path / "lit.spz"
    assert main(["export", str(tmp_path / "shot.lit.usda"), "--prim", "/World/A", "--time", "1", "-o", str(out),
                 "-q"]) == 0
    g = read_capture(out)
    assert g.count == a.count
    np.testing.assert_allclose(g.sh[:, 0], a.sh[:, 0] * 0.5, atol=0.5 / (0.15 * 255) + 1e-6)
    out = tmp_path / "lit.ply"
    assert main(["export", str(tmp_path / "shot.lit.usda"), "--prim", "/World/A", "-o", str(out), "-q"]) == 0
    np.testing.assert_array_equal(read_capture(out).sh, (a.sh * 0.5).astype(np.float32))


def test_export_errors(tmp_path, capsys, shot):
    path, _, _ = shot
    cases = [
        (["--frames", "1-3", "-o", tmp_path / "one.ply"], "frame token"),
        (["-o", tmp_path / "x.glb"], "must end in .ply, .splat, .spz"),
        (["--local", "-o", tmp_path / "x.ply"], "--local needs exactly one"),
        (["--frames", "1-2", "--time", "1", "-o", tmp_path / "x_#.ply"], "not both"),
        (["-o", tmp_path / "nodir" / "x.ply"], "does not exist"),
    ]
    for extra, msg in cases:
        code = main(["export", str(path), *map(str, extra)])
        err = capsys.readouterr().err
        assert code == 2 and msg in err and len(err.strip().splitlines()) == 1, (extra, err)


def test_concatenate_is_what_export_writes(tmp_path, shot):
    path, a, bs = shot
    out = tmp_path / "f2.ply"
    assert main(["export", str(path), "--prim", "/World/B", "--prim", "/World/A", "--time", "2", "-o", str(out),
                 "-q"]) == 0
    g = read_capture(out)
    shifted = GaussianSet(a.positions + OFFSET, a.orientations, a.scales, a.opacities, a.sh)
    ref = GaussianSet.concatenate([bs[2], shifted])
    np.testing.assert_allclose(g.positions, ref.positions, atol=1e-6)
    np.testing.assert_allclose(g.scales, ref.scales, rtol=1e-6)
