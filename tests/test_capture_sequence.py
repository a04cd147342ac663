"""Frame sequences: pattern expansion, `usdgs import PATTERN` as one time-sampled prim (counts
changing per frame, static attributes authored once), and reading each frame back."""

from __future__ import annotations

import numpy as np
import pytest
from capture_testutil import DATA
from pxr import Usd
from test_capture_formats import random_set

from usd_gs.cli import main
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.io.formats import folder_pattern, read_capture, write_capture
from usd_gs.io.sequence import discover_frames, frame_path, is_pattern, parse_frames, sequence_paths
from usd_gs.usd.gaussian_prim import read_gaussian_prim

MONKEY = DATA / "sequences" / "monkey"


def test_pattern_expansion(tmp_path):
    assert frame_path("a/m_####.sog", 7) == "a/m_0007.sog"
    assert frame_path("a/m_#.sog", 12) == "a/m_12.sog"
    assert frame_path("m_%04d.ply", 3) == "m_0003.ply"
    assert frame_path("m_%d.ply", 3) == "m_3.ply"
    assert frame_path("dir#1/x.ply", 3) == "dir#1/x.ply" and not is_pattern("dir#1/x.ply")
    assert is_pattern("m_####.sog") and is_pattern("m.%03d.splat")
    assert parse_frames("1-50") == (1, 50) and parse_frames("7") == (7, 7) and parse_frames("-2--1") == (-2, -1)
    for bad in ("5-1", "a-b", "1-2-3"):
        with pytest.raises(UserError):
            parse_frames(bad)
    with pytest.raises(UserError, match="more than one frame token"):
        is_pattern("m_##_%02d.ply")
    for f in (3, 4, 6):
        (tmp_path / f"s_{f:03d}.splat").write_bytes(b"")
    pat = str(tmp_path / "s_###.splat")
    assert discover_frames(pat) == (3, 6)
    with pytest.raises(UserError) as exc:
        sequence_paths(pat)
    assert str(tmp_path / "s_005.splat") in str(exc.value) and "missing frame 5" in str(exc.value)
    with pytest.raises(UserError, match="s_002.splat"):
        sequence_paths(pat, (2, 4))


def _frames(tmp_path, counts, static_count=False):
    """.splat frames; with ``static_count`` every frame shares orientations/scales/colours and
    only positions move."""
    sets = []
    base = random_set(counts[0], 0, seed=9)
    for i, n in enumerate(counts):
        g = random_set(n, 0, seed=10 + i)
        if static_count:
            g = GaussianSet(base.positions + 0.1 * i, base.orientations, base.scales, base.opacities, base.sh)
        write_capture(tmp_path / f"f_{i + 1:04d}.splat", g)
        sets.append(read_capture(tmp_path / f"f_{i + 1:04d}.splat"))
    return sets


def test_sequence_counts_change_per_frame(tmp_path, capsys):
    sets = _frames(tmp_path, [10, 17, 5])
    out = tmp_path / "seq.usdc"
    code = main(["import", str(tmp_path / "f_####.splat"), "-o", str(out), "--prim", "/World/Seq",
                 "--role", "avatar", "--fps", "12"])
    assert code == 0, capsys.readouterr().err
    assert "3 frames 1-3" in capsys.readouterr().out
    stage = Usd.Stage.Open(str(out))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (1, 3, 12)
    prim = stage.GetPrimAtPath("/World/Seq")
    assert prim.GetAttribute("usdgs:role").Get() == "avatar"
    for f, g in enumerate(sets, start=1):
        back = read_gaussian_prim(prim, Usd.TimeCode(f), world=False)
        assert back.count == g.count
        np.testing.assert_array_equal(back.positions, g.positions)
        np.testing.assert_array_equal(back.orientations, g.orientations)
        np.testing.assert_array_equal(back.scales, g.scales)
        np.testing.assert_array_equal(back.opacities, g.opacities)
        np.testing.assert_array_equal(back.sh, g.sh)
    assert main(["validate", str(out), "-q"]) == 0


def test_sequence_static_attributes_authored_once(tmp_path, capsys):
    sets = _frames(tmp_path, [20, 20, 20, 20], static_count=True)
    out = tmp_path / "seq.usda"
    assert main(["import", str(tmp_path / "f_%04d.splat"), "-o", str(out), "--frames", "2-4", "-q"]) == 0
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath("/f")
    assert stage.GetStartTimeCode() == 2 and stage.GetEndTimeCode() == 4
    assert prim.GetAttribute("positions").GetTimeSamples() == [2.0, 3.0, 4.0]
    for name in ("orientations", "scales", "opacities", "radiance:sphericalHarmonicsCoefficients"):
        attr = prim.GetAttribute(name)
        assert attr.GetNumTimeSamples() == 0 and attr.HasAuthoredValue(), name
    for f in (2, 3, 4):
        back = read_gaussian_prim(prim, Usd.TimeCode(f), world=False)
        np.testing.assert_array_equal(back.positions, sets[f - 1].positions)
        np.testing.assert_array_equal(back.scales, sets[f - 1].scales)


