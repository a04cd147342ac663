"""``usdgs rig`` on small generated MakeHuman-format files and a BVH: readers, alignment, weight
transfer, retargeting, the written UsdSkel stage and bad input (usd_gs.demo.rig, io.bvh, io.makehuman)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pxr import Usd, UsdSkel

from usd_gs.cli import main
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.io.bvh import read_bvh
from usd_gs.io.makehuman import load_makehuman
from usd_gs.io.ply import write_ply
from usd_gs.usd.gaussian_prim import read_gaussian_prim

pytest.importorskip("trimesh")
pytest.importorskip("scipy")

HIP, CHEST, TOP = 8.5, 12.0, 17.0  # decimetres
RADIUS = 1.5


def _cylinder(n_around=24, n_up=35):
    ang = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    ys = np.linspace(0.0, TOP, n_up)
    v = np.array([[RADIUS * np.cos(a), y, RADIUS * np.sin(a)] for y in ys for a in ang])
    quads = []
    for i in range(n_up - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            quads.append((a, b, b + n_around, a + n_around))
    return v, quads


def _weights(v):
    """root below the chest, spine above, a 2 dm linear blend; leg below the hip."""
    y = v[:, 1]
    spine = np.clip((y - (CHEST - 1)) / 2.0, 0, 1)
    leg = np.clip(((HIP - 1) - y) / 2.0, 0, 1)
    root = 1 - spine - leg
    return {"root": root, "spine": spine, "leg": leg}


@pytest.fixture()
def mh_files(tmp_path):
    v, quads = _cylinder()
    markers = np.array([[0, HIP, 0], [0, CHEST, 0], [0, TOP, 0], [0, 0.0, 0]])
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.concatenate([v, markers])]
    lines.append("g body")
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in q) for q in quads]
    nv = len(v)
    lines.append("g joint-markers")  # helper geometry, not skin
    lines.append(f"f {nv + 1} {nv + 2} {nv + 3}")
    obj = tmp_path / "body.obj"
    obj.write_text("\n".join(lines) + "\n")
    joints = {"hip": [nv], "chest": [nv + 1], "top": [nv + 2], "floor": [nv + 3]}
    bones = {"root": {"head": "hip", "tail": "chest", "parent": None},
             "spine": {"head": "chest", "tail": "top", "parent": "root"},
             "leg": {"head": "hip", "tail": "floor", "parent": "root"}}
    skel = tmp_path / "body.mhskel"
    skel.write_text(json.dumps({"bones": bones, "joints": joints}))
    w = _weights(v)
    mhw = tmp_path / "body.mhw"
    mhw.write_text(json.dumps({"weights": {b: [[i, float(x)] for i, x in enumerate(w[b]) if x > 0] for b in w}}))
    return obj, skel, mhw, v * 0.1


BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0.85 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 0.35 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0.5 0
    }
  }
  JOINT Leg
  {
    OFFSET 0 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -0.85 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0416667
0 0 0 0 0 0 0 0 0 0 0 0
0 0 0 0 0 0 90 0 0 0 0 0
0.2 0 0 0 0 0 0 0 0 0 0 0
"""


def _avatar(points_m, tmp_path, seed=0):
    """Gaussians on the cylinder's surface (metres), written as a PLY."""
    rng = np.random.default_rng(seed)
    n = 600
    ang = rng.uniform(0, 2 * np.pi, n)
    y = rng.uniform(0.0, TOP * 0.1, n)
    r = RADIUS * 0.1 * rng.uniform(0.97, 1.0, n)
    pos = np.stack([r * np.cos(ang), y, r * np.sin(ang)], axis=1)
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    g = GaussianSet(pos, q, np.full((n, 3), 0.01), np.full(n, 0.9), np.zeros((n, 1, 3)), label="avatar")
    path = tmp_path / "avatar.ply"
    write_ply(path, g)
    return g, path


def test_makehuman_reader(mh_files):
    obj, skel, mhw, v_m = mh_files
    rig = load_makehuman(obj, skel, mhw)
    assert rig.bones == ["root", "spine", "leg"] and list(rig.parents) == [-1, 0, 0]
    assert rig.faces.shape[0] == 2 * 24 * 34  # quads split, helper group dropped
    np.testing.assert_allclose(rig.heads[1], [0, CHEST * 0.1, 0], atol=1e-12)
    np.testing.assert_allclose(rig.weights.sum(axis=1), 1.0, atol=1e-6)
    w = _weights(v_m * 10)
    dense = np.zeros((len(v_m), 3))
    k = rig.joint_indices.shape[1]
    np.add.at(dense, (np.repeat(np.arange(len(v_m)), k), rig.joint_indices[: len(v_m)].reshape(-1)),
              rig.weights[: len(v_m)].reshape(-1))
    np.testing.assert_allclose(dense, np.stack([w["root"], w["spine"], w["leg"]], axis=1), atol=1e-6)


