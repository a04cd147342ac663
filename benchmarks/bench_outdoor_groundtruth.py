"""Relighting with modelled lights against ground truth (issue 18): the outdoor scenes and the indoor ones.

Usage (from the repo root; ../shared/data present; Embree through the eval extra):

    PYTHONPATH=. .venv/bin/python benchmarks/bench_outdoor_groundtruth.py [--quick] [--skip-indoor] [--skip-outdoor]
        [--far-tolerance T]

1. outdoor (``usd_gs.evaluation.outdoor_groundtruth``): the CIE clear sky with a 0.53 degree sun,
   ``kiara_1_dawn_1k.hdr`` with its sun replaced by the analytic one, and the CIE overcast sky;
   the authored sun and sky given to the relighting, the sun's visibility from the DGSMs (scene and
   self). Printed: relit PSNR (linear ``albedo E / pi`` and sRGB display), unrelit, with the mesh
   normals, and the timings;
2. indoor: the four known-light configurations of ``relight_groundtruth.relight_ground_truth``
   (props + lamp / lamp / props / neither) at the default size, the no-regression figures, with
   the probe's far field (the main job's default) and without it.
"""

from __future__ import annotations

import argparse
import time


def outdoor(quick: bool) -> None:
    from usd_gs.evaluation.outdoor_groundtruth import SKIES, outdoor_ground_truth

    kw = dict(n_avatar=1500, n_surface=6000, env_size=(16, 32)) if quick else dict(n_avatar=4000, n_surface=12000,
                                                                                     env_size=(16, 32))
    print("outdoor ground truth (PSNR dB): linear / display / unrelit display / mesh normals display")
    for sky in SKIES:
        t = time.perf_counter()
        r = outdoor_ground_truth(sky, **kw)
        print(f"  {sky:9s} {r['psnr_linear']:5.1f} / {r['psnr_display']:5.1f} / {r['psnr_orig_display']:5.1f} / "
              f"{r['psnr_true_normals_display']:5.1f}   sun {r['sun_e'].round(2)} toward {r['sun_dir'].round(3)}   "
              f"({time.perf_counter() - t:.0f} s: "
              + ", ".join(f"{k} {v:.1f}" for k, v in r["timings"].items()) + ")", flush=True)


def indoor(far_tolerance: float | None = None) -> None:
    from usd_gs.evaluation.relight_groundtruth import relight_ground_truth

    print("indoor known-light ground truth, default size (PSNR dB): relit / relit with the probe's far field off "
          "(probe_far_radius 0; the environment's dome lies 30 m away, beyond the default 15 m) / change / unrelit")
    for name, kw in (("props + lamp", dict(lamp=True, props=True)), ("lamp", dict(lamp=True, props=False)),
                     ("props", dict(lamp=False, props=True)), ("neither", dict(lamp=False, props=False))):
        r = relight_ground_truth(metrics=False, far_tolerance=far_tolerance, **kw)
        off = relight_ground_truth(metrics=False, far_radius=0.0, **kw)
        print(f"  {name:13s} {r['psnr_relit']:6.3f} / {off['psnr_relit']:6.3f} / "
              f"{r['psnr_relit'] - off['psnr_relit']:+6.3f} / {r['psnr_orig']:5.2f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small outdoor sizes (1500 avatar, 6000 scene Gaussians)")
    ap.add_argument("--skip-indoor", action="store_true")
    ap.add_argument("--skip-outdoor", action="store_true")
    ap.add_argument("--far-tolerance", type=float, default=None,
                    help="indoor: the far field's probe_far_tolerance (default: the main job's)")
    a = ap.parse_args()
    if not a.skip_outdoor:
        outdoor(a.quick)
    if not a.skip_indoor:
        indoor(a.far_tolerance)


if __name__ == "__main__":
    main()
