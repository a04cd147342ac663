"""Shadow evaluation of a processed stage (``usdgs eval``, ``usdgs bench``): stage inputs,
per-caster DGSM strengths, per-frame metrics.

What a stage must hold (errors name the missing piece, ``UserError`` -> exit 2):

- ``/UsdGs`` (written by every ``usdgs process`` run) and at least one light that
  ``light_prims.read_stage_lights`` reads (the estimated ``/UsdGs/Lights/Light_N`` or the
  input's UsdLux lights);
- a *guide mesh*: a ``UsdGeom.Mesh`` with a relationship ``usdgs:demo:guideFor`` targeting
  a Gaussian prim (the demo writes ``/World/CesiumMan_guide`` for ``/World/CesiumMan``): the
  pseudo ground truth replaces that prim's Gaussians by the mesh (triangulated, world space
  at the frame);
- a ``UsdGeom.Camera`` (``--camera``, else the first camera in path order).

Which shadow is compared: only the guide target's (the avatar's). The demo has other
casters (the biker and the guitar captures) that have no mesh, so the DGSM matte ``S`` is by
default computed for the avatar alone (``matte='caster'``): the same code the main job runs
for each caster prim (``shot_shadows.caster_transmittance``: cone ROI, footprint samples,
atlas, lookups) with the stage's lights and a ``DGSMConfig``, lights combined with the
pipeline's shares. ``matte='stage'`` instead uses the stored ``primvars:usdgs:transmittance``
of the processed stage, which includes every caster's shadow (so the other casters' shadows
inside the ROI count as errors there).

Receivers are the prims whose role (``roles.resolve_roles``) is ``scene`` and that receive
shadows; avatars and objects are left out of the render (receivers-only pass).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom

from numba_kernels import cubemap, dgsm_sample
from usd_gs.errors import UserError
from usd_gs.evaluation.shadow_metrics import evaluate_view
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
from usd_gs.pipeline.options import dgsm_config, load_config
from usd_gs.render.camera import Camera
from usd_gs.render.preview import camera_prims, stage_label
from usd_gs.shadows.dgsm import footprint_samples, prepare_occluders
from usd_gs.shadows.shading import combine_lights, light_shares
from usd_gs.shadows.shot import Receivers, caster_transmittance, occluder_sphere, shadow_cone_indices
from usd_gs.usd.gaussian_prim import (
    POSITIONS,
    data_attribute,
    describe_gaussian_prim,
    find_gaussian_prims,
    is_gaussian_prim,
    read_gaussian_prim,
)
from usd_gs.usd.lux import read_stage_lights
from usd_gs.usd.output_author import TRANSMITTANCE
from usd_gs.usd.roles import resolve_roles
from usd_gs.usd.stage import open_stage

GUIDE_REL = "usdgs:demo:guideFor"
ATLASES = ("octahedral", "cube")


@dataclass
class EvalContext:
    """An opened processed stage and what the evaluation needs from it (module docstring)."""

    stage: object
    label: str
    avatar_path: str
    guide_path: str
    camera_path: str
    scene_paths: list[str]
    up_axis: str
    width: int
    frames_range: tuple[float, float]
    _static: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ per frame inputs
    def receivers(self, frame: float):
        """``shot_shadows.Receivers`` of the scene prims at ``frame`` (static prims cached)."""

        parts = []
        for p in self.scene_paths:
            prim = self.stage.GetPrimAtPath(p)
            if p in self._static:
                g = self._static[p]
            else:
                g = read_gaussian_prim(prim, Usd.TimeCode(frame))
                if not _is_animated(prim):
                    self._static[p] = g
            parts.append((p, g))
        return Receivers.build(parts)

    def caster(self, frame: float) -> GaussianSet:
        return read_gaussian_prim(self.stage.GetPrimAtPath(self.avatar_path), Usd.TimeCode(frame))

    def mesh(self, frame: float) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V, 3) float64 world, faces (F, 3) int64) of the guide mesh at ``frame``."""
        return guide_mesh_world(self.stage.GetPrimAtPath(self.guide_path), frame)

    def lights(self, frame: float) -> list:
        lights, _ = read_stage_lights(self.stage, Usd.TimeCode(frame))
        if not lights:
            raise UserError(f"{self.label}: no light at frame {frame:g} (no /UsdGs/Lights prim and no UsdLux light "
                            "in the stage)")
        return lights

    def camera(self, frame: float):
        return Camera.from_usd(self.stage.GetPrimAtPath(self.camera_path), frame, width=self.width)

    def stored_strength(self, receivers, frame: float) -> np.ndarray:
        """(N,) ``1 - primvars:usdgs:transmittance`` of the receivers at ``frame`` (0 where the
        primvar has no value: never shadowed). ``UserError`` when no receiver has the primvar at
        all: the stage was processed without ``--aovs transmittance``."""
        if not any(self.stage.GetPrimAtPath(p).GetAttribute(TRANSMITTANCE).HasAuthoredValue()
                   for p in receivers.ranges if self.stage.GetPrimAtPath(p).HasAttribute(TRANSMITTANCE)):
            raise UserError(f"{self.label}: no receiver has '{TRANSMITTANCE}': --matte stage reads what the main "
                            "job wrote; run 'usdgs process' with --aovs transmittance")
        out = np.zeros(receivers.gaussians.count)
        for p, (a, b) in receivers.ranges.items():
            attr = self.stage.GetPrimAtPath(p).GetAttribute(TRANSMITTANCE)
            v = attr.Get(Usd.TimeCode(frame)) if attr else None
            if v is None:
                continue
            t = np.asarray(v, np.float64)
            if t.shape != (b - a,):
                raise UserError(f"{self.label}: {p}: '{TRANSMITTANCE}' has {t.shape[0]} values at frame {frame:g}, "
                                f"but the prim has {b - a} Gaussians")
            out[a:b] = 1.0 - t
        return out


