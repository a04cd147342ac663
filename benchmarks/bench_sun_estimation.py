"""Sun and sky from a capture's baked shadows, against a known-light open scene (figures, not a test).

    .venv/bin/python benchmarks/bench_sun_estimation.py [--quick] [--speed-gaussians N]

Scenes: ``usd_gs.evaluation.sun_scene.make_sun_scene`` (ground, a statue-sized box, a sun with a
0.53 deg disc plus a uniform sky, exact ray-box visibility, no sky Gaussians). Prints per case
the direction error (deg), the sun/sky ratio against the truth, the score and whether it is
confident; for the overcast variant the best score against the threshold. Then the avatar's
new cast shadow: a second box (0.45 x 1.75 x 0.3 m, an avatar's size) is baked into the ground
truth as well; its display-luminance darkening on the ground it shadows (mean over the ground
Gaussians whose sun visibility the avatar box drops below 0.5) against the main job's
``1 - (1 - darkening x (1 - T)) x sky`` with T from the avatar box's directional DGSM along the
estimated sun and ``sky`` the factor of the sky the box hides (``usd_gs.shadows.sky_occlusion``),
and against the sun's part of the truth alone.
Last, the speed of ``estimate_sun`` (warm) on an N-Gaussian open scene (default 1,000,000:
ground at 7.5 mm spacing and six props).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from usd_gs.evaluation.sun_scene import make_sun_scene, visible
from usd_gs.relight import sun_estimation as se

LUMA = se.LUMA
CENTRE = np.array([1.3, 0.9, 1.1])
STATUE = ((-0.4, 0.0, -0.3), (0.4, 1.8, 0.3))
AVATAR = ((0.9, 0.0, 1.0), (1.35, 1.75, 1.3))


def direction_cases(quick: bool):
    cases = [(45.0, 30.0, 3.0), (30.0, 120.0, 3.0), (65.0, -60.0, 1.5)]
    return cases[:2] if quick else cases


def run_case(el, az, ratio, spacing, sky):
    sc = make_sun_scene(el, az, ratio, spacing=spacing, sky_samples=sky, seed=2)
    t = time.perf_counter()
    est = se.estimate_sun(sc.gaussians, CENTRE, "Y", ground_hint=0.0)
    dt = time.perf_counter() - t
    err = se.angle_deg(est.direction, sc.sun)
    print(f"sun el {el:4.0f} az {az:5.0f} ratio {ratio:.1f}: direction error {err:5.2f} deg, sun/sky {est.ratio:5.2f} "
          f"({100 * (est.ratio / ratio - 1):+5.1f} %), score {est.score:.2f} (coarse pass {est.coarse_score:.2f}), "
          f"confident {est.confident}, {dt:.1f} s")
    return err, est.ratio / ratio - 1


def avatar_darkening(spacing, sky):
    """(ground truth, main job) mean display darkening of the avatar box's new shadow."""
    from usd_gs.gaussians import GaussianSet
    from usd_gs.shadows.dgsm import DGSMConfig, shadow_transmittance
    from usd_gs.shadows.sky_occlusion import hidden_sky_share, sky_factor, sphere_proxy

    el, az, ratio = 45.0, 30.0, 3.0
    base = make_sun_scene(el, az, ratio, spacing=spacing, sky_samples=sky, seed=3, boxes=[STATUE])
    both = make_sun_scene(el, az, ratio, spacing=spacing, sky_samples=sky, seed=3, boxes=[STATUE, AVATAR],
                          exposure=base.exposure)
    est = se.estimate_sun(base.gaussians, CENTRE + np.array([0.6, 0.0, 0.6]), "Y", ground_hint=0.0)
    # the same ground Gaussians in both bakes (the avatar's footprint is cut out of the second)
    gb = base.gaussians.positions[base.part == 0].astype(np.float64)
    gw = both.gaussians.positions[both.part == 0].astype(np.float64)
    key_b = {tuple(np.round(p, 5)): i for i, p in enumerate(gb)}
    pairs = [(key_b[tuple(np.round(p, 5))], j) for j, p in enumerate(gw) if tuple(np.round(p, 5)) in key_b]
    ib, iw = (np.array(v) for v in zip(*pairs, strict=True))
    db = 0.5 + 0.28209479177387814 * base.gaussians.sh[base.part == 0][ib, 0].astype(np.float64)
    dw = 0.5 + 0.28209479177387814 * both.gaussians.sh[both.part == 0][iw, 0].astype(np.float64)
    p = gb[ib]
    lo, hi = (np.asarray(v, float) for v in AVATAR)
    in_avatar_shadow = ~visible(p + 1e-4 * np.array([0, 1, 0]), base.sun, [(lo, hi)])
    in_statue_shadow = ~visible(p + 1e-4 * np.array([0, 1, 0]), base.sun, [tuple(map(np.asarray, STATUE))])
    sel = in_avatar_shadow & ~in_statue_shadow
    truth = 1.0 - (dw[sel] @ LUMA) / (db[sel] @ LUMA)
    # the part of it the sun alone makes (the rest: the avatar box also hides some sky there)
    rad = base.radiance[base.part == 0][ib][sel]
    alb = base.albedo[base.part == 0][ib][sel]
    rad_sun = alb * base.e_sun * max(float(base.sun[1]), 0.0) / np.pi
    sun_only = 1.0 - (se.srgb_to_display((rad - rad_sun) * base.exposure) @ LUMA) / (
        se.srgb_to_display(rad * base.exposure) @ LUMA)
    # the main job: the avatar box's Gaussians as the caster, the estimated sun, the measured darkening
    av = both.gaussians.subset(np.flatnonzero(both.part == 1))
    avc = av.positions.astype(np.float64)
    mine = np.all((avc >= lo - 0.05) & (avc <= hi + 0.05), axis=1)
    caster = av.subset(np.flatnonzero(mine))
    recv = GaussianSet(p, np.tile([1.0, 0, 0, 0], (len(p), 1)), np.full((len(p), 3), 0.01), np.ones(len(p)),
                       np.zeros((len(p), 1, 3)))
    cfg = DGSMConfig(roi_radius=4.0, sampling="center")
    t = shadow_transmittance(caster, recv, cfg=cfg, direction=est.propagation)
    sun_part = est.darkening * (1.0 - t[sel])
    # and the sky it hides (usd_gs.shadows.sky_occlusion, as the main job applies it)
    centres, radii = sphere_proxy(caster, np.array([0.0, 1.0, 0.0]))
    hidden = hidden_sky_share(centres, radii, p[sel], np.tile([0.0, 1.0, 0.0], (int(sel.sum()), 1)))
    k = sky_factor(hidden, t[sel], est.direct_share, est.sky_visibility, est.lit_luminance)
    ours = 1.0 - (1.0 - sun_part) * k
    print(f"avatar's new shadow: {int(sel.sum())} ground receivers, display darkening truth {truth.mean():.3f}, "
          f"main job {ours.mean():.3f} (difference {ours.mean() - truth.mean():+.3f}; the sun's part alone "
          f"{sun_part.mean():.3f}, difference {sun_part.mean() - truth.mean():+.3f}); the estimate's full-shadow "
          f"darkening {est.darkening:.3f}; of the truth, the sun's part alone {sun_only.mean():.3f}; the sky the "
          f"avatar hides there: {hidden.mean():.3f} of the hemisphere (proxy of {len(radii)} spheres)")
    # around it, in the sun (the sky part alone), within 1.5 m of the box's footprint
    foot = np.clip(p[:, [0, 2]], lo[[0, 2]], hi[[0, 2]])
    near = (~in_avatar_shadow) & (~in_statue_shadow) & (np.linalg.norm(p[:, [0, 2]] - foot, axis=1) < 1.5)
    truth_n = 1.0 - (dw[near] @ LUMA) / (db[near] @ LUMA)
    h_n = hidden_sky_share(centres, radii, p[near], np.tile([0.0, 1.0, 0.0], (int(near.sum()), 1)))
    ours_n = 1.0 - sky_factor(h_n, np.ones(int(near.sum())), est.direct_share, est.sky_visibility, est.lit_luminance)
    print(f"around it in the sun (within 1.5 m): {int(near.sum())} receivers, darkening truth {truth_n.mean():.4f} "
          f"(max {truth_n.max():.3f}), main job {ours_n.mean():.4f} (max {ours_n.max():.3f})")
    return float(ours.mean() - truth.mean())


