"""Lighting-consistency metrics (paper 4.1) on a processed stage and the known-light ground truth.

Usage (from the repo root):

    PYTHONPATH=. .venv/bin/usdgs demo make --quick
    PYTHONPATH=. .venv/bin/usdgs process stages/demo.usda --frames 1-4
    PYTHONPATH=. .venv/bin/python benchmarks/bench_lighting_metrics.py [--stage stages/demo.lit.usdc] [--small]
        [--frames 1,13,25,37|all]

Prints, per avatar, PAA-Y / APF-Y / NCM-ab for the original and relit colours and the
improvement (orig - relit, positive is better), then the relighting ground truth: PSNR over
the avatar's Gaussians of the project's relighting against the known-light colours, in
several scene configurations, the lamp and the environment apart (lamp alone = environment x
1e-4) at the default and at this size, and the 4.1 metrics for the relit and the exact colours.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from usd_gs.evaluation.lighting_metrics import METRICS
from usd_gs.evaluation.lighting_stage import format_report, lighting_consistency_for_stage
from usd_gs.evaluation.relight_groundtruth import relight_ground_truth


def _row(name: str, m: dict) -> str:
    return f"  {name:<11}" + "".join(f"{m['orig'][k]:>9.3f}{m['relit'][k]:>9.3f}{m['improvement'][k]:>+9.3f}"
                                      for k in METRICS)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stage", default="stages/demo.lit.usdc")
    ap.add_argument("--small", action="store_true", help="ground truth at test size (faster)")
    ap.add_argument("--frames", default="1,13,25,37",
                    help="comma-separated frames of the stage to evaluate ('all': every relit frame; each "
                         "takes seconds)")
    a = ap.parse_args()

    if Path(a.stage).exists():
        t = time.perf_counter()
        frames = None if a.frames == "all" else [float(f) for f in a.frames.split(",")]
        r = lighting_consistency_for_stage(a.stage, frames=frames)
        dt = time.perf_counter() - t
        print(f"== {a.stage}: frames {r['frames']}, {dt:.1f} s ({dt / max(1, len(r['frames'])):.1f} s/frame, "
              f"all avatars)")
        print(format_report(r))
        for av, per in r["per_frame"].items():
            f0 = next(iter(per.values()))
            print(f"  {av}: {f0['n_avatar']} Gaussians, scene neighbourhood {f0['n_scene']}, "
                  f"SH rank {f0['scene_sh_rank']}")
    else:
        print(f"(no {a.stage}: run 'usdgs demo make --quick' and 'usdgs process stages/demo.usda --frames 1-4')")

    size = dict(n_avatar=1500, n_surface=6000, env_size=(16, 32)) if a.small else \
        dict(n_avatar=6000, n_surface=24000, env_size=(32, 64))
    print(f"\n== relighting ground truth ({size}); PSNR dB over avatar Gaussians")
    print(f"{'config':<34}{'relit':>8}{'unrelit':>8}{'relit,mesh n':>13}{'flipped n':>10}{'s':>7}")
    head = "  " + " " * 11 + "".join(f"{k + ' orig':>9}{'relit':>9}{'impr.':>9}" for k in METRICS)
    details = []
    for props, lamp, dil in ((True, True, None), (True, True, 0.3), (False, True, None), (False, True, 0.3),
                             (False, False, None)):
        t = time.perf_counter()
        r = relight_ground_truth(lamp=lamp, props=props, dilation=dil, **size)
        dt = time.perf_counter() - t
        light = "lamp+env" if lamp else "env only"
        name = f"{'props' if props else 'open'}, {light}, dil {'0 (default)' if dil is None else dil}"
        print(f"{name:<34}{r['psnr_relit']:>8.2f}{r['psnr_orig']:>8.2f}{r['psnr_relit_true_normals']:>13.2f}"
              f"{r['flipped_normals']:>10.3f}{dt:>7.1f}")
        details.append((name, r))
    print("\nlamp and environment apart (open scene; independent errors add in squared error):")
    for sz_name, sz in (("default size", {}), ("this size", size)):
        parts = {name: relight_ground_truth(lamp=lamp, props=False, metrics=False, env_scale=scale, **sz)["psnr_relit"]
                 for name, lamp, scale in (("lamp alone", True, 1e-4), ("environment alone", False, 1.0),
                                           ("together", True, 1.0))}
        indep = -10.0 * np.log10(10.0 ** (-parts["lamp alone"] / 10) + 10.0 ** (-parts["environment alone"] / 10))
        print(f"  {sz_name:<13}" + "".join(f"{k} {v:.2f} dB, " for k, v in parts.items())
              + f"independent errors would give {indep:.2f} dB")
    print("\nwith --probe-supersample 2 (probe render drawn at 2x and filtered down):")
    for sz_name, sz in (("default size", {}), ("this size", size)):
        vals = [relight_ground_truth(lamp=lamp, props=props, metrics=False, probe_supersample=2, **sz)["psnr_relit"]
                for props, lamp in ((True, True), (False, True), (True, False), (False, False))]
        print(f"  {sz_name:<13} props+lamp {vals[0]:.2f}, lamp {vals[1]:.2f}, props {vals[2]:.2f}, "
              f"neither {vals[3]:.2f} dB")
    print("\n4.1 metrics on the ground-truth scene (relit = the project's relighting; exact = the known colours)")
    for name, r in details:
        print(f"{name} (scene neighbourhood {r['metrics']['n_scene']}, SH rank {r['metrics']['scene_sh_rank']})")
        print(head)
        print(_row("relit", r["metrics"]))
        print(_row("exact", r["metrics_gt"]))


if __name__ == "__main__":
    main()