def test_bvh_reader(tmp_path):
    p = tmp_path / "m.bvh"
    p.write_text(BVH)
    b = read_bvh(p)
    assert b.names == ["Hips", "Chest", "Leg"] and list(b.parents) == [-1, 0, 0] and b.num_frames == 3
    g = b.global_transforms()
    # frame 1: chest turned 90 degrees about +Z: its local +Y points to -X
    np.testing.assert_allclose(g[1, 1, :3, :3] @ [0, 1, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(g[2, 0, :3, 3], [0.2, 0.85, 0], atol=1e-12)
    np.testing.assert_allclose(b.end_offsets[1], [0, 0.5, 0])


def test_rig_end_to_end(mh_files, tmp_path):
    obj, skel, mhw, v_m = mh_files
    g, ply = _avatar(v_m, tmp_path)
    bvh = tmp_path / "m.bvh"
    bvh.write_text(BVH)
    out = tmp_path / "rigged.usda"
    rc = main(["rig", str(ply), "--skin", str(obj), "--skeleton", str(skel), "--weights", str(mhw),
               "--motion", str(bvh), "--joint-map", "Hips:root,Chest:spine,Leg:leg", "--facing", "+z",
               "--align-matrix", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "-o", str(out), "-q"])
    assert rc == 0
    stage = Usd.Stage.Open(str(out))
    assert stage.GetStartTimeCode() == 1 and stage.GetEndTimeCode() == 3
    prim = stage.GetPrimAtPath("/Avatar/Gaussians")
    assert prim.HasAPI(UsdSkel.BindingAPI) and stage.GetPrimAtPath("/Avatar").IsA(UsdSkel.Root)
    rest = read_gaussian_prim(prim, 1, skin=False)
    np.testing.assert_allclose(rest.positions, g.positions, atol=1e-6)
    sq = UsdSkel.Cache()
    sq.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Avatar")), Usd.PrimDefaultPredicate)
    idx, w = sq.GetSkinningQuery(prim).ComputeJointInfluences()
    k = 4
    idx, w = np.array(idx).reshape(-1, k), np.array(w).reshape(-1, k)
    dense = np.zeros((g.count, 3))
    np.add.at(dense, (np.repeat(np.arange(g.count), k), idx.reshape(-1)), w.reshape(-1))
    # weights transferred from the surface: the analytic weights at each Gaussian's height
    expect = _weights(np.asarray(g.positions, np.float64) * 10)
    np.testing.assert_allclose(dense, np.stack([expect["root"], expect["spine"], expect["leg"]], axis=1), atol=0.02)
    # frame 1: rest; frame 2: spine turned 90 degrees about +Z around the chest joint; frame 3: moved +0.2 x
    p = g.positions.astype(np.float64)
    f1 = read_gaussian_prim(prim, 1).positions
    np.testing.assert_allclose(f1, p, atol=1e-5)
    rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    h = np.array([0, CHEST * 0.1, 0])
    want = dense[:, :1] * p + dense[:, 2:3] * p + dense[:, 1:2] * ((p - h) @ rz.T + h)
    np.testing.assert_allclose(read_gaussian_prim(prim, 2).positions, want, atol=1e-5)
    np.testing.assert_allclose(read_gaussian_prim(prim, 3).positions, p + [0.2, 0, 0], atol=1e-5)


def test_rig_automatic_alignment_recovers_a_similarity(mh_files, tmp_path):
    from usd_gs.demo.rig import align_to_mesh, makehuman_source

    obj, skel, mhw, v_m = mh_files
    src = makehuman_source(obj, skel, mhw)
    g, _ = _avatar(v_m, tmp_path, seed=2)
    # the capture: half size, Z-up, shifted
    m = np.array([[0.5, 0, 0, 0.3], [0, 0, -0.5, -0.1], [0, 0.5, 0, 2.0], [0, 0, 0, 1]])
    cap = g.transformed(m.T)
    fit, info = align_to_mesh(cap, src.vertices, up="+z", facing="+z", faces=src.faces)
    back = cap.positions.astype(np.float64) @ fit[:3, :3].T + fit[:3, 3]
    assert abs(info["scale"] - 2.0) < 0.02
    # radial distance from the axis and height are recovered (the cylinder's spin about Y is free)
    np.testing.assert_allclose(back[:, 1], g.positions[:, 1], atol=0.01)
    np.testing.assert_allclose(np.hypot(back[:, 0], back[:, 2]), np.hypot(g.positions[:, 0], g.positions[:, 2]),
                               atol=0.01)


def test_rig_bad_input(mh_files, tmp_path, capsys):
    obj, skel, mhw, v_m = mh_files
    _, ply = _avatar(v_m, tmp_path)
    bvh = tmp_path / "m.bvh"
    bvh.write_text(BVH.replace("Hips", "Pelvis").replace("Chest", "Torso").replace("Leg", "Thigh"))
    base = ["rig", str(ply), "--skin", str(obj), "--skeleton", str(skel), "--weights", str(mhw),
            "-o", str(tmp_path / "o.usda")]
    assert main(base + ["--motion", str(bvh)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "BVH joint 'Pelvis'" in err[0] and "--joint-map" in err[0]
    assert main(base + ["--motion", str(bvh), "--joint-map", "Pelvis:root,Neck:spine"]) == 2
    assert "joint-map BVH joint 'Neck' is not in the BVH" in capsys.readouterr().err
    assert main(base[:4] + ["-o", str(tmp_path / "o.usda")]) == 2
    assert "--skeleton" in capsys.readouterr().err
    with pytest.raises(UserError, match=r"bad.bvh: line 4: OFFSET values"):
        bad = tmp_path / "bad.bvh"
        bad.write_text("HIERARCHY\nROOT A\n{\n  OFFSET 0 zero 0\n}\nMOTION\n")
        read_bvh(bad)