def speed(n: int):
    # warm the kernels on a small scene first
    se.estimate_sun(make_sun_scene(spacing=0.1, sky_samples=8).gaussians, CENTRE, "Y", ground_hint=0.0)
    boxes = [STATUE, ((2.0, 0, -2.0), (2.6, 1.0, -1.4)), ((-2.5, 0, 1.5), (-1.9, 2.5, 2.0)),
             ((-2.0, 0, -2.5), (-1.2, 0.5, -1.9)), ((1.8, 0, 2.2), (2.2, 3.0, 2.6)), ((-0.2, 0, 2.6), (0.4, 0.8, 3.0))]
    half = 3.5
    spacing = (4 * half * half / n) ** 0.5 * 1.3  # the props' faces hold about 40 % more
    t = time.perf_counter()
    sc = make_sun_scene(spacing=spacing, ground_half=half, boxes=boxes, sky_samples=1, sun_samples=1)
    print(f"speed scene: {sc.gaussians.count:,} Gaussians (generated in {time.perf_counter() - t:.0f} s)")
    t = time.perf_counter()
    est = se.estimate_sun(sc.gaussians, CENTRE, "Y", ground_hint=0.0)
    dt = time.perf_counter() - t
    print(f"estimate_sun: {dt:.1f} s ({est.timings.get('builds')} candidate directions; "
          + ", ".join(f"{k} {v:.1f}" for k, v in est.timings.items() if k not in ("builds",)) + ")")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="coarser scenes, fewer cases")
    ap.add_argument("--speed-gaussians", type=int, default=1_000_000)
    args = ap.parse_args()
    spacing, sky = (0.07, 32) if args.quick else (0.04, 96)
    errs = [run_case(el, az, r, spacing, sky) for el, az, r in direction_cases(args.quick)]
    oc = make_sun_scene(overcast=True, spacing=spacing, sky_samples=sky, seed=2)
    est = se.estimate_sun(oc.gaussians, CENTRE, "Y", ground_hint=0.0)
    thr = se.CaptureConfig().score_threshold
    print(f"overcast: best score {est.score:.2f} (coarse pass {est.coarse_score:.2f}; threshold {thr:.2f}), "
          f"confident {est.confident}")
    d = avatar_darkening(spacing, sky)
    print(f"summary: max direction error {max(e for e, _ in errs):.2f} deg, max |ratio error| "
          f"{100 * max(abs(r) for _, r in errs):.1f} %, overcast confident {est.confident}, avatar darkening "
          f"difference {d:+.3f}")
    if args.speed_gaussians:
        speed(args.speed_gaussians)


if __name__ == "__main__":
    main()
