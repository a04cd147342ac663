"""Lighting-consistency metrics (paper 4.1) of a processed stage (``usdgs process`` output).

The output stage ``<stem>.lit.usdc`` sublayers the input; its avatar prims carry the relit
``radiance:sphericalHarmonicsCoefficients`` (relighting and shadow attenuation) and
``primvars:usdgs:lightScale`` at every processed frame. The original colours are read by
opening the input (the output's first sublayer) on its own. Roles come from the input
(``usd_gs.usd.roles``: authored ``usdgs:role``, else the automatic rules); the scene set is
every ``scene`` prim of the input (bricks concatenated), read once at the earliest time
(the captured scene, without the shadows the avatars cast into it).
"""

from __future__ import annotations

import os

from pxr import Sdf, Usd, UsdGeom

from usd_gs.errors import UserError
from usd_gs.evaluation.lighting_metrics import METRICS, PAA_MIN_RANK, lighting_consistency, summarize
from usd_gs.gaussians import GaussianSet
from usd_gs.usd.gaussian_prim import describe_gaussian_prim, find_gaussian_prims, read_gaussian_prim
from usd_gs.usd.output_author import LIGHT_SCALE, SH_COEFFS, SH_COEFFS_HALF
from usd_gs.usd.roles import resolve_roles
from usd_gs.usd.stage import open_stage


def _input_path(output_stage) -> str:
    layer = output_stage.GetRootLayer()
    subs = list(layer.subLayerPaths)
    if not subs:
        raise UserError(f"{layer.identifier}: has no sublayer; not a 'usdgs process' output stage")

    path = Sdf.ComputeAssetPathRelativeToLayer(layer, subs[0])
    if not os.path.exists(path):
        raise UserError(f"{layer.identifier}: its input (first sublayer) {subs[0]} does not exist")
    return path


def _processed_frames(output_stage, path: str) -> list[float]:
    """The frames at which the output relit prim ``path``: the time samples its output layer
    holds for the relit SH (half or float) or the ``lightScale`` AOV."""
    layer = output_stage.GetRootLayer()
    frames: set[float] = set()
    for name in (SH_COEFFS_HALF, SH_COEFFS, LIGHT_SCALE):
        spec = layer.GetAttributeAtPath(f"{path}.{name}")
        if spec is not None:
            frames.update(float(t) for t in layer.ListTimeSamplesForPath(spec.path))
    return sorted(frames)


def lighting_consistency_for_stage(output_stage_path, frames=None, radius: float = 1.5, avatars=None,
                                   view_from=None, alpha_prior: float = 1.0, max_points: int = 2000,
                                   seed: int = 0) -> dict:
    """PAA-Y, APF-Y and NCM-ab for original and relit avatars of a processed stage.

    output_stage_path: a ``usdgs process`` output. frames: iterable of time codes, or None
    for the frames the output relit (time samples of its relit SH).
    radius: neighbourhood radius in metres (stage ``metersPerUnit`` applied). avatars: prim
    paths (default: every prim whose role is ``avatar`` and that the output relit).

    Returns ``{'input': path, 'output': path, 'radius_m', 'frames': [..], 'avatars': [..],
    'per_frame': {avatar: {frame: result}}, 'mean': {avatar: summary}, 'overall': summary}``
    where ``result`` is :func:`usd_gs.evaluation.lighting_metrics.lighting_consistency` and ``summary``
    :func:`usd_gs.evaluation.lighting_metrics.summarize`.
    """

    out_path = str(output_stage_path)
    out_stage = open_stage(out_path)
    in_path = _input_path(out_stage)
    in_stage = open_stage(in_path)
    mpu = UsdGeom.GetStageMetersPerUnit(in_stage) or 1.0
    prims = {p.GetPath().pathString: p for p in find_gaussian_prims(in_stage)}
    infos = [describe_gaussian_prim(p, Usd.TimeCode.EarliestTime()) for p in prims.values()]
    roles, _ = resolve_roles(infos)
    scene_paths = [r.path for r in roles if r.role == "scene"]
    if not scene_paths:
        raise UserError(f"{in_path}: no scene Gaussian prim (role 'scene') to compare the avatars with")
    if avatars is None:
        avatars = [r.path for r in roles if r.role == "avatar" and _processed_frames(out_stage, r.path)]
    else:
        known = {r.path for r in roles}
        for a in avatars:
            if a not in known:
                raise UserError(f"{in_path}: {a} is not a Gaussian prim of the input")
    if not avatars:
        raise UserError(f"{out_path}: no relit avatar prim (no 'primvars:usdgs:lightScale' samples)")
    scene = GaussianSet.concatenate([read_gaussian_prim(prims[p], Usd.TimeCode.EarliestTime())
                                     for p in scene_paths], label="scene")
    per_frame, means, everything = {}, {}, []
    used_frames: set[float] = set()
    for a in avatars:
        fr = sorted(float(f) for f in frames) if frames is not None else _processed_frames(out_stage, a)
        if not fr:
            raise UserError(f"{out_path}: {a} has no relit frame")
        per_frame[a] = {}
        out_prim = out_stage.GetPrimAtPath(a)
        for f in fr:
            tc = Usd.TimeCode(f)
            orig = read_gaussian_prim(prims[a], tc)
            relit = read_gaussian_prim(out_prim, tc)
            per_frame[a][f] = lighting_consistency(orig, relit, scene, radius, mpu, view_from, alpha_prior,
                                                   max_points, seed)
            used_frames.add(f)
        means[a] = summarize(list(per_frame[a].values()))
        everything += list(per_frame[a].values())
    return {"input": in_path, "output": out_path, "radius_m": float(radius), "frames": sorted(used_frames),
            "avatars": list(avatars), "per_frame": per_frame, "mean": means, "overall": summarize(everything)}


def format_report(result: dict) -> str:
    """Printable table of :func:`lighting_consistency_for_stage` (means per avatar and overall)."""
    import math


    def cell(v: float) -> str:
        return f"{'n/a':>16}" if not math.isfinite(v) else f"{v:>16.4f}"

    head = f"{'avatar':<28}" + "".join(f"{m + ' ' + k:>16}" for m in METRICS for k in ("orig", "relit", "impr."))
    lines = [head]
    rows = list(result["mean"].items()) + [("all", result["overall"])]
    for name, s in rows:
        vals = "".join(cell(s["orig"][m]) + cell(s["relit"][m]) + cell(s["improvement"][m]) for m in METRICS)
        lines.append(f"{name:<28}" + vals)
    for name, s in result["mean"].items():
        n = s["determined"]["paa_y"]
        if n < s["count"]:
            lines.append(f"{name}: PAA-Y undetermined in {s['count'] - n} of {s['count']} frames (the scene "
                         f"neighbourhood's normals determine fewer than {PAA_MIN_RANK} SH coefficients; "
                         "mean over the others)")
    return "\n".join(lines)


__all__ = ["format_report", "lighting_consistency_for_stage"]
