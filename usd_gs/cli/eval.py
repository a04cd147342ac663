"""``usdgs eval``: shadow accuracy (paper 4.2) and, when available, lighting consistency (4.1)
of a processed stage. The shadow logic is in ``usd_gs/evaluation/shadow_stage.py`` and
``usd_gs/evaluation/shadow_metrics.py``."""

from __future__ import annotations

import json
import sys
import time

from usd_gs.errors import UserError


def _fmt(v, nd=3) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def lighting_metrics(stage_path: str, frames, radius: float):
    """Lighting consistency of the relit avatars (paper 4.1,
    ``usd_gs.evaluation.lighting_stage.lighting_consistency_for_stage``)."""
    from usd_gs.evaluation.lighting_stage import lighting_consistency_for_stage

    return lighting_consistency_for_stage(stage_path, frames=frames, radius=radius)


def _jsonable(o):
    """``json.dump`` default: numpy arrays and scalars as lists and numbers."""
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def run_eval(stage_path: str, camera=None, frames=None, width: int = 960, radius: float = 2.0, config=None,
             matte: str = "caster", avatar=None) -> dict:
    """Shadow metrics of ``stage_path`` per frame and their mean (a JSON-ready dict)."""
    from usd_gs.evaluation.shadow_stage import (
        caster_strength,
        default_eval_frames,
        dgsm_config_from_file,
        evaluate_frame,
        frame_inputs,
        mean_metrics,
        open_eval_stage,
    )
    from usd_gs.usd.frames import outside_warning, parse_frames

    if matte not in ("caster", "stage"):
        raise UserError(f"--matte must be 'caster' or 'stage', got '{matte}'")
    from usd_gs.resources import check_limit

    check_limit("eval_width", width, "--width")
    if not radius > 0:
        raise UserError(f"--radius must be > 0, got {radius}")
    ctx = open_eval_stage(stage_path, camera=camera, avatar=avatar, width=width)
    cfg, roi = dgsm_config_from_file(config)
    a, b = ctx.frames_range
    fl = parse_frames(frames, a, b) if frames is not None else default_eval_frames(ctx)
    outside = outside_warning(fl, a, b, stage_path)
    if outside:
        print(f"warning: {outside}", file=sys.stderr)
    rows = []
    for f in fl:
        t0 = time.perf_counter()
        fi = frame_inputs(ctx, f)
        if matte == "caster":
            strength, dgsm_s = caster_strength(fi.caster, fi.receivers, fi.lights, cfg, roi=roi)
        else:
            strength, dgsm_s = ctx.stored_strength(fi.receivers, f), 0.0
        r = evaluate_frame(fi, strength, radius, ctx.up_axis)
        r["seconds"] = {"dgsm": dgsm_s, **r["seconds"], "total": time.perf_counter() - t0}
        rows.append(r)
    return {"stage": ctx.label, "avatar": ctx.avatar_path, "guide_mesh": ctx.guide_path, "camera": ctx.camera_path,
            "image": [fi.camera.width, fi.camera.height], "roi_radius": radius, "matte": matte,
            "tau": 0.1, "boundary_tol_px": 2, "frames": rows, "mean": mean_metrics(rows)}


def _nan_to_none(o):
    """Undetermined metrics (NaN) as JSON ``null``; containers (and numpy arrays, as lists)
    walked recursively."""
    import math

    import numpy as np

    if isinstance(o, (np.ndarray, np.generic)):
        o = o.tolist()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _nan_to_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_nan_to_none(v) for v in o]
    return o


def cmd_eval(args) -> int:
    out = run_eval(args.stage, args.camera, args.frames, args.width, args.radius, args.config, args.matte, args.avatar)
    light = lighting_metrics(args.stage, [r["frame"] for r in out["frames"]], args.lighting_radius)
    out["lighting"] = light
    if args.json:
        json.dump(_nan_to_none(out), sys.stdout, indent=2, default=_jsonable)
        print()
        return 0
    print(f"{out['stage']}: shadow of {out['avatar']} against the mesh {out['guide_mesh']}, camera {out['camera']} "
          f"({out['image'][0]}x{out['image'][1]}), ROI {out['roi_radius']:g} m, matte '{out['matte']}'")
    print(f"{'frame':>7s} {'SAE':>7s} {'SM-IoU':>7s} {'BF':>7s} {'shadow px':>10s} {'ROI px':>8s} {'s':>6s}")
    for r in out["frames"]:
        print(f"{r['frame']:7g} {_fmt(r['sae']):>7s} {_fmt(r['iou']):>7s} {_fmt(r['bf']):>7s} {r['shadow_px']:10d} "
              f"{r['roi_px']:8d} {r['seconds']['total']:6.2f}")
    m = out["mean"]
    print(f"{'mean':>7s} {_fmt(m['sae']):>7s} {_fmt(m['iou']):>7s} {_fmt(m['bf']):>7s}")
    from usd_gs.evaluation.lighting_stage import format_report

    print(f"lighting consistency (paper 4.1, radius {args.lighting_radius:g} m; lower is better, "
          "improvement = orig - relit):")
    print(format_report(light))
    return 0


def register_eval(sub, formatter):
    p = sub.add_parser(
        "eval", formatter_class=formatter, help="shadow accuracy of a processed stage against a mesh pseudo ground "
                                                "truth (and lighting consistency when available)",
        description="Paper section 4.2: the avatar's Gaussians are replaced by its posed guide mesh (a UsdGeom.Mesh "
                    "with a usdgs:demo:guideFor relationship, as the demo writes); shadow rays from every visible "
                    "scene point of the camera view to each light give the pseudo ground-truth matte S+, the DGSM "
                    "matte S is a receivers-only splat render of the shadow strength. Prints SAE, SM-IoU (tau 0.1) "
                    "and BF (2 px boundary F-measure) in the avatar-centric ROI per frame and their mean. By "
                    "default S is the avatar's own DGSM shadow, recomputed with the stage's lights and the DGSM "
                    "options (--config, as for 'usdgs process'); --matte stage uses the stored "
                    "primvars:usdgs:transmittance instead, which includes every caster's shadow.")
    p.add_argument("stage", help="processed stage (the output of 'usdgs process')")
    p.add_argument("--camera", metavar="PATH", help="UsdGeom.Camera prim (default: the first camera in the stage)")
    p.add_argument("--frames", help="frames: A-B, A:B:STEP, N or a comma list (default: at most 8 frames spread "
                                    "over the stage's range)")
    p.add_argument("--avatar", metavar="PATH", help="the avatar whose guide mesh is used (default: the first)")
    p.add_argument("--width", type=int, default=960,
                   help="image width in pixels, 16..8192 (height from the camera aperture)")
    p.add_argument("--radius", type=float, default=2.0, help="ROI half-size R in metres around the avatar")
    p.add_argument("--matte", choices=("caster", "stage"), default="caster", help="where S comes from (above)")
    p.add_argument("--config", help="JSON DGSM options as for 'usdgs process --config' (matte 'caster')")
    p.add_argument("--lighting-radius", type=float, default=1.5, help="neighbourhood radius of the lighting metrics")
    p.add_argument("--json", action="store_true", help="print a machine-readable result")
    p.set_defaults(handler=cmd_eval)


REGISTRARS = [register_eval]
