"""The measurements behind the relighting and 4.1-metric choices of the parallax probes and
``usd_gs.evaluation.lighting_metrics`` (each printed with what it supports).

Usage (from the repo root; ../shared/data present; the demo stage is generated if missing):

    PYTHONPATH=. .venv/bin/python benchmarks/bench_lighting_limits.py [--skip-demo]

1. occlusion test of the parallax probes: known-light ground truth PSNR (default size, the four
   scenes props+lamp / lamp / props / neither) without it, with z-buffer sizes 16 / 32 / 64, and
   with every texel drawn as a disc (no grazing cut-off);
2. the ground truth's lamp drawn alone at 32^2: its irradiance at the avatar centroid against
   ``L pi R^2 / d^2``, supersampled 1x and 2x;
3. APF-Y of the exact known-light colours (props scene): with ``c_scene``, with the avatar's own
   exact order-3 irradiance, and for an avatar "as captured" under a studio key light;
4. demo: PAA-Y of CesiumMan with the room's own shading model applied to it (the exact lighting)
   at frames 1, 13, 25, 37 (SH rank of the neighbourhood printed), and milliseconds per relit
   prim at frame 1 of ``reprojected_probes`` with and without the occlusion test and of the
   probe render supersampled 1x and 2x.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def occlusion_ablation() -> None:
    from usd_gs.evaluation.relight_groundtruth import relight_ground_truth
    from usd_gs.relight import avatar
    from usd_gs.relight import parallax as pp

    scenes = ((True, True), (False, True), (True, False), (False, False))

    def run() -> list[float]:
        return [relight_ground_truth(lamp=lamp, props=props, metrics=False)["psnr_relit"] for props, lamp in scenes]

    print("1. parallax occlusion test, relit PSNR dB (props+lamp / lamp / props / neither)")
    reproject, default_cos = pp.reprojected_probes, pp._MIN_SPLAT_COS
    try:  # the main job's code path: usd_gs.relight.avatar calls its own import of reprojected_probes
        for label, size, cos in (("none", None, default_cos), ("z-buffer 16", 16, default_cos),
                                 ("z-buffer 32 (default)", 32, default_cos), ("z-buffer 64", 64, default_cos),
                                 ("32, every texel a disc", 32, -2.0)):
            avatar.reprojected_probes = lambda tex, pts, degree, _s=size: reproject(tex, pts, degree,
                                                                                    occlusion_size=_s)
            pp._MIN_SPLAT_COS = cos
            print(f"   {label:<24}" + " / ".join(f"{v:.2f}" for v in run()))
    finally:
        avatar.reprojected_probes, pp._MIN_SPLAT_COS = reproject, default_cos


def lamp_energy() -> None:
    import trimesh

    from numba_kernels.cubemap_dirs import cube_face_directions, cube_face_solid_angles
    from usd_gs.demo.mesh_avatar import gaussians_on_mesh, sample_surface
    from usd_gs.relight.probe import render_probe_faces

    lamp, radius = np.array([3.0, 3.2, 2.5]), 0.3
    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    f, b = sample_surface(ball.vertices, ball.faces, 1500, 1)
    g = gaussians_on_mesh(np.asarray(ball.vertices) + lamp, ball.faces, ball.vertex_normals, f, b, np.ones(3),
                          opacity=0.99)
    c = np.array([0.0, 0.9, 0.0])
    exact = np.pi * radius ** 2 / float(np.sum((lamp - c) ** 2))
    d = cube_face_directions(32)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    print("2. the ground truth's lamp alone, rendered irradiance / exact at the centroid (32^2 faces)")
    for k in (1, 2):
        rgb, _, _ = render_probe_faces(g, c, 32, supersample=k)
        e = np.linalg.norm(((rgb[..., 0] * cube_face_solid_angles(32))[..., None] * d).sum(axis=(0, 1, 2)))
        print(f"   supersample {k}: {e / exact:.3f}")


def apf_limits() -> None:
    from usd_gs import sh3dgs
    from usd_gs.evaluation import relight_groundtruth as gt
    from usd_gs.evaluation.colorimetry import luminance
    from usd_gs.evaluation.lighting_metrics import apf_y, fit_factorization, lighting_consistency, pseudo_normals
    from usd_gs.gaussians import quaternion_to_matrix

    scene = gt.make_scene(12000, (16, 32), props=True)
    av = gt.make_avatar(4000)
    alb = 0.5 + sh3dgs.C0 * av.sh[:, 0, :].astype(np.float64)
    truth = gt.avatar_ground_truth(scene, av, alb, oversample=2)
    exact = av.with_label("exact")
    exact.sh = ((truth - 0.5) / sh3dgs.C0)[:, None, :].astype(np.float32)
    print("3. APF-Y (lower is better) in the known-light scene with props, default size")
    m = lighting_consistency(av, exact, scene.visible)
    print(f"   unlit albedo {m['orig']['apf_y']:.3f}, exact colours {m['relit']['apf_y']:.3f} (with c_scene)")
    n_true = quaternion_to_matrix(av.orientations)[:, :, 2].astype(np.float64)
    c_own = fit_factorization(luminance(truth) / luminance(alb), n_true, alpha_prior=np.inf).coeffs
    for name, nrm in (("pseudo-normals", pseudo_normals(av)), ("mesh normals", n_true)):
        print(f"   with the avatar's own exact order-3 irradiance, {name}: unlit "
              f"{apf_y(luminance(alb), nrm, c_own)[0]:.3f}, exact {apf_y(luminance(truth), nrm, c_own)[0]:.3f}")
    key = np.array([-0.5, 0.6, 0.8]) / np.linalg.norm([-0.5, 0.6, 0.8])
    captured = np.clip(alb * (0.35 + 0.9 * np.maximum(n_true @ key, 0.0))[:, None], 0.0, 1.0)
    cap = av.with_label("captured")
    cap.sh = ((captured - 0.5) / sh3dgs.C0)[:, None, :].astype(np.float32)
    m = lighting_consistency(cap, exact, scene.visible)
    print(f"   orig as captured under a studio key light {m['orig']['apf_y']:.3f}, exact colours "
          f"{m['relit']['apf_y']:.3f}")


def demo_limits() -> None:
    from pxr import Usd

    from numba_kernels.normals import gaussian_normals
    from usd_gs import sh3dgs
    from usd_gs.cli.process import is_missing_demo, make_missing_demo
    from usd_gs.evaluation.colorimetry import luminance
    from usd_gs.evaluation.lighting_metrics import (
        PAA_MIN_RANK,
        fit_factorization,
        gaussian_colors,
        paa_y,
        pseudo_normals,
        scene_lighting,
    )
    from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
    from usd_gs.relight.parallax import ProbeBlend, cube_texels, reprojected_probes
    from usd_gs.relight.probe import render_probe_faces
    from usd_gs.usd.gaussian_prim import find_gaussian_prims, read_gaussian_prim
    from usd_gs.usd.stage import open_stage

    path = "stages/demo.usda"
    if is_missing_demo(path):
        make_missing_demo(path)
    st = open_stage(path)
    world = st.GetPrimAtPath("/World")
    lamps = [np.array(world.GetCustomDataByKey(f"usdgs:demo:{k}")) for k in
             ("lampPositions", "lampColors", "lampIntensities")]
    prims = {p.GetPath().pathString: p for p in find_gaussian_prims(st)}
    room = GaussianSet.concatenate([read_gaussian_prim(p, Usd.TimeCode.EarliestTime()) for k, p in prims.items()
                                    if k.startswith("/World/Room")], label="room")
    print("4. demo: CesiumMan with the room's own shading model (ambient 0.2 + lamps, no shadows), PAA-Y")
    for f in (1, 13, 25, 37):
        g = read_gaussian_prim(prims["/World/CesiumMan"], Usd.TimeCode(f))
        n = gaussian_normals(g.positions, g.orientations, g.scales, g.opacities).astype(np.float64)
        alb = 0.5 + sh3dgs.C0 * g.sh[:, 0, :].astype(np.float64)
        p = g.positions.astype(np.float64)
        irr = np.full_like(alb, 0.2)
        for pos, col, inten in zip(*lamps, strict=True):
            d = pos - p
            r2 = np.einsum("ij,ij->i", d, d)
            irr += (inten * np.maximum(np.einsum("ij,ij->i", n, d) / np.sqrt(r2), 0.0) / r2)[:, None] * col
        lit = g.with_label("room-lit")
        lit.sh = g.sh.copy()
        lit.sh[:, 0, :] = ((np.clip(alb * irr, 0.0, 1.0) - 0.5) / sh3dgs.C0).astype(np.float32)
        sc = scene_lighting(room, alpha_weighted_centroid(g))
        nrm = pseudo_normals(g)
        # the restricted comparison itself, also where the metric reports n/a (rank < PAA_MIN_RANK)
        vals = [paa_y(fit_factorization(luminance(gaussian_colors(h)), nrm).coeffs, sc.fit.coeffs, sc.normals)
                for h in (g, lit)]
        note = "" if sc.sh_rank >= PAA_MIN_RANK else f" (below rank {PAA_MIN_RANK}: reported n/a)"
        print(f"   frame {f}: SH rank {sc.sh_rank}, unlit {vals[0]:.3f}, room-lit {vals[1]:.3f}{note}")
    print("   frame 1, ms per relit prim: reprojected_probes (8 points) without / with the occlusion test; "
          "probe render supersampled 1x / 2x")
    gs = {k: read_gaussian_prim(p, Usd.TimeCode(1)) for k, p in prims.items()}
    everything = GaussianSet.concatenate(list(gs.values()))
    start = 0
    for k, g in gs.items():
        span = (start, start + g.count)
        start += g.count
        if k not in ("/World/CesiumMan", "/World/Biker", "/World/Guitar"):
            continue
        mask = np.ones(everything.count, bool)
        mask[span[0]:span[1]] = False
        c = alpha_weighted_centroid(g)
        pts = ProbeBlend.build(g.positions, 8).centres(g.positions)
        tex = cube_texels(*render_probe_faces(everything, c, 32, mask), c)
        render_ms = []
        for k_ss in (1, 2):
            render_probe_faces(everything, c, 32, mask, supersample=k_ss)
            t0 = time.perf_counter()
            for _ in range(3):
                render_probe_faces(everything, c, 32, mask, supersample=k_ss)
            render_ms.append((time.perf_counter() - t0) / 3 * 1e3)
        ms = []
        for occ in (None, 32):
            reprojected_probes(tex, pts, 4, occlusion_size=occ)
            t0 = time.perf_counter()
            for _ in range(5):
                reprojected_probes(tex, pts, 4, occlusion_size=occ)
            ms.append((time.perf_counter() - t0) / 5 * 1e3)
        print(f"   {k:<18} {ms[0]:.1f} / {ms[1]:.1f}; {render_ms[0]:.1f} / {render_ms[1]:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skip-demo", action="store_true", help="skip part 4 (the demo stage)")
    a = ap.parse_args()
    occlusion_ablation()
    lamp_energy()
    apf_limits()
    if not a.skip_demo:
        demo_limits()


if __name__ == "__main__":
    main()
