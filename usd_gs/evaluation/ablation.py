"""Ablations of the shadow pipeline (paper 4.4, tables 3-5 and the culling timings) and the
DGSM speed-versus-error sweep, scored against the mesh pseudo ground truth (``usd_gs.evaluation.shadow_stage``).

Every variant is a ``DGSMConfig`` (plus the atlas type, and for diagnostics a factor on the
caster's Gaussian scales) run through :func:`usd_gs.evaluation.shadow_stage.caster_strength` -- the code the
main job runs per caster prim -- on the same frames, lights, camera and ray-cast reference.
Time is the wall time of the avatar's DGSM (all lights: packing, ROI, footprint samples, atlas,
lookups) per frame, on whatever threads numba has.

Groups: ``A sampling`` (centre / deterministic 7-point stencil / MC footprint, table 3),
``B mapping`` (avg / simple / mass / diag, table 4), ``C atlas`` (octahedral vs cube map with
the same texel count, both with plain trilinear lookups, table 5), ``D culling`` (ROI off;
the build time without tile culling comes from :func:`culling_timings`), ``sweep`` (atlas
side, K, samples) and ``diagnostics`` (kappa, k_sigma, shrunken caster Gaussians: why the
figures are what they are).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from numba_kernels import dgsm_build
from usd_gs.evaluation.shadow_metrics import mesh_shadow_matte
from usd_gs.evaluation.shadow_stage import caster_strength, evaluate_frame, mean_metrics
from usd_gs.shadows.dgsm import DGSMConfig, footprint_samples, prepare_occluders
from usd_gs.shadows.shot import shadow_cone_indices


def timed(fn, *a, repeat: int = 3, **kw):
    """(best wall s, process CPU s of that run, result) of ``fn(*a, **kw)`` over ``repeat`` runs."""
    best, cpu, out = np.inf, np.inf, None
    for _ in range(repeat):
        c = time.process_time()
        t = time.perf_counter()
        out = fn(*a, **kw)
        el = time.perf_counter() - t
        if el < best:
            best, cpu = el, time.process_time() - c
    return best, cpu, out


@dataclass(frozen=True)
class Variant:
    """One configuration: ``group`` and ``name`` for the report, the DGSM options, the atlas
    ('octahedral' | 'cube') and ``caster_scale`` (diagnostics: the caster's scales times this).
    ``oracle``: no DGSM; each receiver gets the mesh's exact shadow strength at its centre (ray
    cast): the best any per-receiver-Gaussian shadow can score on this scene, i.e. the ceiling
    that the receivers' size and the splat render put on the metrics."""

    group: str
    name: str
    cfg: DGSMConfig
    atlas: str = "octahedral"
    caster_scale: float = 1.0
    oracle: bool = False


def variants(quick: bool = False) -> list[Variant]:
    """The ablation and sweep variants (module docstring); ``quick`` trims the sweep."""
    base = DGSMConfig()
    label = f"default ({base.sampling}, {base.mapping}, octahedral {base.atlas_size}, K {base.K})"
    v = [Variant("default", label, base)]
    v += [Variant("A sampling", "centre sample", replace(base, sampling="center", n_samples=1)),
          Variant("A sampling", "deterministic 7-point stencil", replace(base, sampling="stencil7", n_samples=7)),
          Variant("A sampling", "MC footprint, 8 samples", replace(base, sampling="mc", n_samples=8))]
    names = {"avg": "avg", "simple": "simple", "mass": "mass (= the paper's diag for rotated Gaussians)",
             "diag": "per-ray sqrt(d^T A d) (this project's 'diag')"}
    v += [Variant("B mapping", names[m], replace(base, mapping=m)) for m in ("avg", "simple", "mass", "diag")]
    plain = replace(base, refine_contrast=None)
    v += [Variant("C atlas", "octahedral 512^2 (plain trilinear)", plain),
          Variant("C atlas", "cube map 6 x 208^2 (plain trilinear)", plain, atlas="cube")]
    v += [Variant("D culling", "ROI + tile culling", base),
          Variant("D culling", "no ROI (every receiver)", replace(base, use_roi=False))]
    sizes = (128, 256, 512) if quick else (128, 256, 512, 1024)
    ks = (16, 64) if quick else (16, 32, 64, 128)
    samples = (("center", 1), ("stencil7", 7), ("mc", 8), ("mc", 32)) if quick else \
        (("center", 1), ("stencil7", 7), ("mc", 8), ("mc", 16), ("mc", 32))
    seen = set()
    for w, k, mode, n in [(w, 64, "mc", 8) for w in sizes] + [(512, k, "mc", 8) for k in ks] + \
            [(512, 64, m, n) for m, n in samples]:
        if (w, k, mode, n) not in seen:
            seen.add((w, k, mode, n))
            v.append(Variant("sweep", f"W={w} K={k} {mode} n={n}",
                             replace(base, atlas_size=w, K=k, sampling=mode, n_samples=n)))
    v += [Variant("diagnostics", "kappa 0.5", replace(base, kappa=0.5)),
          Variant("diagnostics", "kappa 2", replace(base, kappa=2.0)),
          Variant("diagnostics", "k_sigma 3 (paper)", replace(base, k_sigma=3.0)),
          Variant("diagnostics", "caster scales x 0.7", base, caster_scale=0.7),
          Variant("diagnostics", "caster scales x 0.5", base, caster_scale=0.5),
          Variant("diagnostics", "oracle: mesh shadow at each receiver centre", base, oracle=True)]
    return v


