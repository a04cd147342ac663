"""DGSM speed and error on the bench scene (not a test).

Scene: ``../shared/data/splats/biker.ply`` (152,746 Gaussians, Y-up) scaled to 1.8 m tall
with its feet on the floor y = 0, centred at the origin; 1,000,000 receivers: small flat
Gaussians on a 20 x 20 m floor and four 3 m walls; a point light 2.5 m above the floor and
1 m beside the avatar's centroid.

Prints, side by side: stage timings of the default configuration, the atlas error (atlas
lookups vs the exact function at the same footprint sample points, averaged per receiver)
and the footprint-sampling error (n-sample estimate vs a 64-sample exact footprint mean), the
exact per-receiver path as the reference row, a speed/error sweep, the culling-ablation
ratios, bin-skip gain, and the scene-size independence check.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_dgsm.py            # a few minutes
    PYTHONPATH=. .venv/bin/python benchmarks/bench_dgsm.py --full     # full sweep
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba
import numpy as np
from plyfile import PlyData

from numba_kernels import cubemap, dgsm_build, dgsm_exact, dgsm_sample
from usd_gs.evaluation.ablation import timed
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import DGSMConfig, build_dgsm, footprint_samples, prepare_occluders, sample_dgsm

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load_biker(height: float = 1.8) -> GaussianSet:
    v = PlyData.read(str(DATA / "splats" / "biker.ply"))["vertex"]
    pos = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    q = np.stack([v["rot_0"], v["rot_1"], v["rot_2"], v["rot_3"]], 1)
    s = np.exp(np.stack([v["scale_0"], v["scale_1"], v["scale_2"]], 1).astype(np.float64))
    op = 1.0 / (1.0 + np.exp(-np.asarray(v["opacity"], np.float64)))
    lo, hi = np.percentile(pos[:, 1], [0.5, 99.5])
    k = height / (hi - lo)
    c = np.median(pos, axis=0)
    pos = (pos - [c[0], lo, c[2]]) * k
    return GaussianSet(pos, q, s * k, op, np.zeros((len(pos), 1, 3)), label="biker.ply")


def make_room(n: int = 1_000_000, size: float = 20.0, wall_h: float = 3.0, seed: int = 1) -> GaussianSet:
    """``n`` flat receivers on a ``size``^2 floor (y = 0) and four walls, area-proportional."""
    rng = np.random.default_rng(seed)
    a_floor, a_wall = size * size, size * wall_h
    n_floor = int(n * a_floor / (a_floor + 4 * a_wall))
    n_wall = n - n_floor
    h = size / 2
    pos = np.empty((n, 3))
    pos[:n_floor, 0] = rng.uniform(-h, h, n_floor)
    pos[:n_floor, 1] = 0.0
    pos[:n_floor, 2] = rng.uniform(-h, h, n_floor)
    wall = rng.integers(0, 4, n_wall)
    along = rng.uniform(-h, h, n_wall)
    up = rng.uniform(0, wall_h, n_wall)
    side = np.where(wall % 2 == 0, -h, h)
    pos[n_floor:, 0] = np.where(wall < 2, side, along)
    pos[n_floor:, 2] = np.where(wall < 2, along, side)
    pos[n_floor:, 1] = up
    spacing = np.sqrt((a_floor + 4 * a_wall) / n)
    scales = np.empty((n, 3))
    scales[:, 0:2] = 0.6 * spacing
    scales[:, 2] = 0.05 * spacing
    # local z = surface normal: floor normal +y (rotate -90 deg about x), walls normal x or z
    half = np.sqrt(0.5)
    q = np.zeros((n, 4))
    q[:n_floor] = [half, -half, 0, 0]
    q[n_floor:] = np.where((wall < 2)[:, None], [half, 0, half, 0], [1.0, 0, 0, 0])
    return GaussianSet(pos, q, scales, np.full(n, 0.9), np.zeros((n, 1, 3)), label="room")


def run_config(avatar, room, light, cfg, prepared, repeat=3):
    tb, cb, d = timed(build_dgsm, avatar, room, light, cfg, prepared=prepared, repeat=repeat)
    ts, cs, vals = timed(sample_dgsm, d, repeat=repeat)
    return tb, ts, d, vals, cb, cs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", action="store_true", help="full sweep (atlas 128..1024, K 16..128, samples 1..32)")
    ap.add_argument("--n-err", type=int, default=1500, help="ROI receivers used for the error figures")
    ap.add_argument("--n-err-sweep", type=int, default=400, help="ROI receivers for the sweep's error columns")
    ap.add_argument("--receivers", type=int, default=1_000_000)
    args = ap.parse_args()

    t = time.perf_counter()
    avatar = load_biker()
    room = make_room(args.receivers)
    c = (avatar.opacities.astype(np.float64) @ avatar.positions) / avatar.opacities.sum()
    light = np.array([c[0] + 1.0, 2.5, c[2]])
    print(f"scene: {avatar.count} occluders, {room.count} receivers, light {light.round(3)} "
          f"(setup {time.perf_counter() - t:.1f} s); numba threads {numba.get_num_threads()}, "
          f"load average {os.getloadavg()[0]:.2f}")
    cfg = DGSMConfig(sampling="mc", n_samples=8)  # the bench configuration (paper: MC footprint)
    paper = DGSMConfig(k_sigma=3.0, refine_contrast=None, sampling="mc", n_samples=8)
    t = time.perf_counter()
    for cc in (cfg, paper):
        dw = build_dgsm(avatar.subset(slice(0, 2000)), room.subset(slice(0, 20000)), light, cc)  # numba warm-up
        sample_dgsm(dw)
    print(f"numba warm-up {time.perf_counter() - t:.1f} s")

    tp, cp, prepared = timed(prepare_occluders, avatar, cfg)
    occ, dd, _ = prepared
    rng = np.random.default_rng(123)
    print("\nStage timings, best of 3 (wall s / process CPU s; CPU/2 ~ wall on an idle 2-core machine)")
    results = {}
    for name, cc in (("default (k_sigma=4, refine 0.1)", cfg), ("paper (k_sigma=3, plain lookup)", paper)):
        tb, ts, d, vals, cb, cs = run_config(avatar, room, light, cc, prepared)
        results[name] = (d, vals)
        a = d.atlas
        tm = d.timings
        print(f"  {name}: W={cc.atlas_size} K={cc.K} {cc.sampling} n={cc.n_samples}; ROI receivers {len(d.roi)}, "
              f"sample points {len(d.points)}, |P| {len(a.pixels)}, bins {a.kmin}..{a.kmax}, t_max {a.t_max:.3f} m, "
              f"pairs {a.pairs}, erfc evals {a.erf_evals}")
        print(f"    prepare_occluders {tp:.3f}/{cp:.3f} | build {tb:.3f}/{cb:.3f} [roi+points "
              f"{tm['roi_and_points']:.3f}, atlas {tm['atlas']:.3f}] | sampling {ts:.3f}/{cs:.3f} | "
              f"frame total {tp + tb + ts:.3f} s wall")

    # ---------------------------------------------------------------- errors
    d, vals = results["default (k_sigma=4, refine 0.1)"]
    dp, valsp = results["paper (k_sigma=3, plain lookup)"]
    sub = np.sort(rng.choice(len(d.roi), size=min(args.n_err, len(d.roi)), replace=False))
    n = cfg.n_samples
    sub_pts = d.points.reshape(len(d.roi), n, 3)[sub].reshape(-1, 3)
    t = time.perf_counter()
    ex_pts = dgsm_exact.transmittance_point(light, sub_pts, occ, dd)
    t_exact = time.perf_counter() - t
    per_recv = t_exact / len(sub)
    ex = dgsm_sample.weighted_mean(ex_pts, d.weights)
    plain_pts = dgsm_sample.lookup_point(d.atlas, light, sub_pts)
    ref_pts, refined = dgsm_sample.lookup_point_refined(d.atlas, light, sub_pts, occ, dd, cfg.refine_contrast)
    paper_pts = dgsm_sample.lookup_point(dp.atlas, light, sub_pts)
    print(f"\nErrors vs the exact function at the same sample points ({len(sub)} random ROI receivers, "
          f"{len(sub_pts)} points; shadowed fraction T<0.99: {(ex < 0.99).mean():.3f}):")
    print(f"  {'path':48s} {'recv mean':>9s} {'recv max':>9s} {'point mean':>10s} {'point max':>9s}")
    for name, vp in (("atlas discretisation alone (k=4, plain trilinear)", plain_pts),
                     (f"default: atlas + edge refinement ({refined.mean():.1%} refined)", ref_pts),
                     ("paper config (k=3, plain trilinear)", paper_pts)):
        er = np.abs(dgsm_sample.weighted_mean(vp, d.weights) - ex)
        ep = np.abs(vp - ex_pts)
        print(f"  {name:48s} {er.mean():9.5f} {er.max():9.5f} {ep.mean():10.5f} {ep.max():9.5f}")
    m_fp = min(100, len(sub))
    idx_fp = d.roi[sub[:m_fp]]
    print(f"  footprint sampling error alone (exact T; n-sample estimate vs 64-sample footprint mean, {m_fp} "
          "receivers):")
    ref_p, ref_w = footprint_samples(room, idx_fp, DGSMConfig(sampling="mc", n_samples=64, seed=99))
    ref = dgsm_sample.weighted_mean(dgsm_exact.transmittance_point(light, ref_p, occ, dd), ref_w)
    for mode, nn in (("center", 1), ("stencil7", 7), ("mc", 8), ("mc", 32)):
        p, w = footprint_samples(room, idx_fp, DGSMConfig(sampling=mode, n_samples=nn, seed=7))
        e = np.abs(dgsm_sample.weighted_mean(dgsm_exact.transmittance_point(light, p, occ, dd), w) - ref)
        print(f"    {mode:8s} n={nn:2d}: mean {e.mean():.5f} max {e.max():.5f}")

    # -------------------------------------------------------------- sweep table
    sub_s = sub[:args.n_err_sweep]
    ex_s = ex[:len(sub_s)]
    print("\nSpeed vs error (errors vs exact at the same sample points, "
          f"{len(sub_s)} receivers; times best of 2, wall s)")
    print(f"  {'config':34s} {'build':>7s} {'sample':>7s} {'mean':>8s} {'max':>8s} {'plain mean':>10s} "
          f"{'plain max':>9s}")
    print(f"  {'exact per-receiver path, mc n=8':34s} {'-':>7s} {per_recv * len(d.roi):7.2f} {0:8.5f} {0:8.5f}"
          f"   (measured {t_exact:.1f} s on {len(sub)} receivers, scaled to {len(d.roi)})")
    sizes = (128, 256, 512, 1024) if args.full else (256, 512, 1024)
    ks = (16, 32, 64, 128) if args.full else (32, 64, 128)
    samples = (("center", 1), ("stencil7", 7), ("mc", 8), ("mc", 16), ("mc", 32)) if args.full else \
        (("center", 1), ("stencil7", 7), ("mc", 8), ("mc", 32))
    combos = [(w, k, "mc", 8) for w in sizes for k in ks] + [(512, 64, m, nn) for m, nn in samples]
    seen = set()
    for w, k, mode, nn in combos:
        if (w, k, mode, nn) in seen:
            continue
        seen.add((w, k, mode, nn))
        c2 = DGSMConfig(atlas_size=w, K=k, sampling=mode, n_samples=nn)
        tb2, ts2, d2, vals2, _, _ = run_config(avatar, room, light, c2, prepared, repeat=2)
        pts2 = d2.points.reshape(len(d2.roi), -1, 3)[sub_s].reshape(-1, 3)
        ex2 = dgsm_sample.weighted_mean(dgsm_exact.transmittance_point(light, pts2, occ, dd), d2.weights) \
            if (mode, nn) != ("mc", 8) else ex_s
        e2 = np.abs(vals2[sub_s] - ex2)
        e3 = np.abs(dgsm_sample.weighted_mean(dgsm_sample.lookup_point(d2.atlas, light, pts2), d2.weights) - ex2)
        print(f"  {f'W={w} K={k} {mode} n={nn}':34s} {tb2:7.3f} {ts2:7.3f} {e2.mean():8.5f} {e2.max():8.5f} "
              f"{e3.mean():10.5f} {e3.max():9.5f}")

    # ----------------------------------------------------------- culling ablation
    print(f"\nCulling ablation (atlas build only, W={cfg.atlas_size} K={cfg.K} k_sigma={cfg.k_sigma}; paper, A100: "
          "0.13 s with both, "
          "29.1 s without ROI (224x), 17.1 s without light-space culling (132x))")
    occ_all, dd_all, cov_all = prepared
    pts = d.points

    def atlas_time(pts_, repeat=2, **kw):
        best, at = np.inf, None
        for _ in range(repeat):
            t0 = time.perf_counter()
            at = dgsm_build.build_point(light, occ_all, dd_all, cov_all, pts_, cfg.atlas_size, cfg.K,
                                        t_max=d.atlas.t_max, k_sigma=cfg.k_sigma, **kw)
            best = min(best, time.perf_counter() - t0)
        return best, at

    base, at0 = atlas_time(pts, repeat=3)
    rows = [("ROI + tiles + bin skip", base, at0, "")]
    tb_, at_ = atlas_time(pts, bin_skip=False)
    rows.append(("ROI + tiles, no bin skip", tb_, at_, ""))
    tb_, at_ = atlas_time(pts, repeat=1, use_roi=False)
    rows.append(("no ROI (all W^2 x K voxels)", tb_, at_, ""))
    # no tile culling: every occluder for every ROI pixel; timed on a 1/64 subset of the
    # receivers' sample points and scaled by the pixel count (cost is |P| x N_occluders)
    abl_pts = pts.reshape(len(d.roi), -1, 3)[::64].reshape(-1, 3)
    tb_, at_ = atlas_time(abl_pts, repeat=1, use_tiles=False)
    scale = len(at0.pixels) / len(at_.pixels)
    rows.append(("ROI, no tile culling", tb_ * scale, at_, f" (measured {tb_:.2f} s on |P| = {len(at_.pixels)}, "
                 f"x{scale:.1f})"))
    for name, tt, at_, note in rows:
        print(f"  {name:30s} {tt:8.3f} s  ratio {tt / base:7.1f}x  |P| {len(at_.pixels):>7d} pairs {at_.pairs:>11d} "
              f"erfc evals {at_.erf_evals:>11d}{note}")

    # ------------------------------------------------------- atlas parameterisation (ablation C)
    face = int(round(cfg.atlas_size / np.sqrt(6) / 8)) * 8
    t0 = time.perf_counter()
    cube = cubemap.build_point_cube(light, occ_all, dd_all, cov_all, pts, face, cfg.K, t_max=d.atlas.t_max,
                                    k_sigma=cfg.k_sigma)
    t_cube = time.perf_counter() - t0
    cube_pts = cubemap.lookup_point_cube(cube, light, sub_pts)
    oct_pts = dgsm_sample.lookup_point(d.atlas, light, sub_pts)
    print(f"\nAblation C, plain trilinear lookups vs exact ({len(sub)} receivers): octahedral {cfg.atlas_size}^2 vs "
          f"cube map 6 x {face}^2 ({6 * face * face} texels)")
    for name, vp, tt in (("octahedral", oct_pts, base), ("cube map (clamp-to-edge faces)", cube_pts, t_cube)):
        er = np.abs(dgsm_sample.weighted_mean(vp, d.weights) - ex)
        print(f"  {name:32s} build {tt:7.3f} s  recv mean {er.mean():.5f} max {er.max():.5f}")

    # ----------------------------------------------------- scene-size independence
    big = make_room(2 * args.receivers, size=40.0, seed=5)
    far = np.flatnonzero((np.abs(big.positions[:, 0]) > 12) | (np.abs(big.positions[:, 2]) > 12))
    room2 = GaussianSet.concatenate([room, big.subset(far[:room.count])], label="room2")
    ta, tb2_ = [], []
    for _ in range(4):  # interleaved, best of 4 each: the machine is shared
        tb_a, ts_a, _, _, _, _ = run_config(avatar, room, light, cfg, prepared, repeat=1)
        tb_b, ts_b, d_b, _, _, _ = run_config(avatar, room2, light, cfg, prepared, repeat=1)
        ta.append(tb_a + ts_a)
        tb2_.append(tb_b + ts_b)
    tb_a, ts_a, tb_b, ts_b = min(ta), 0.0, min(tb2_), 0.0
    print(f"\nScene size: {room.count} -> {room2.count} receivers (added ones outside the ROI; ROI receivers "
          f"{len(d.roi)} -> {len(d_b.roi)}): build+sample {tb_a + ts_a:.3f} s -> {tb_b + ts_b:.3f} s "
          f"({100 * ((tb_b + ts_b) / (tb_a + ts_a) - 1):+.1f} %)")


if __name__ == "__main__":
    main()
