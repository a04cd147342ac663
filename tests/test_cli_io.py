"""`usdgs import/export/inspect/validate`: happy paths on real captures and every user-error path."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from usd_gs.cli import main

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BIKER_PLY = DATA / "splats" / "biker.ply"


def write_raw_ply(path, n=20, degree=1, drop=(), nan_at=None, extra_fields=()):
    """A small INRIA-layout PLY written with plyfile directly (independent of usd_gs.io.ply)."""
    rng = np.random.default_rng(0)
    k = (degree + 1) ** 2 - 1
    names = ["x", "y", "z", *extra_fields, "f_dc_0", "f_dc_1", "f_dc_2", *[f"f_rest_{i}" for i in range(3 * k)],
             "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    names = [n_ for n_ in names if n_ not in drop]
    arr = np.zeros(n, dtype=[(n_, "f4") for n_ in names])
    for n_ in names:
        arr[n_] = rng.normal(size=n)
    if "rot_0" in names:
        arr["rot_0"] = np.abs(arr["rot_0"]) + 0.5
    if nan_at is not None:
        arr[nan_at[0]][nan_at[1]] = np.nan
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(path))
    return arr


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith("usdgs ")
    with pytest.raises(SystemExit):
        main(["import", "--help"])
    assert "--role" in capsys.readouterr().out


def test_import_export_round_trip_real_capture(tmp_path, capsys):
    usd = tmp_path / "biker.usdc"
    code, out, err = run_cli(capsys, "import", BIKER_PLY, "-o", usd, "--prim", "/World/Biker", "--role", "avatar")
    assert code == 0, err
    assert "152,746 Gaussians" in out
    code, out, err = run_cli(capsys, "inspect", usd, "--json")
    assert code == 0, err
    rows = json.loads(out)
    assert [(r["path"], r["count"], r["sh_degree"], r["role"]) for r in rows] == [
        ("/World/Biker", 152746, 0, "avatar")]
    back = tmp_path / "back.ply"
    code, out, err = run_cli(capsys, "export", usd, "--prim", "/World/Biker", "-o", back)
    assert code == 0, err
    a = PlyData.read(str(BIKER_PLY))["vertex"].data
    b = PlyData.read(str(back))["vertex"].data
    for name in a.dtype.names:
        if name.startswith("rot_"):
            continue
        assert np.array_equal(a[name].view(np.uint32), b[name].view(np.uint32)), name
    qa = np.stack([a[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qb = np.stack([b[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qa /= np.linalg.norm(qa, axis=1, keepdims=True)
    qb /= np.linalg.norm(qb, axis=1, keepdims=True)
    assert np.max(np.abs(qa - qb)) < 1e-7
    code, out, err = run_cli(capsys, "validate", usd)
    assert code == 0 and "ok" in out


def test_inspect_table_lists_prim(tmp_path, capsys):
    ply = tmp_path / "small.ply"
    write_raw_ply(ply, n=30, degree=2)
    usd = tmp_path / "small.usda"
    assert run_cli(capsys, "import", ply, "-o", usd, "--up-axis", "Z")[0] == 0
    code, out, _ = run_cli(capsys, "inspect", usd)
    assert code == 0
    assert "upAxis Z" in out and "/small" in out and " 30 " in out


def test_inspect_warns_of_units_and_up_axis_left_to_a_sublayer(tmp_path, capsys):
    """USD reads metersPerUnit and upAxis from the root layer only: a shot layer over an imported
    capture (Z-up, metres) that does not author them is read in centimetres, Y-up; inspect names
    both, with the sublayer's values; a root that authors them (or whose sublayer agrees with USD's
    defaults) gets no warning."""
    from pxr import Sdf, Usd

    from usd_gs.usd.stage import root_metadata_warnings

    ply = tmp_path / "small.ply"
    write_raw_ply(ply, n=30, degree=0)
    assert run_cli(capsys, "import", ply, "-o", tmp_path / "small.usda", "--up-axis", "Z")[0] == 0
    shot = Sdf.Layer.CreateNew(str(tmp_path / "shot.usda"))
    shot.subLayerPaths.append("small.usda")
    shot.Save()
    code, out, _ = run_cli(capsys, "inspect", tmp_path / "shot.usda")
    assert code == 0 and "upAxis Y, metersPerUnit 0.01" in out
    lines = [ln for ln in out.splitlines() if ln.startswith("warning: ")]
    assert len(lines) == 2, out
    assert "metersPerUnit is not authored on the root layer" in lines[0] and "0.01 (centimetres)" in lines[0]
    assert "small.usda says 1: author metersPerUnit = 1" in lines[0]
    assert "upAxis is not authored" in lines[1] and "default Y" in lines[1] and "says Z" in lines[1]
    # usdgs validate says it too, without failing (the stage is valid USD)
    code, out, _ = run_cli(capsys, "validate", tmp_path / "shot.usda")
    assert code == 0 and [ln for ln in out.splitlines() if ln.startswith("warning: ")] == lines
    # usdgs process warns the same (its summary's warnings)
    from usd_gs.pipeline.options import ProcessOptions
    from usd_gs.pipeline.shot import ShotProcessor

    proc = ShotProcessor(str(tmp_path / "shot.usda"), str(tmp_path / "o.usdc"), ProcessOptions())
    proc._open()
    assert [w for w in proc.warnings if "not authored on the root layer" in w] == [ln[9:] for ln in lines]
    # the root authors them: read as authored, nothing to say
    shot.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    shot.pseudoRoot.SetInfo("upAxis", "Z")
    shot.Save()
    assert root_metadata_warnings(Usd.Stage.Open(str(tmp_path / "shot.usda"))) == []
    # a sublayer that says what USD falls back to: nothing lost
    flat = Sdf.Layer.CreateNew(str(tmp_path / "cm.usda"))
    flat.pseudoRoot.SetInfo("metersPerUnit", 0.01)
    flat.Save()
    over = Sdf.Layer.CreateNew(str(tmp_path / "over.usda"))
    over.subLayerPaths.append("cm.usda")
    over.Save()
    assert root_metadata_warnings(Usd.Stage.Open(str(tmp_path / "over.usda"))) == []


@pytest.mark.parametrize(
    "case, expect",
    [
        ("missing", "no such file"),
        ("garbage", "garbage.ply"),
        ("no_opacity", "opacity"),
        ("truncated", "truncated.ply"),
        ("nan", "element 3"),
        ("extension", "unsupported input type '.xyz'"),
    ],
)
def test_import_user_errors_exit_2_one_line(tmp_path, capsys, case, expect):
    src = tmp_path / f"{case}.ply"
    if case == "garbage":
        src.write_bytes(b"this is not a ply file\n" * 10)
    elif case == "no_opacity":
        write_raw_ply(src, drop=("opacity",))
    elif case == "truncated":
        write_raw_ply(src, n=500)
        data = src.read_bytes()
        src.write_bytes(data[: len(data) - 999])
    elif case == "nan":
        write_raw_ply(src, nan_at=(3, "scale_1"))
    elif case == "extension":
        src = tmp_path / "cloud.xyz"
        src.write_text("1 2 3\n")
    code, out, err = run_cli(capsys, "import", src, "-o", tmp_path / "out.usdc")
    assert code == 2
    assert err.startswith("usdgs import: error:") and expect in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "out.usdc").exists()


def test_bad_output_and_prim_paths(tmp_path, capsys):
    ply = tmp_path / "a.ply"
    write_raw_ply(ply)
    code, _, err = run_cli(capsys, "import", ply, "-o", tmp_path / "a.abc")
    assert code == 2 and "output must end in" in err
    code, _, err = run_cli(capsys, "import", ply, "-o", tmp_path / "a.usdc", "--prim", "not/absolute")
    assert code == 2 and "not/absolute" in err
    code, _, err = run_cli(capsys, "import", ply, "-o", tmp_path / "nodir" / "a.usdc")
    assert code == 2 and "does not exist" in err


def test_export_errors_name_stage_and_prim(tmp_path, capsys):
    ply = tmp_path / "a.ply"
    write_raw_ply(ply)
    usd = tmp_path / "a.usda"
    assert run_cli(capsys, "import", ply, "-o", usd, "--prim", "/World/A")[0] == 0
    code, _, err = run_cli(capsys, "export", usd, "--prim", "/World/Nope", "-o", tmp_path / "b.ply")
    assert code == 2 and "no prim at /World/Nope" in err and "/World/A" in err
    code, _, err = run_cli(capsys, "export", usd, "--prim", "/World", "-o", tmp_path / "b.ply")
    assert code == 2 and "not a ParticleField3DGaussianSplat" in err
    code, _, err = run_cli(capsys, "export", tmp_path / "missing.usda", "--prim", "/World/A", "-o", tmp_path / "b.ply")
    assert code == 2 and "missing.usda: no such file" in err
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"A\" {\n")
    code, _, err = run_cli(capsys, "inspect", bad)
    assert code == 2 and "bad.usda: cannot be opened as a USD stage" in err
    # a capture given where a stage is expected: the error says how to bring it in
    sog = tmp_path / "lod"
    sog.mkdir()
    (sog / "lod-meta.json").write_text("{}")
    for capture in (ply, sog):
        for cmd in (["process", capture], ["render", capture, "-o", tmp_path / "f.png"], ["inspect", capture]):
            code, _, err = run_cli(capsys, *cmd)
            assert code == 2 and f"{capture}: is a 3DGS capture, not a USD stage" in err, err
            assert f"usdgs import {capture} -o {capture.name.split('.')[0]}.usdc" in err and "--role avatar" in err
    code, _, err = run_cli(capsys, "export", usd, "--prim", "/World/A", "--time", "soon", "-o", tmp_path / "b.ply")
    assert code == 2 and "--time 'soon'" in err


def test_mismatched_lengths_reported_by_export_and_validate(tmp_path, capsys):
    from pxr import Usd, Vt

    ply = tmp_path / "a.ply"
    write_raw_ply(ply, n=10)
    usd = tmp_path / "a.usda"
    assert run_cli(capsys, "import", ply, "-o", usd, "--prim", "/World/A")[0] == 0
    stage = Usd.Stage.Open(str(usd))
    stage.GetPrimAtPath("/World/A").GetAttribute("opacities").Set(Vt.FloatArray([0.5] * 7))
    stage.GetRootLayer().Save()
    code, _, err = run_cli(capsys, "export", usd, "--prim", "/World/A", "-o", tmp_path / "b.ply")
    assert code == 2 and "/World/A" in err and "opacities" in err
    code, out, err = run_cli(capsys, "validate", usd)
    assert code == 1 and "/World/A.opacities" in out


def test_console_script_debug_traceback(tmp_path):
    exe = Path(sys.executable).with_name("usdgs")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "usd_gs.cli"]
    env = dict(os.environ)
    r = subprocess.run([*cmd, "import", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.usdc")],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "nope.ply: no such file" in r.stderr
    r = subprocess.run([*cmd, "--debug", "import", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.usdc")],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "Traceback" in r.stderr


@pytest.mark.parametrize("up_axis, expect", [("Y", lambda p: p * [1, -1, -1]),
                                             ("Z", lambda p: np.stack([p[:, 0], p[:, 2], -p[:, 1]], 1))])
def test_import_y_down_turns_the_capture_up(tmp_path, up_axis, expect):
    """``--y-down``: a transform on the prim (180 degrees about X for a Y-up stage, -90 for Z-up) puts
    the capture's up (-Y) on the stage's up axis; the data itself and its local export stay as read,
    for one prim, bricks and a sequence."""
    from pxr import Usd

    from usd_gs.io.formats import read_capture, write_capture
    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import find_gaussian_prims, read_gaussian_prim

    src = tmp_path / "cap_0001.splat"
    write_capture(src, random_gaussians(40, 0, seed=3))
    write_capture(tmp_path / "cap_0002.splat", random_gaussians(40, 0, seed=4))
    raw = read_capture(src)
    for extra, name in (([], "one"), (["--brick-size", "16"], "bricks"), ([], "seq")):
        inp = str(tmp_path / "cap_####.splat") if name == "seq" else str(src)
        out = tmp_path / f"{name}_{up_axis}.usdc"
        assert main(["import", inp, "-o", str(out), "--prim", "/World/Cap", "--up-axis", up_axis, "--y-down", "-q",
                     *extra]) == 0
        stage = Usd.Stage.Open(str(out))
        cap = stage.GetPrimAtPath("/World/Cap")
        assert list(cap.GetAttribute("xformOpOrder").Get()) == ["xformOp:rotateX:yDown"]
        assert cap.GetAttribute("xformOp:rotateX:yDown").Get() == (180.0 if up_axis == "Y" else -90.0)
        prims = find_gaussian_prims(stage)
        t = Usd.TimeCode(1) if name == "seq" else Usd.TimeCode.EarliestTime()
        world = np.concatenate([read_gaussian_prim(p, t).positions for p in prims]).astype(np.float64)
        local = np.concatenate([read_gaussian_prim(p, t, world=False).positions for p in prims])
        order = np.lexsort(local.T)  # (bricks reorder the Gaussians)
        np.testing.assert_allclose(world[order], expect(local.astype(np.float64))[order], atol=1e-5)
        ref = raw.positions[np.lexsort(raw.positions.T)]
        np.testing.assert_array_equal(local[order], ref)  # the data as read