def _scaled(g, factor: float):
    return g if factor == 1.0 else replace(g, scales=g.scales * np.float32(factor), log_scales=None)


def run_variants(frames: list, var: list[Variant], radius: float, up_axis: str, log=None) -> list[dict]:
    """Per variant: mean SAE / SM-IoU / BF over ``frames`` (``eval_stage.FrameInputs``, their
    ray-cast references filled on first use) and the mean DGSM seconds per frame."""

    out = []
    for v in var:
        rows, secs = [], []
        if not v.oracle:  # warm-up (numba cache loads, first-call costs), not timed
            caster_strength(_scaled(frames[0].caster, v.caster_scale), frames[0].receivers, frames[0].lights, v.cfg,
                            atlas=v.atlas)
        for fi in frames:
            if v.oracle:
                strength, s = oracle_strength(fi)
            else:
                strength, s = caster_strength(_scaled(fi.caster, v.caster_scale), fi.receivers, fi.lights, v.cfg,
                                              atlas=v.atlas)
            rows.append(evaluate_frame(fi, strength, radius, up_axis))
            secs.append(s)
        m = mean_metrics(rows)
        out.append({"group": v.group, "name": v.name, "atlas": v.atlas, "caster_scale": v.caster_scale,
                    "oracle": v.oracle,
                    "config": {k: getattr(v.cfg, k) for k in ("atlas_size", "K", "sampling", "n_samples", "mapping",
                                                               "kappa", "k_sigma", "use_roi", "refine_contrast")},
                    **m, "seconds": float(np.mean(secs)), "per_frame": [
                        {k: r[k] for k in ("frame", "sae", "iou", "bf", "shadow_px", "pred_px")} for r in rows]})
        if log:
            log(f"  {v.group:12s} {v.name:40s} SAE {_f(m['sae'])} IoU {_f(m['iou'])} BF {_f(m['bf'])} "
                f"{out[-1]['seconds']:.3f} s")
    return out


def oracle_strength(fi) -> tuple[np.ndarray, float]:
    """(N,) exact mesh shadow strength at every receiver centre of the frame, seconds."""

    t = time.perf_counter()
    p = fi.receivers.gaussians.positions.astype(np.float64)[:, None, :]
    s = mesh_shadow_matte(p, np.ones(p.shape[:2], bool), fi.vertices, fi.faces, fi.lights)[:, 0]
    return s, time.perf_counter() - t


def _f(x):
    return "  -  " if x is None else f"{x:.3f}"


def culling_timings(fi, cfg: DGSMConfig | None = None, subset: int = 16) -> dict:
    """Atlas build seconds of the avatar's DGSM for the frame's first point light: with ROI and
    tile culling, without bin skipping, without the ROI (every voxel of the atlas's radial
    range), without tile culling (every occluder for every ROI pixel: built on every
    ``subset``-th receiver's samples and scaled by the ROI pixel count, as
    benchmarks/bench_dgsm.py does). Best of 2, wall seconds."""

    cfg = (cfg or DGSMConfig()).validate()
    light = next((lt for lt in fi.lights if lt.kind == "point"), None)
    if light is None:
        return {}
    g = fi.receivers.gaussians
    occ, dd, cov6 = prepare_occluders(fi.caster, cfg)
    idx = shadow_cone_indices(fi.caster, g.positions, light, cfg.k_sigma)
    pts, _ = footprint_samples(g, idx, cfg)
    lp = np.asarray(light.position, np.float64)

    def build(p, repeat=2, **kw):
        return timed(dgsm_build.build_point, lp, occ, dd, cov6, np.ascontiguousarray(p), cfg.atlas_size, cfg.K,
                     None, cfg.k_sigma, repeat=repeat, **kw)

    base, _, at0 = build(pts)
    noskip, _, _ = build(pts, bin_skip=False)
    noroi, _, at_r = build(pts, repeat=1, use_roi=False)
    sub = pts.reshape(len(idx), -1, 3)[::subset].reshape(-1, 3)
    notile, _, at_t = build(sub, repeat=1, use_tiles=False)
    scale = len(at0.pixels) / max(len(at_t.pixels), 1)
    return {"light": light.name, "occluders": int(fi.caster.count), "roi_receivers": int(len(idx)),
            "roi_pixels": int(len(at0.pixels)), "with_culling_s": base, "no_bin_skip_s": noskip,
            "no_roi_s": noroi, "no_roi_pixels": int(len(at_r.pixels)), "no_tile_culling_s": notile * scale,
            "no_tile_culling_measured_s": notile, "no_tile_culling_pixels": int(len(at_t.pixels))}


def pareto_front(times, errors) -> np.ndarray:
    """(M,) indices of the points not dominated in (time, error), both lower-is-better,
    sorted by time. A point is dominated when another is no worse in both and better in one."""
    t = np.asarray(times, np.float64)
    e = np.asarray(errors, np.float64)
    keep = []
    for i in range(len(t)):
        dom = (t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))
        if not dom.any() and np.isfinite(e[i]):
            keep.append(i)
    return np.array(sorted(keep, key=lambda i: (t[i], e[i])), np.int64)