def _is_animated(prim) -> bool:
    attr, _ = data_attribute(prim, POSITIONS)
    return bool(attr and attr.GetNumTimeSamples() > 1) or UsdGeom.Xformable(prim).TransformMightBeTimeVarying()


def guide_mesh_world(prim, frame: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a ``UsdGeom.Mesh`` in world space at ``frame`` (polygons fan-triangulated)."""

    path = str(prim.GetPath())
    tc = Usd.TimeCode(frame)
    mesh = UsdGeom.Mesh(prim)
    pts = mesh.GetPointsAttr().Get(tc)
    counts = mesh.GetFaceVertexCountsAttr().Get(tc)
    idx = mesh.GetFaceVertexIndicesAttr().Get(tc)
    if pts is None or counts is None or idx is None or len(pts) == 0:
        raise UserError(f"{path}: guide mesh has no points or faces at frame {frame:g}")
    v = np.asarray(pts, np.float64)
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(idx, np.int64)
    if counts.sum() != idx.size or (counts < 3).any() or idx.min() < 0 or idx.max() >= len(v):
        raise UserError(f"{path}: inconsistent faceVertexCounts / faceVertexIndices (or an index out of range)")
    if (counts == 3).all():
        faces = idx.reshape(-1, 3)
    else:
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        faces = np.concatenate([np.stack([np.full(c - 2, s), s + np.arange(1, c - 1), s + np.arange(2, c)], 1)
                                for s, c in zip(starts, counts, strict=True)])
        faces = idx[faces]
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc), np.float64)
    return v @ m[:3, :3] + m[3, :3], faces


def find_guides(stage) -> dict[str, str]:
    """{guide mesh path: target prim path} of every ``UsdGeom.Mesh`` with ``usdgs:demo:guideFor``."""

    out = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        rel = prim.GetRelationship(GUIDE_REL)
        targets = rel.GetTargets() if rel else []
        if targets:
            out[str(prim.GetPath())] = str(targets[0])
    return out


def open_eval_stage(path: str, camera: str | None = None, avatar: str | None = None, width: int = 960,
                    require_processed: bool = True) -> EvalContext:
    """Open ``path`` and check it (module docstring); ``avatar`` picks the guide mesh by its target."""

    stage = open_stage(path)
    label = stage_label(stage)
    if require_processed and not stage.GetPrimAtPath("/UsdGs"):
        raise UserError(f"{label}: not a processed stage (no /UsdGs prim); run 'usdgs process' on the input first "
                        "and evaluate its output (<stem>.lit.usdc)")
    guides = find_guides(stage)
    if avatar is not None:
        guides = {g: t for g, t in guides.items() if t == avatar}
    if not guides:
        which = f" targeting {avatar}" if avatar else ""
        raise UserError(f"{label}: no guide mesh{which}: the pseudo ground truth needs a UsdGeom.Mesh with a "
                        f"'{GUIDE_REL}' relationship to the avatar prim (the demo writes /World/CesiumMan_guide)")
    guide, target = sorted(guides.items())[0]
    tprim = stage.GetPrimAtPath(target)
    if not tprim or not is_gaussian_prim(tprim):
        raise UserError(f"{label}: {guide}: '{GUIDE_REL}' targets {target}, which is not a "
                        "ParticleField3DGaussianSplat prim")
    if camera is None:
        cams = camera_prims(stage)
        if not cams:
            raise UserError(f"{label}: no UsdGeom.Camera prim in the stage; pass --camera PATH")
        camera = str(cams[0].GetPath())
    else:
        prim = stage.GetPrimAtPath(camera)
        if not prim or not prim.IsA(UsdGeom.Camera):
            raise UserError(f"{label}: --camera {camera}: no UsdGeom.Camera prim at this path")
    prims = find_gaussian_prims(stage)
    infos = [describe_gaussian_prim(p, Usd.TimeCode.EarliestTime()) for p in prims]
    roles, _ = resolve_roles(infos)
    scene = [r.path for r in roles if r.role == "scene" and r.receives_shadows and r.path != target]
    if not scene:
        raise UserError(f"{label}: no scene prim receives shadows (role 'scene'): nothing to evaluate on")
    up = "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"
    return EvalContext(stage, label, target, guide, camera, scene, up, int(width),
                       (stage.GetStartTimeCode(), stage.GetEndTimeCode()))


# ----------------------------------------------------------------------------- DGSM strength of one caster
def _cube_transmittance(caster, receivers, light, cfg, prepared, sphere):
    """Like ``shot_shadows.caster_transmittance`` (cone ROI, no candidates) with the cube-map
    atlas of ablation C (``numba_kernels.cubemap``, 6 faces of ~``atlas_size / sqrt 6`` px:
    the same texel count), plain trilinear lookups."""

    if light.kind != "point":
        raise UserError(f"{light.name}: the cube-map atlas ablation supports point lights only")
    g = receivers.gaussians
    idx = (np.arange(g.count, dtype=np.int64) if not cfg.use_roi
           else shadow_cone_indices(caster, g.positions, light, cfg.k_sigma, sphere))
    if idx.size == 0:
        return idx, np.zeros(0)
    pts, w = footprint_samples(g, idx, cfg)
    face = max(8, int(round(cfg.atlas_size / np.sqrt(6) / 8)) * 8)
    lp = np.asarray(light.position, np.float64)
    at = cubemap.build_point_cube(lp, *prepared, np.ascontiguousarray(pts), face, cfg.K, t_max=cfg.t_max,
                                  k_sigma=cfg.k_sigma, bin_skip=cfg.bin_skip)
    return idx, dgsm_sample.weighted_mean(cubemap.lookup_point_cube(at, lp, pts), w)


def caster_strength(caster: GaussianSet, receivers, lights: list, cfg, roi: str = "cone",
                    atlas: str = "octahedral") -> tuple[np.ndarray, float]:
    """(shadow strength ``1 - T`` (N,) float64 of every receiver from ``caster`` alone, wall
    seconds): one DGSM per light as the main job builds it, lights combined with
    ``shading.light_shares`` / ``combine_lights``. ``atlas``: 'octahedral' or 'cube'."""

    if atlas not in ATLASES:
        raise UserError(f"atlas must be one of {ATLASES}, got {atlas!r}")
    t0 = time.perf_counter()
    cfg = cfg.validate()
    n = receivers.gaussians.count
    prepared = prepare_occluders(caster, cfg)
    sphere = occluder_sphere(caster, cfg.k_sigma)
    per = []
    for light in lights:
        t = np.ones(n)
        if atlas == "cube":
            idx, val = _cube_transmittance(caster, receivers, light, cfg, prepared, sphere)
        else:
            idx, val = caster_transmittance(caster, receivers, light, cfg, roi=roi, prepared=prepared, sphere=sphere)
        t[idx] = val
        per.append(t)
    T = combine_lights(per, light_shares(lights, receivers.gaussians.positions)).astype(np.float64)
    return 1.0 - T, time.perf_counter() - t0


# ----------------------------------------------------------------------------- one frame
@dataclass
class FrameInputs:
    """Everything one frame's evaluation reads from the stage, plus the cached ray-cast reference."""

    frame: float
    receivers: object
    caster: GaussianSet
    vertices: np.ndarray
    faces: np.ndarray
    lights: list
    camera: object
    centre: np.ndarray
    reference: tuple | None = None


def frame_inputs(ctx: EvalContext, frame: float) -> FrameInputs:
    caster = ctx.caster(frame)
    v, f = ctx.mesh(frame)
    return FrameInputs(float(frame), ctx.receivers(frame), caster, v, f, ctx.lights(frame), ctx.camera(frame),
                       alpha_weighted_centroid(caster))


def evaluate_frame(fi: FrameInputs, strength: np.ndarray, radius: float = 2.0, up_axis: str = "Y",
                   keep_images: bool = False) -> dict:
    """Metrics of one frame for receiver strengths ``strength`` (``metrics_shadow.evaluate_view``);
    the ray-cast reference is computed on the first call and reused by later ones."""

    r = evaluate_view(fi.receivers.gaussians, strength, fi.camera, fi.vertices, fi.faces, fi.lights, fi.centre,
                      radius, up_axis, reference=fi.reference)
    if fi.reference is None:
        fi.reference = (r["S_dagger"], r["roi"], r["valid"])
    if not keep_images:
        for k in ("S", "S_dagger", "roi", "valid"):
            r.pop(k)
    r["frame"] = fi.frame
    return r


def default_eval_frames(ctx: EvalContext, max_frames: int = 8) -> list[float]:
    """At most ``max_frames`` frames spread evenly over the stage's time range (whole frames)."""
    a, b = ctx.frames_range
    n = int(b - a) + 1
    step = max(1, int(np.ceil(n / max_frames)))
    return [float(f) for f in np.arange(a, b + 1, step)]


def mean_metrics(rows: list[dict]) -> dict:
    """Mean of ``sae``, ``iou``, ``bf`` over the frames where each is defined (None if none)."""
    out = {}
    for k in ("sae", "iou", "bf"):
        vals = [r[k] for r in rows if r.get(k) is not None]
        out[k] = float(np.mean(vals)) if vals else None
    out["frames"] = len(rows)
    return out


def dgsm_config_from_file(path: str | None):
    """(DGSMConfig, roi) from a ``usdgs process --config`` JSON file (None: defaults)."""

    cfg = load_config(path) if path else {}
    return dgsm_config(cfg), cfg.get("roi", "cone")


__all__ = ["EvalContext", "FrameInputs", "caster_strength", "default_eval_frames", "dgsm_config_from_file",
           "evaluate_frame", "find_guides", "frame_inputs", "guide_mesh_world", "mean_metrics", "open_eval_stage"]