def test_sequence_errors(tmp_path, capsys):
    _frames(tmp_path, [5, 5])
    code = main(["import", str(tmp_path / "f_####.splat"), "-o", str(tmp_path / "x.usdc"), "--frames", "1-3"])
    err = capsys.readouterr().err
    assert code == 2 and str(tmp_path / "f_0003.splat") in err and len(err.strip().splitlines()) == 1
    code = main(["import", str(tmp_path / "f_0001.splat"), "-o", str(tmp_path / "x.usdc"), "--frames", "1-3"])
    assert code == 2 and "--frames needs a frame pattern" in capsys.readouterr().err
    write_capture(tmp_path / "f_0002.splat", random_set(5, 0))  # fine: still degree 0
    write_capture(tmp_path / "g_0001.ply", random_set(5, 0))
    write_capture(tmp_path / "g_0002.ply", random_set(5, 1))
    code = main(["import", str(tmp_path / "g_####.ply"), "-o", str(tmp_path / "x.usdc")])
    err = capsys.readouterr().err
    assert code == 2 and "g_0002.ply" in err and "SH degree" in err


def test_sequence_folder_names_its_pattern(tmp_path, capsys):
    """A folder of numbered captures given where a capture is expected: the error gives the
    frame pattern to import (the most common prefix, digit count and ending)."""
    _frames(tmp_path, [5, 5, 5])  # f_0001.splat .. f_0003.splat
    write_capture(tmp_path / "other_01.ply", random_set(5, 0))  # one file of another group
    (tmp_path / "notes_2.txt").write_text("not a capture")
    assert folder_pattern(tmp_path) == (str(tmp_path / "f_####.splat"), 3)
    code = main(["import", str(tmp_path), "-o", str(tmp_path / "x.usdc")])
    err = capsys.readouterr().err
    assert code == 2 and "not a SOG folder" in err
    assert f"a frame sequence of 3 files: import it with its frame pattern, '{tmp_path / 'f_####.splat'}'" in err
    lone = tmp_path / "lone"
    lone.mkdir()
    write_capture(lone / "scan_7.ply", random_set(5, 0))
    assert folder_pattern(lone) is None  # one file is no sequence
    assert main(["import", str(lone), "-o", str(tmp_path / "y.usdc")]) == 2
    assert "frame sequence" not in capsys.readouterr().err


@pytest.mark.skipif(not MONKEY.exists(), reason="shared data not found (../shared/data)")
def test_monkey_sequence(tmp_path, capsys):
    out = tmp_path / "monkey.usdc"
    assert main(["import", str(MONKEY / "monkey_####.sog"), "-o", str(out), "--frames", "1-6", "--fps", "24",
                 "--prim", "/Monkey", "--role", "avatar", "-q"]) == 0
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath("/Monkey")
    assert prim.GetAttribute("positions").GetTimeSamples() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    ref = read_capture(MONKEY / "monkey_0004.sog")
    back = read_gaussian_prim(prim, Usd.TimeCode(4), world=False)
    np.testing.assert_array_equal(back.positions, ref.positions)
    np.testing.assert_array_equal(back.sh, ref.sh)
    np.testing.assert_array_equal(back.opacities, ref.opacities)


def test_main_job_on_sequence_with_changing_counts(tmp_path, capsys):
    """`usdgs process` on an imported sequence avatar whose count changes per frame (shared/
    DESIGN.md section 2): it is relit and receives shadows at every frame, and the output
    SH has that frame's count."""
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    rng = np.random.default_rng(0)
    counts = {1: 40, 2: 55}
    for f, n in counts.items():
        g = random_set(n, 0, seed=f)
        write_capture(tmp_path / f"av_{f:04d}.ply", GaussianSet(
            g.positions * 0.1 + np.array([0.0, 0.6, 0.0]), g.orientations, g.scales * 0.03, np.full(n, 0.9), g.sh))
    assert main(["import", str(tmp_path / "av_####.ply"), "-o", str(tmp_path / "av.usdc"), "--prim", "/World/Av",
                 "--role", "avatar", "-q"]) == 0
    m = 600
    stage = new_stage(default_prim="World")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    floor = GaussianSet(np.stack([rng.uniform(-1, 1, m), np.zeros(m), rng.uniform(-1, 1, m)], 1),
                        np.tile([1.0, 0, 0, 0], (m, 1)), np.tile([0.05, 0.005, 0.05], (m, 1)), np.full(m, 0.95),
                        np.full((m, 1, 3), 0.8))
    write_gaussian_prim(stage, "/World/Floor", floor)
    from pxr import Gf, UsdLux

    light = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    light.CreateIntensityAttr(30.0)
    light.AddTranslateOp().Set(Gf.Vec3d(0.3, 2.5, 0.3))
    stage.GetRootLayer().subLayerPaths = [str(tmp_path / "av.usdc")]
    save_stage_atomic(stage, tmp_path / "shot.usdc")
    assert main(["process", str(tmp_path / "shot.usdc"), "-o", str(tmp_path / "lit.usdc"), "-q"]) == 0, \
        capsys.readouterr().err
    lit = Usd.Stage.Open(str(tmp_path / "lit.usdc"))
    src = Usd.Stage.Open(str(tmp_path / "av.usdc"))
    for f, n in counts.items():
        out = read_gaussian_prim(lit.GetPrimAtPath("/World/Av"), Usd.TimeCode(f))
        before = read_gaussian_prim(src.GetPrimAtPath("/World/Av"), Usd.TimeCode(f))
        assert out.count == before.count == n
        np.testing.assert_array_equal(out.positions, before.positions)
        assert np.abs(out.sh - before.sh).max() > 1e-3  # relit (and shadowed) at this frame
