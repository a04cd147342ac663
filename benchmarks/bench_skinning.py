"""Skinning speed and accuracy of a skinned Gaussian avatar (not a test).

Avatar: ``--count`` (default 150,000) Gaussians on the surface of the MakeHuman base mesh
(``../shared/data/humans/makehuman_base.obj``, posed into the T-pose bind pose by
``usd_gs.demo.rig.makehuman_source``), 4 influences each (barycentric blend of the vertex weights,
the 4 largest kept), the 163-joint MakeHuman skeleton driven by ``cmu_131_01_scaled.bvh``
(retargeted, 24 fps), SH degree ``--degree`` (random coefficients).

Prints, per frame (median over ``--frames`` frames after one warm-up):

- ``kernel``: ``numba_kernels.skinning.skin_gaussians`` alone (positions, polar rotations,
  scales, per-band SH rotation), with the thread count numba uses;
- ``read``: ``read_gaussian_prim(prim, t)`` end to end (USD reads of the bind pose and the
  influences, UsdSkel joint matrices, validation, the kernel);
- the largest distance between the skinned centres and ``UsdSkel.BakeSkinning`` of a Mesh with
  the same points and influences (metres), over the timed frames;
- the share of Gaussians whose skinned scale differs from the rest scale by more than 20 %.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_skinning.py
    PYTHONPATH=. .venv/bin/python benchmarks/bench_skinning.py --count 150000 --degree 3 --frames 12
    PYTHONPATH=. .venv/bin/python benchmarks/bench_skinning.py --dq     # dual-quaternion skinning
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numba
import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

from usd_gs.demo.mesh_avatar import gaussians_on_mesh, sample_surface
from usd_gs.demo.rig import blend_vertex_weights, makehuman_source, retarget_bvh, stretched_share
from usd_gs.gaussians import matrix_to_quaternion
from usd_gs.io.bvh import read_bvh
from usd_gs.usd import skel as uskel
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, write_gaussian_prim

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "humans"


def build(count: int, degree: int, frames: int, seed: int = 0):
    src = makehuman_source(DATA / "makehuman_base.obj", DATA / "makehuman_default.mhskel",
                           DATA / "makehuman_default_weights.mhw")
    face, bary = sample_surface(src.vertices, src.faces, count, seed)
    normals = np.zeros_like(src.vertices)
    fn = np.cross(src.vertices[src.faces[:, 1]] - src.vertices[src.faces[:, 0]],
                  src.vertices[src.faces[:, 2]] - src.vertices[src.faces[:, 0]])
    for k in range(3):
        np.add.at(normals, src.faces[:, k], fn)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    rng = np.random.default_rng(seed)
    g = gaussians_on_mesh(src.vertices, src.faces, normals, face, bary, rng.uniform(0.2, 0.8, (count, 3)),
                          sh_degree=degree, label="/Avatar/Gaussians")
    if degree:
        g.sh[:, 1:] = rng.normal(0, 0.05, g.sh[:, 1:].shape).astype(np.float32)
    idx, w = blend_vertex_weights(src.joint_indices, src.weights, src.faces, face, bary, len(src.names), 4)
    times, local = retarget_bvh(src, read_bvh(DATA / "cmu_131_01_scaled.bvh"))
    step = max(1, len(times) // (frames + 1))
    local = local[::step][: frames + 1]
    stage = new_stage()
    root = UsdSkel.Root.Define(stage, "/Avatar")
    joints = src.joint_paths
    sk = uskel.author_skeleton(stage, "/Avatar/Skeleton", joints, src.bind, src.rest_local)
    lin = local[:, :, :3, :3]
    sc = np.linalg.norm(lin, axis=2)
    rots = matrix_to_quaternion((lin / sc[:, :, None, :]).reshape(-1, 3, 3)).reshape(len(local), len(joints), 4)
    tcs = np.arange(len(local)) + 1.0
    uskel.author_animation(stage, "/Avatar/Skeleton/Motion", sk, joints, tcs, local[:, :, :3, 3], rots, sc)
    prim = write_gaussian_prim(stage, "/Avatar/Gaussians", g, keep_raw=False)
    uskel.bind_prim(prim, sk, idx, w)
    mesh = UsdGeom.Mesh.Define(stage, "/Avatar/Mesh")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(g.positions))
    nt = count // 3
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(nt, 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.arange(3 * nt, dtype=np.int32)))
    uskel.bind_prim(mesh.GetPrim(), sk, idx, w)
    del root
    return stage, prim, g, tcs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=150_000)
    ap.add_argument("--degree", type=int, default=0)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--dq", action="store_true", help="dual-quaternion skinning (primvars:skel:skinningMethod)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    stage, prim, rest, tcs = build(args.count, args.degree, args.frames)
    if args.dq:
        for p in (prim, stage.GetPrimAtPath("/Avatar/Mesh")):
            UsdSkel.BindingAPI(p).CreateSkinningMethodAttr().Set(UsdSkel.Tokens.dualQuaternion)
    print(f"built {args.count:,} Gaussians (SH degree {args.degree}), {len(tcs)} frames in "
          f"{time.perf_counter() - t0:.1f} s; numba threads {numba.get_num_threads()}")
    read_gaussian_prim(prim, tcs[0])  # compile / warm caches
    kernel, kernel_cpu, read, skinned = [], [], [], {}
    for t in tcs[1:]:
        b = uskel.evaluate_binding(prim, rest.count, t)
        a, c = time.perf_counter(), time.process_time()
        uskel.skin_arrays(rest, b.joint_indices, b.weights, b.skinning, b.dual)
        kernel.append(time.perf_counter() - a)
        kernel_cpu.append(time.process_time() - c)
        a = time.perf_counter()
        skinned[t] = read_gaussian_prim(prim, t)
        read.append(time.perf_counter() - a)
    # CPU seconds over all threads: the wall time on an idle machine is about this / threads
    print(f"kernel: {1000 * np.median(kernel):.1f} ms/frame wall (min {1000 * min(kernel):.1f}), "
          f"{1000 * np.median(kernel_cpu):.1f} ms CPU over {numba.get_num_threads()} threads; "
          f"read_gaussian_prim: {1000 * np.median(read):.1f} ms/frame wall (min {1000 * min(read):.1f})")
    share = np.mean([stretched_share(rest, g) for g in skinned.values()])
    a = time.perf_counter()
    assert UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetPrimAtPath("/Avatar")), Gf.Interval(tcs[1], tcs[-1]))
    bake_s = time.perf_counter() - a
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Avatar/Mesh"))
    err = 0.0
    for t, g in skinned.items():
        ref = np.array(mesh.GetPointsAttr().Get(Usd.TimeCode(t)), np.float64)
        m = np.array(mesh.ComputeLocalToWorldTransform(t))
        ref = ref @ m[:3, :3] + m[3, :3]
        err = max(err, float(np.abs(g.positions.astype(np.float64) - ref).max()))
    print(f"max |centre - UsdSkel.BakeSkinning| over {len(skinned)} frames: {err:.2e} m "
          f"(BakeSkinning {bake_s:.1f} s)")
    print(f"Gaussians whose scale changes by > 20 %: {100 * share:.2f} % (mean over frames)")


if __name__ == "__main__":
    main()
