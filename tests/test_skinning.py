"""Skinned Gaussian prims: numba kernel vs numpy reference, LBS positions vs UsdSkel.BakeSkinning,
SH rotation vs sh3dgs.rotate_coefficients, bad bindings (usd_gs.usd.skel)."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from numba_kernels.reference.skinning import skin_gaussians as skin_reference
from numba_kernels.skinning import skin_gaussians
from usd_gs import sh3dgs
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet, quaternion_to_matrix
from usd_gs.usd import skel as uskel
from usd_gs.usd.gaussian_prim import describe_gaussian_prim, read_gaussian_prim, write_gaussian_prim
from usd_gs.usd.skel_bake import bake_skinning

JOINTS = ["hip", "hip/knee", "hip/knee/ankle", "hip/other"]


def _rot(axis, deg):
    return np.array(Gf.Matrix3d(Gf.Rotation(Gf.Vec3d(*axis), deg)), np.float64).T  # column-vector


def _mat(r=None, t=(0, 0, 0), s=1.0):
    m = np.eye(4)
    m[:3, :3] = s * (np.eye(3) if r is None else np.asarray(r))
    m[:3, 3] = t
    return m


def random_gaussians(n, degree, seed=0, label="g"):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-0.5, 0.5, (n, 3)) + [0, 1.0, 0]
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    sc = rng.uniform(0.01, 0.05, (n, 3))
    sh = rng.normal(size=(n, sh3dgs.num_coeffs(degree), 3)) * 0.3
    return GaussianSet(pos, q, sc, rng.uniform(0.2, 1, n), sh, label=label)


def random_influences(n, k, j, seed=1):
    rng = np.random.default_rng(seed)
    idx = np.stack([rng.permutation(j)[:k] for _ in range(n)]).astype(np.int32)
    w = rng.uniform(0.05, 1, (n, k))
    w /= w.sum(axis=1, keepdims=True)
    return idx, w.astype(np.float32)


def build_stage(n=300, k=3, degree=2, with_anim=True, prim_joints=None, geom_bind=None, seed=0, method=None):
    """SkelRoot /Root with a translated+rotated Skeleton, a 3-sample SkelAnimation, a bound Gaussian
    prim /Root/GS and a Mesh /Root/Mesh with the same points and influences."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    root = UsdSkel.Root.Define(stage, "/Root")
    UsdGeom.Xformable(root).AddTranslateOp().Set(Gf.Vec3d(0.3, 0.0, -0.2))
    rest_local = np.stack([_mat(t=(0, 1, 0)), _mat(t=(0, -0.5, 0)), _mat(t=(0, -0.4, 0)), _mat(t=(0.2, 0, 0))])
    bind = np.stack([rest_local[0], rest_local[0] @ rest_local[1], rest_local[0] @ rest_local[1] @ rest_local[2],
                     rest_local[0] @ rest_local[3]])
    sk = uskel.author_skeleton(stage, "/Root/Skel", JOINTS, bind, rest_local)
    UsdGeom.Xformable(sk).AddRotateYOp().Set(30.0)
    if with_anim:
        times = [1.0, 2.0, 3.0]
        tr = np.broadcast_to(rest_local[:, :3, 3], (3, 4, 3)).copy()
        tr[:, 0] += np.array([[0, 0, 0], [0.1, 0.05, 0], [0.2, 0, 0.1]])
        rots = []
        for f in range(3):
            rs = [_rot((0, 1, 0), 10 * f), _rot((1, 0, 0), 35 * f), _rot((0, 0, 1), -50 * f), _rot((1, 1, 0), 20 * f)]
            from usd_gs.gaussians import matrix_to_quaternion
            rots.append(matrix_to_quaternion(np.stack(rs)))
        uskel.author_animation(stage, "/Root/Skel/Anim", sk, JOINTS, times, tr, np.stack(rots),
                               scales=np.full((3, 4, 3), 1.0))
    g = random_gaussians(n, degree, seed)
    prim = write_gaussian_prim(stage, "/Root/GS", g)
    idx, w = random_influences(n, k, 4, seed + 1)
    gb = geom_bind if geom_bind is not None else _mat(_rot((0, 0, 1), 5), (0.01, 0.02, 0.0), 1.1)
    uskel.bind_prim(prim, sk, idx, w, geom_bind=gb, joints=prim_joints)
    mesh = UsdGeom.Mesh.Define(stage, "/Root/Mesh")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(g.positions))
    mesh.CreateFaceVertexCountsAttr([3] * (n // 3))
    mesh.CreateFaceVertexIndicesAttr(list(range(3 * (n // 3))))
    uskel.bind_prim(mesh.GetPrim(), sk, idx, w, geom_bind=gb, joints=prim_joints)
    if method is not None:
        for p in (prim, mesh.GetPrim()):
            UsdSkel.BindingAPI(p).CreateSkinningMethodAttr().Set(method)
    return stage, g, idx, w


def _baked_mesh_points(stage, times):
    """World points of /Root/Mesh after UsdSkel.BakeSkinning (which turns the SkelRoot into a plain Xform)."""
    assert UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetPrimAtPath("/Root")), Gf.Interval(1, 3))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    out = {}
    for t in times:
        local = np.array(mesh.GetPointsAttr().Get(t), np.float64)
        m = np.array(mesh.ComputeLocalToWorldTransform(t))
        out[t] = local @ m[:3, :3] + m[3, :3]
    return out


@pytest.mark.parametrize("prim_joints", [None, ["hip/other", "hip/knee/ankle", "hip", "hip/knee"]])
def test_positions_match_bake_skinning(prim_joints):
    stage, g, idx, w = build_stage(prim_joints=prim_joints)
    prim = stage.GetPrimAtPath("/Root/GS")
    skinned = {t: read_gaussian_prim(prim, t) for t in (1.0, 2.0, 3.0)}
    baked = _baked_mesh_points(stage, (1.0, 2.0, 3.0))
    for t in (1.0, 2.0, 3.0):
        ref = baked[t]
        err = np.abs(skinned[t].positions.astype(np.float64) - ref).max()
        assert err < 1e-5, (t, err)
    # the frames really move
    assert np.abs(skinned[3.0].positions - skinned[1.0].positions).max() > 0.1


def test_kernel_matches_reference_and_sh_rotation():
    stage, g, idx, w = build_stage(n=200, k=3, degree=3)
    prim = stage.GetPrimAtPath("/Root/GS")
    rest = read_gaussian_prim(prim, 3.0, skin=False, world=False)
    b = uskel.evaluate_binding(prim, rest.count, 3.0)
    dirs, pinv = uskel.sh_rotation_tables(3)
    args = (rest.positions, rest.orientations, rest.scales, rest.sh, b.joint_indices, b.weights, b.skinning)
    got = skin_gaussians(*[np.ascontiguousarray(a) for a in args], dirs, pinv)
    ref = skin_reference(*args, dirs, pinv)
    pos, quat, sc, sh, rot = got
    np.testing.assert_allclose(pos, ref[0], atol=2e-6)
    np.testing.assert_allclose(np.abs(np.sum(quat * ref[1], axis=1)), 1.0, atol=2e-6)
    np.testing.assert_allclose(sc, ref[2], rtol=2e-6)
    np.testing.assert_allclose(sh, ref[3], atol=2e-5)
    np.testing.assert_allclose(rot, ref[4], atol=2e-6)
    # rotation is orthonormal, proper; quaternion = R * q_rest
    np.testing.assert_allclose(np.einsum("nji,njk->nik", rot, rot), np.broadcast_to(np.eye(3), rot.shape), atol=1e-5)
    expect = np.einsum("nij,njk->nik", rot.astype(np.float64), quaternion_to_matrix(rest.orientations))
    np.testing.assert_allclose(quaternion_to_matrix(quat), expect, atol=1e-5)
    # SH of each Gaussian = sh3dgs.rotate_coefficients with its own rotation
    for i in (0, 7, 123):
        one = sh3dgs.rotate_coefficients(rest.sh[i:i + 1], rot[i].astype(np.float64))
        np.testing.assert_allclose(sh[i], one[0], atol=2e-5)
    # uniform scale: geomBind scale 1.1 and rigid joints -> polar scale 1.1 where one joint dominates
    one_joint = b.weights.max(axis=1) > 0.999
    assert not one_joint.any() or np.allclose(sc[one_joint] / rest.scales[one_joint], 1.1, rtol=1e-5)


def test_rigid_single_joint_equals_transform():
    """One influence per particle: skinning is the joint's rigid transform (GaussianSet.transformed)."""
    g = random_gaussians(50, 3, seed=4)
    m = _mat(_rot((1, 2, 3), 70), (0.5, -0.2, 1.0), 1.3)
    got = uskel.skin_gaussian_set(g, uskel.SkinBinding(np.zeros((50, 1), np.int32), np.ones((50, 1), np.float32),
                                                       m[None], "", "", "classicLinear", None))
    want = g.transformed(m.T)
    np.testing.assert_allclose(got.positions, want.positions, atol=1e-5)
    np.testing.assert_allclose(got.scales, want.scales, rtol=1e-5)
    np.testing.assert_allclose(np.abs(np.sum(got.orientations * want.orientations, axis=1)), 1.0, atol=1e-5)
    np.testing.assert_allclose(got.sh, want.sh, atol=1e-4)


def test_describe_reports_animation():
    stage, *_ = build_stage()
    info = describe_gaussian_prim(stage.GetPrimAtPath("/Root/GS"), 2.0)
    assert info.animated and info.time_samples == (1.0, 3.0)
    g = read_gaussian_prim(stage.GetPrimAtPath("/Root/GS"), 2.0)
    lo, hi = info.world_bounds
    assert np.all(g.positions >= lo - 1e-6) and np.all(g.positions <= hi + 1e-6)
    assert np.all(hi - lo < (g.positions.max(0) - g.positions.min(0)) + 0.5)


def _expect_error(stage, pattern):
    with pytest.raises(UserError, match=pattern):
        read_gaussian_prim(stage.GetPrimAtPath("/Root/GS"), 2.0)


def test_bad_bindings():
    stage, g, idx, w = build_stage()
    attr = stage.GetPrimAtPath("/Root/GS").GetAttribute(uskel.JOINT_WEIGHTS)
    bad = w.copy()
    bad[5, 0] += 0.01
    attr.Set(Vt.FloatArray.FromNumpy(bad.reshape(-1)))
    _expect_error(stage, r"/Root/GS.*primvars:skel:jointWeights' particle 5 .*sums to 1.01")

    stage, g, idx, w = build_stage()
    bad = idx.copy()
    bad[7, 1] = 9
    stage.GetPrimAtPath("/Root/GS").GetAttribute(uskel.JOINT_INDICES).Set(Vt.IntArray.FromNumpy(bad.reshape(-1)))
    _expect_error(stage, r"/Root/GS.*jointIndices' element 22 \(particle 7\) is 9")

    stage, *_ = build_stage()
    stage.GetPrimAtPath("/Root/GS").GetAttribute(uskel.JOINT_INDICES).Set(Vt.IntArray([0, 1, 2]))
    _expect_error(stage, r"jointIndices' has 3 elements")

    stage, *_ = build_stage(with_anim=False)
    _expect_error(stage, r"/Root/GS.*Skeleton /Root/Skel has no animation")


def test_blocked_binding_reads_unskinned():
    stage, g, *_ = build_stage()
    prim = stage.GetPrimAtPath("/Root/GS")
    prim.GetRelationship("skel:skeleton").SetTargets([])
    got = read_gaussian_prim(prim, 2.0)
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(2.0))
    np.testing.assert_allclose(got.positions, g.positions @ m[:3, :3] + m[3, :3], atol=1e-6)


def test_no_skel_root_is_an_error():
    stage, *_ = build_stage()
    # a second prim bound outside the SkelRoot
    g = random_gaussians(10, 0)
    prim = write_gaussian_prim(stage, "/Outside/GS", g)
    uskel.bind_prim(prim, UsdSkel.Skeleton(stage.GetPrimAtPath("/Root/Skel")), np.zeros((10, 1)), np.ones((10, 1)))
    with pytest.raises(UserError, match=r"/Outside/GS.*no SkelRoot"):
        read_gaussian_prim(prim, 1.0)
    assert Sdf.Path("/Outside/GS")


def test_validate_reports_binding_problems():
    from usd_gs.usd.validate import validate_prim

    stage, g, idx, w = build_stage()
    prim = stage.GetPrimAtPath("/Root/GS")
    assert [p for p in validate_prim(prim) if p.attribute.startswith(("skel", "primvars:skel"))] == []
    bad = w.copy()
    bad[3] *= 0.5
    prim.GetAttribute(uskel.JOINT_WEIGHTS).Set(Vt.FloatArray.FromNumpy(bad.reshape(-1)))
    probs = [p for p in validate_prim(prim) if p.attribute == uskel.JOINT_WEIGHTS]
    assert len(probs) == 1 and probs[0].element == 9 and "particle 3" in probs[0].message


def test_cli_exit_2_on_bad_binding(tmp_path, capsys):
    from usd_gs.cli import main

    stage, g, idx, w = build_stage()
    bad = idx.copy()
    bad[0, 0] = -1
    stage.GetPrimAtPath("/Root/GS").GetAttribute(uskel.JOINT_INDICES).Set(Vt.IntArray.FromNumpy(bad.reshape(-1)))
    path = tmp_path / "bad.usda"
    stage.GetRootLayer().Export(str(path))
    out = tmp_path / "f.ply"
    rc = main(["export", str(path), "--prim", "/Root/GS", "--time", "2", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert "/Root/GS" in err[0] and "primvars:skel:jointIndices' element 0" in err[0] and "is -1" in err[0]


def test_bake_skinning_into_an_output_layer(tmp_path):
    """``bake_skinning`` in a layer over the input: every reader then sees the baked frames (the
    binding is blocked), equal to the skinned evaluation; the input layer is untouched."""
    stage, g, idx, w = build_stage(degree=1)
    src = tmp_path / "in.usda"
    stage.GetRootLayer().Export(str(src))
    src_stage = Usd.Stage.Open(str(src))
    want = {t: read_gaussian_prim(src_stage.GetPrimAtPath("/Root/GS"), t) for t in (1.0, 3.0)}
    out = Sdf.Layer.CreateNew(str(tmp_path / "out.usda"))
    out.subLayerPaths = [str(src)]
    st = Usd.Stage.Open(out)
    assert bake_skinning(st, "/Root/GS", [1.0, 2.0, 3.0]) == 3
    out.Save()
    baked = Usd.Stage.Open(str(tmp_path / "out.usda"))
    prim = baked.GetPrimAtPath("/Root/GS")
    assert not uskel.has_skel_binding(prim)
    assert prim.GetAttribute("positions").GetTimeSamples() == [1.0, 2.0, 3.0]
    for t, ref in want.items():
        got = read_gaussian_prim(prim, t)
        np.testing.assert_allclose(got.positions, ref.positions, atol=1e-5)
        np.testing.assert_allclose(got.sh, ref.sh, atol=1e-5)
        np.testing.assert_allclose(np.abs(np.sum(got.orientations * ref.orientations, axis=1)), 1.0, atol=1e-5)
    assert uskel.has_skel_binding(src_stage.GetPrimAtPath("/Root/GS"))


@pytest.mark.parametrize("prim_joints", [None, ["hip/other", "hip/knee/ankle", "hip", "hip/knee"]])
def test_dual_quaternion_positions_match_bake_skinning(prim_joints):
    """primvars:skel:skinningMethod dualQuaternion: centres equal UsdSkel's own DQS of the same points
    (BakeSkinning of the Mesh); the orientation is the rotation of the Gaussian's DQS affine map."""
    stage, g, idx, w = build_stage(prim_joints=prim_joints, method=UsdSkel.Tokens.dualQuaternion, degree=1)
    prim = stage.GetPrimAtPath("/Root/GS")
    skinned = {t: read_gaussian_prim(prim, t) for t in (1.0, 2.0, 3.0)}
    lbs = uskel.skin_gaussian_set(read_gaussian_prim(prim, 3.0, skin=False, world=False),
                                  uskel.SkinBinding(*[getattr(uskel.evaluate_binding(prim, g.count, 3.0), f)
                                                      for f in ("joint_indices", "weights", "skinning", "skeleton",
                                                                "animation", "method", "time_range")]))
    b = uskel.evaluate_binding(prim, g.count, 3.0)
    assert b.method == "dualQuaternion"
    rest = read_gaussian_prim(prim, 3.0, skin=False, world=False)
    lo, hi = describe_gaussian_prim(prim, 3.0).world_bounds
    assert np.all(skinned[3.0].positions >= lo - 1e-6) and np.all(skinned[3.0].positions <= hi + 1e-6)
    baked = _baked_mesh_points(stage, (1.0, 2.0, 3.0))
    for t in (1.0, 2.0, 3.0):
        err = np.abs(skinned[t].positions.astype(np.float64) - baked[t]).max()
        assert err < 1e-5, (t, err)
    assert np.abs(lbs.positions - skinned[3.0].positions).max() > 1e-3  # DQS is not LBS here
    # rotation part of the DQS map: a finite difference of the skinned centres along the rest axes
    eps = 1e-4
    jac = np.stack([(uskel.dq_positions(rest.positions + eps * e, b.joint_indices, b.weights, b.dual)
                     - uskel.dq_positions(rest.positions - eps * e, b.joint_indices, b.weights, b.dual)) / (2 * eps)
                    for e in np.eye(3)], axis=2)
    u, _, vt = np.linalg.svd(jac)
    rot = u @ vt
    want = np.einsum("nij,njk->nik", rot, quaternion_to_matrix(rest.orientations))
    np.testing.assert_allclose(quaternion_to_matrix(skinned[3.0].orientations), want, atol=2e-4)


def test_dual_quaternion_kernel_matches_reference():
    stage, g, idx, w = build_stage(n=150, k=3, degree=3, method=UsdSkel.Tokens.dualQuaternion)
    prim = stage.GetPrimAtPath("/Root/GS")
    rest = read_gaussian_prim(prim, 3.0, skin=False, world=False)
    b = uskel.evaluate_binding(prim, rest.count, 3.0)
    dirs, pinv = uskel.sh_rotation_tables(3)
    args = (rest.positions, rest.orientations, rest.scales, rest.sh, b.joint_indices, b.weights, b.skinning)
    got = skin_gaussians(*[np.ascontiguousarray(a) for a in args], dirs, pinv, b.dual)
    ref = skin_reference(*args, dirs, pinv, b.dual)
    np.testing.assert_allclose(got[0], ref[0], atol=2e-6)
    np.testing.assert_allclose(np.abs(np.sum(got[1] * ref[1], axis=1)), 1.0, atol=2e-6)
    np.testing.assert_allclose(got[2], ref[2], rtol=2e-6)
    np.testing.assert_allclose(got[3], ref[3], atol=2e-5)
    np.testing.assert_allclose(got[0], uskel.dq_positions(rest.positions.astype(np.float64), b.joint_indices,
                                                          b.weights, b.dual), atol=2e-6)
