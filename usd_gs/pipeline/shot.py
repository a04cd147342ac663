"""The main job (``usdgs process``): shadows, probes and relighting for every frame of a shot.

Steps (paper sections in brackets):

1. Open the input, list the Gaussian prims and resolve their roles (``usd_gs.usd.roles``).
   Static prims are read once, in world space; dynamic ones at every frame.
2. Lights: the stage's UsdLux lights, or ``k`` lights estimated once per shot from the
   scene Gaussians at the avatars' mean position over the frame range [3.1]
   (``--lights-per-frame`` re-estimates at every frame). Estimated lights are written as
   ``SphereLight`` prims under ``/UsdGs/Lights``.
3. Per frame and light: one DGSM per dynamic caster prim, sampled on the scene receivers
   in its ROI and on the other dynamic prims; the static scene's DGSM sampled on the
   dynamic prims [3.2, 3.3] (``usd_gs.shadows.shot``). Lights are combined by their share
   of the direct light (``usd_gs.shadows.shading``).
4. Per relit prim (avatars and objects with ``usdgs:relight``): six cube faces rendered at
   its alpha-weighted centroid from everything else, an SH probe fitted [3.4], normals
   (estimated once, then carried by each Gaussian's rotation) and SH transfer [3.5].
5. Results go to the layered output stage (``usd_gs.usd.output_layer``) through
   ``usd_gs.usd.output_author``; probe textures (lat-long OpenEXR) beside the output. All of
   it is written atomically at the end: an interrupted run leaves nothing behind.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
from usd_gs.pipeline import jit_warmup
from usd_gs.pipeline.options import ProcessOptions
from usd_gs.pipeline.summary import ProcessSummary
from usd_gs.relight.avatar import relight_factors
from usd_gs.relight.light_estimation import estimate_lights
from usd_gs.relight.parallax import ProbeBlend
from usd_gs.shadows.dgsm import prepare_occluders
from usd_gs.shadows.shading import attenuation_factor, combine_lights, light_shares, scale_sh
from usd_gs.shadows.shot import (
    Receivers,
    caster_transmittance,
    occluder_sphere,
    occluders_toward,
    prim_spheres,
    prims_in_shadow,
    receiver_points,
    shared_transmittance,
    toward_mask,
)
from usd_gs.shadows.static_scene import StaticSceneAtlas
from usd_gs.usd.frames import parse_frames
from usd_gs.usd.gaussian_prim import describe_gaussian_prim, find_gaussian_prims, read_gaussian_prim
from usd_gs.usd.lux import ShotLight, read_stage_lights, write_estimated_lights
from usd_gs.usd.output_author import OutputAuthor
from usd_gs.usd.output_layer import OutputLayer
from usd_gs.usd.roles import resolve_roles
from usd_gs.usd.stage import open_stage

__all__ = ["ProcessOptions", "ProcessSummary", "ShotProcessor", "default_output_path"]


class _Clock:
    def __init__(self):
        self.t: dict[str, float] = {}

    def add(self, key: str, since: float) -> float:
        now = time.perf_counter()
        self.t[key] = self.t.get(key, 0.0) + (now - since)
        return now


def default_output_path(input_path: str) -> str:
    """``<stem>.lit.usdc`` beside the input."""
    p = Path(input_path)
    return str(p.with_name(p.stem + ".lit.usdc"))


def _safe_name(path: str) -> str:
    return path.rstrip("/").rsplit("/", 1)[-1]


@dataclass
class FrameShadows:
    """One frame's shadow pass: the moving receivers (``drecv``), the static receivers some light
    is blocked for (``touched``, indices into the static receivers) with their combined
    transmittance ``t_touched``, and every moving receiver's combined transmittance ``t_dyn``."""

    drecv: Receivers
    touched: np.ndarray
    t_touched: np.ndarray
    t_dyn: np.ndarray


@dataclass
class _MovingCasters:
    """Per frame: each moving caster's packed occluders and bounding sphere, and the bounding
    sphere of each moving receiver (prim-level culling against a caster's beam)."""

    packed: dict
    bound: dict
    receiver_spheres: dict


class ShotProcessor:
    """Runs the steps of the module docstring for one input stage. ``options`` is not modified."""

    def __init__(self, input_path: str, output_path: str | None, options: ProcessOptions,
                 lights: list[ShotLight] | None = None, anchor_frame: float | None = None):
        """``lights``: shot-level lights to use at every frame (a chunk of a farm run, see
        :meth:`shot_lights`); ``anchor_frame``: the shot's first frame when this run is a chunk
        starting later (normals are estimated there, as in the whole-shot run)."""
        self.input_path = str(input_path)
        self.output_path = str(output_path or default_output_path(input_path))
        self.opts = options.check()
        self.preset_lights = lights
        self.anchor_frame = anchor_frame
        self.clock = _Clock()
        self.warnings: list[str] = []
        # the shot's DGSM options: the user's with the stage's up axis (set by _open)
        self.dgsm = self.opts.dgsm
        self._centre_cfg = replace(self.dgsm, sampling="center")
        self.mpu = 1.0
        # caches that live for the whole shot
        self._shot_lights: list[ShotLight] | None = None
        self._scene_packs: dict = {}  # per light: the static scene's atlas and emitter mask
        self._buffer = None  # the probe renders' concatenated shot (_shot_buffer)
        self._local_normals: dict = {}
        self._probe_blends: dict = {}
        self._local_sh_cache: dict = {}
        # what the run did
        self.affected: dict[str, int] = {}
        self.probe_files = 0
        self.lights_used: list[ShotLight] = []

    # ------------------------------------------------------------------ set-up
    def _open(self):
        t0 = time.perf_counter()
        self.stage = open_stage(self.input_path)
        prims = find_gaussian_prims(self.stage)
        if not prims:
            raise UserError(f"{self.input_path}: no ParticleField3DGaussianSplat prims to process")
        self.prims = {str(p.GetPath()): p for p in prims}
        infos = [describe_gaussian_prim(p, Usd.TimeCode.EarliestTime()) for p in prims]
        self.counts = {i.path: i.count for i in infos}
        self.roles, warnings = resolve_roles(infos, self.opts.scene_paths, self.opts.avatar_paths,
                                             self.opts.object_paths)
        self.warnings += warnings
        self.frames = parse_frames(self.opts.frames, self.stage.GetStartTimeCode(), self.stage.GetEndTimeCode())
        up = UsdGeom.GetStageUpAxis(self.stage)
        self.dgsm = replace(self.opts.dgsm, up_axis="Z" if up == UsdGeom.Tokens.z else "Y")
        self._centre_cfg = replace(self.dgsm, sampling="center")
        self.mpu = UsdGeom.GetStageMetersPerUnit(self.stage) or 1.0
        self.clock.add("open", t0)

    def _read(self, path: str, frame: float):
        return read_gaussian_prim(self.prims[path], Usd.TimeCode(frame))

    def _read_static(self):
        t0 = time.perf_counter()
        self.static = {r.path: read_gaussian_prim(self.prims[r.path], Usd.TimeCode.EarliestTime())
                       for r in self.roles if not r.per_frame}
        self.clock.add("read", t0)

    # ------------------------------------------------------------------ lights
    def _estimate(self, frames: list[float], k: int) -> list[ShotLight]:
        scene = [g for r in self.roles if r.role == "scene" and not r.per_frame for g in [self.static[r.path]]]
        if not scene:
            self.warnings.append("no static scene prim: no lights can be estimated")
            return []
        movers = [r.path for r in self.roles if r.role == "avatar"] or [r.path for r in self.roles if r.per_frame]
        picks = sorted({frames[0], frames[len(frames) // 2], frames[-1]})
        cents = [alpha_weighted_centroid(self._read(p, f)) for p in movers for f in picks]
        if not cents:
            cents = [alpha_weighted_centroid(GaussianSet.concatenate(scene))]
        centroid = np.mean(cents, axis=0)
        est = estimate_lights(GaussianSet.concatenate(scene, label="scene"), centroid, k=k,
                              meters_per_unit=self.mpu)
        return [ShotLight(f"Light_{i}", "point", np.asarray(e.position, np.float64), color=np.asarray(e.color),
                          intensity=float(e.intensity), score=float(e.score)) for i, e in enumerate(est)]

    def _lights(self, frame: float) -> list[ShotLight]:
        if self.preset_lights is not None:
            return self.preset_lights
        t0 = time.perf_counter()
        mode = self.opts.lights
        if mode in ("auto", "stage"):
            lights, warns = read_stage_lights(self.stage, Usd.TimeCode(frame))
            for w in warns:
                if w not in self.warnings:
                    self.warnings.append(w)
            if lights or mode == "stage":
                if not lights:
                    raise UserError(f"{self.input_path}: --lights stage but the stage has no usable UsdLux light")
                self.clock.add("lights", t0)
                return lights
            k = self.opts.default_light_count
        else:
            k = int(mode)
        if self.opts.lights_per_frame:
            lights = self._estimate([frame], k)
        else:
            if self._shot_lights is None:
                self._shot_lights = self._estimate(self.frames, k)
            lights = self._shot_lights
        self.clock.add("lights", t0)
        return lights

    def shot_lights(self) -> list[ShotLight] | None:
        """The shot-level step of a chunked run: opens the input and returns the lights estimated
        once over the whole frame range (what every chunk must use), or None where each frame
        reads the stage's UsdLux lights or re-estimates (``lights_per_frame``). Sets ``frames``."""
        self._open()
        self._read_static()
        if self.opts.lights_per_frame:
            return None
        lights = self._lights(self.frames[0])
        return lights if not lights or lights[0].source == "estimated" else None

    # ------------------------------------------------------------------ per shot
    def _shot_setup(self):
        """What does not change from frame to frame: static receivers (concatenated once, with
        each prim's bounding sphere for brick-level culling) and static casters."""
        receivers = [r.path for r in self.roles if r.receives_shadows]
        self._static_recv_paths = [p for p in receivers if p in self.static]
        self._dyn_recv_paths = [p for p in receivers if p not in self.static]
        self._static_recv = Receivers.build([(p, self.static[p]) for p in self._static_recv_paths])
        self._spheres = prim_spheres(self._static_recv, self.dgsm.k_sigma)
        static_casters = [r.path for r in self.roles if not r.per_frame and r.casts_shadows]
        casters = Receivers.build([(p, self.static[p]) for p in static_casters])
        self._scene_block = casters.gaussians if static_casters else None
        spheres = prim_spheres(casters, self.dgsm.k_sigma)
        self._caster_ranges = [casters.ranges[p] for p in spheres]
        self._caster_centres = np.array([spheres[p][0] for p in spheres]).reshape(-1, 3)
        self._caster_radii = np.array([spheres[p][1] for p in spheres])
        self._casters_dyn = [r.path for r in self.roles if r.per_frame and r.casts_shadows and r.role != "scene"]

    # ------------------------------------------------------------------ per frame
    def _frame(self, frame: float, author, probe_dir: Path):
        """One frame: read what moves, the lights, then the shadow, relighting and authoring passes."""
        t = time.perf_counter()
        dyn = {r.path: self._read(r.path, frame) for r in self.roles if r.per_frame}
        sets = {**self.static, **dyn}
        self.clock.add("read", t)
        lights = self._lights(frame)
        self.lights_used = lights
        shadows = self._shadow_pass(sets, lights)
        t = time.perf_counter()
        relit = self._relight_pass(dyn, sets, frame, author, probe_dir)
        t = self.clock.add("relight", t)
        self._author_pass(frame, author, sets, shadows, relit)
        self.clock.add("write", t)

    def _shadow_pass(self, sets: dict, lights: list[ShotLight]) -> FrameShadows:
        """Every light's transmittance on every receiver, combined by the lights' shares."""
        clk = self.clock
        t = time.perf_counter()
        srecv = self._static_recv
        drecv = Receivers.build([(p, sets[p]) for p in self._dyn_recv_paths])
        t = clk.add("prepare", t)

        cfg = self.dgsm
        packed = {q: prepare_occluders(sets[q], cfg) for q in self._casters_dyn} if lights else {}
        bound = {q: occluder_sphere(sets[q], cfg.k_sigma) for q in packed}
        # moving receivers: prim-level culling against each caster's beam, as for the bricks
        dspheres = {p: bound[p] if p in bound else occluder_sphere(sets[p], cfg.k_sigma)
                    for p in self._dyn_recv_paths if sets[p].count} if packed else {}
        movers = _MovingCasters(packed, bound, dspheres)
        s_light, d_light, touched = [], [], []
        for light in lights:
            ts, td, hits = self._moving_caster_shadows(light, sets, drecv, movers)
            self._scene_shadows_on_moving(light, sets, drecv, td)
            s_light.append(ts)
            d_light.append(td)
            touched.extend(hits)
        # static receivers: combine lights only where some light is blocked
        u = np.unique(np.concatenate(touched)) if touched else np.zeros(0, np.int64)
        t_static_u = np.ones(0, np.float32)
        if u.size:
            per = [ts[u] for ts in s_light]
            t_static_u = combine_lights(per, light_shares(lights, srecv.gaussians.positions[u]))
        t_dyn = (combine_lights(d_light, light_shares(lights, drecv.gaussians.positions)) if lights
                 else np.ones(drecv.gaussians.count, np.float32))
        clk.add("shadows", t)
        return FrameShadows(drecv, u, t_static_u, t_dyn)

    def _moving_caster_shadows(self, light, sets: dict, drecv: Receivers, movers: _MovingCasters):
        """One light: every moving caster's DGSM sampled on the static receivers in its beam and
        on the other moving receivers. Returns (static transmittance, moving transmittance, the
        static receivers some caster shadows)."""
        cfg = self.dgsm
        srecv = self._static_recv
        ts = np.ones(srecv.gaussians.count)
        hits = []
        td = np.ones(drecv.gaussians.count)
        for q in self._casters_dyn:
            bound = movers.bound[q]
            # one DGSM per caster and light, over the static and the dynamic receivers' voxels
            hit = prims_in_shadow(self._spheres, sets[q], light, cfg.k_sigma, bound)
            part_s = None
            if hit:
                cand = np.concatenate([np.arange(*srecv.ranges[p]) for p in hit])
                part_s = receiver_points(sets[q], srecv, light, cfg, roi=self.opts.roi, candidates=cand, sphere=bound)
            part_d = None
            dhit = [p for p in prims_in_shadow(movers.receiver_spheres, sets[q], light, cfg.k_sigma, bound) if p != q]
            if dhit:
                cand = np.concatenate([np.arange(*drecv.ranges[p]) for p in dhit])
                part_d = receiver_points(sets[q], drecv, light, cfg, roi=self.opts.roi, candidates=cand, sphere=bound)
            (idx, val), (idx_d, val_d) = shared_transmittance(sets[q], [part_s, part_d], light, cfg, movers.packed[q])
            ts[idx] *= val
            hits.append(idx[val < 1.0])
            td[idx_d] *= val_d
        return ts, td, hits

    def _scene_shadows_on_moving(self, light, sets: dict, drecv: Receivers, td: np.ndarray) -> None:
        """Multiplies ``td`` (the moving receivers' transmittance for ``light``) by the static
        scene's: from its shot-long atlas for a point light, from per-prim culled occluders for a
        directional one."""
        block = self._scene_block
        if block is None or not block.count:
            return
        if light.kind == "point":
            # the static scene's atlas, built once per shot and light, voxel columns on demand
            part = receiver_points(block, drecv, light, self._centre_cfg, roi="all",
                                   bias=self.opts.contact_bias / self.mpu)
            if part is not None:
                td[part[0]] *= self._static_atlas(light).transmittance(part[1])
            return
        keep = self._emitter_keep(light)
        for p in self._dyn_recv_paths:
            # brick-level culling first, then per Gaussian
            near_prims = toward_mask(self._caster_centres, self._caster_radii, sets[p].positions, light)
            if not near_prims.any():
                continue
            cand = np.concatenate([np.arange(*self._caster_ranges[k]) for k in np.flatnonzero(near_prims)])
            cand = cand[keep[cand]]
            near = occluders_toward(block, sets[p].positions, light, self.dgsm.k_sigma, candidates=cand)
            if near.size == 0:
                continue
            a, b = drecv.ranges[p]
            idx, val = caster_transmittance(block.subset(near), drecv, light, self._centre_cfg, roi="cone",
                                            bias=self.opts.contact_bias / self.mpu, candidates=np.arange(a, b))
            td[idx] *= val

    def _relight_pass(self, dyn: dict, sets: dict, frame: float, author, probe_dir: Path) -> dict:
        """``{path: (N, 3) s(n)}`` for every relit avatar and object (probe + transfer)."""
        relit = {}
        for r in self.roles:
            if r.per_frame and r.relight and r.role in ("avatar", "object"):
                everything, spans = self._shot_buffer(dyn)
                relit[r.path] = self._relight(r.path, sets[r.path], everything, spans[r.path], frame, author,
                                              probe_dir)
        return relit

    def _author_pass(self, frame: float, author, sets: dict, shadows: FrameShadows, relit: dict) -> None:
        """Static prims only where shadowed now or before; dynamic ones always. Results are
        per-Gaussian colour factors, which commute with SH band rotations: they are applied to the
        prim-local SH that the attribute holds (the world-space SH are rotated)."""
        srecv, drecv = self._static_recv, shadows.drecv
        u, t_static_u, t_dyn = shadows.touched, shadows.t_touched, shadows.t_dyn
        affected = []
        f = self.opts.direct_fraction
        gamma = self.opts.relight_gamma
        owner = np.searchsorted(np.array([srecv.ranges[p][1] for p in self._static_recv_paths]), u, side="right")
        for k, p in enumerate(self._static_recv_paths):
            sel = owner == k
            if not sel.any() and author.is_clean(p):
                continue
            a, b = srecv.ranges[p]
            tp = np.ones(b - a, np.float32)
            tp[u[sel] - a] = t_static_u[sel]
            sh_in = self._local_sh(p, frame, sets[p])
            sh_out = scale_sh(sh_in, attenuation_factor(tp, f)) if (tp < 1).any() else sh_in
            if author.receiver(p, frame, tp, sh_out, sh_in):
                affected.append(p)
        for p in self._dyn_recv_paths:
            a, b = drecv.ranges[p]
            tp = t_dyn[a:b]
            sh_in = self._local_sh(p, frame, sets[p])
            base_sh = scale_sh(sh_in, gamma * relit[p]) if p in relit else sh_in
            sh_out = scale_sh(base_sh, attenuation_factor(tp, f)) if (tp < 1).any() else base_sh
            if author.receiver(p, frame, tp, sh_out, sh_in) or p in relit:
                affected.append(p)
        for p, scale in relit.items():
            author.light_scale(p, frame, scale)
            if p not in drecv.ranges:
                sh_in = self._local_sh(p, frame, sets[p])
                author.receiver(p, frame, np.ones(sets[p].count, np.float32), scale_sh(sh_in, gamma * scale), sh_in)
        for p in affected:
            self.affected[p] = self.affected.get(p, 0) + 1

    def _local_sh(self, path: str, frame: float, g):
        """(N, K, 3) SH of prim ``path`` in its own frame (what its SH attribute holds) at
        ``frame``: ``g.sh`` (world space) when the prim's world transform has no rotation, else
        read unrotated (once per shot for static prims)."""
        static = path in self.static
        if static and path in self._local_sh_cache:
            return self._local_sh_cache[path]
        tc = Usd.TimeCode.EarliestTime() if static else Usd.TimeCode(frame)
        m = np.array(UsdGeom.Xformable(self.prims[path]).ComputeLocalToWorldTransform(tc).ExtractRotationMatrix())
        s = abs(np.linalg.det(m)) ** (1.0 / 3.0)
        sh = g.sh if s > 0 and np.allclose(m / s, np.eye(3), atol=1e-9) else read_gaussian_prim(
            self.prims[path], tc, world=False).sh
        if static:
            self._local_sh_cache[path] = sh
        return sh

    def _shot_buffer(self, dyn: dict):
        """Every Gaussian of the frame in one set for probe renders: the static part is copied
        once per shot, each frame only overwrites the dynamic prims' slots."""
        counts = tuple((p, g.count, g.sh_degree) for p, g in dyn.items())
        if self._buffer is None or self._buffer[0] != counts:
            order = list(self.static) + list(dyn)
            sets = {**self.static, **dyn}
            buf = GaussianSet.concatenate([sets[p] for p in order], label="shot")
            offsets = np.cumsum([0] + [sets[p].count for p in order])
            spans = {p: (int(offsets[i]), int(offsets[i + 1])) for i, p in enumerate(order)}
            self._buffer = (counts, buf, spans, -1)
            return buf, spans
        _, buf, spans, _ = self._buffer
        k = buf.sh.shape[1]
        for p, g in dyn.items():
            a, b = spans[p]
            buf.positions[a:b] = g.positions
            buf.orientations[a:b] = g.orientations
            buf.scales[a:b] = g.scales
            buf.opacities[a:b] = g.opacities
            buf.sh[a:b] = 0.0
            buf.sh[a:b, : g.sh.shape[1]] = g.sh[:, :k]
        return buf, spans

    def _static_atlas(self, light):
        """The static casters' shot-long DGSM for a point light (``usd_gs.shadows.static_scene``),
        without the light's own emitter Gaussians (:meth:`_emitter_keep`)."""
        key = ("atlas", tuple(np.round(light.position, 6)))
        if key not in self._scene_packs:
            self._scene_packs[key] = StaticSceneAtlas(self._scene_block.subset(self._emitter_keep(light)),
                                                      light.position, self._centre_cfg)
        return self._scene_packs[key]

    def _emitter_keep(self, light) -> np.ndarray:
        """(N_static_casters,) bool, computed once per shot and light: False for the scene
        Gaussians within ``emitter_radius`` of a point light. They are the light's own emitter
        (an estimated light sits inside the bright cluster it was found in) and cast no shadow
        for it."""
        key = (light.kind, tuple(np.round(light.position, 6)), tuple(np.round(light.direction, 6)))
        if key not in self._scene_packs:
            block = self._scene_block
            keep = np.ones(block.count, bool)
            if light.kind == "point":
                r = max(self.opts.emitter_radius / self.mpu, 3.0 * light.radius)
                keep = np.sum((block.positions.astype(np.float64) - light.position) ** 2, axis=1) > r * r
            self._scene_packs[key] = keep
        return self._scene_packs[key]

    def _relight(self, path, g, everything, span, frame, author, probe_dir):
        jit_warmup.wait_for("relight")  # cold cache: the warm-up process compiles these kernels
        t = time.perf_counter()
        centre = alpha_weighted_centroid(g)
        mask = np.ones(everything.count, bool)
        mask[span[0]:span[1]] = False
        local = self._local_normals.get(path)
        first = None
        if local is None and self.anchor_frame is not None and self.anchor_frame != frame:
            first = self._read(path, self.anchor_frame)  # a chunk: normals and clusters from the shot's first frame
            local = normals_to_local(first.orientations, gaussian_normals(first.positions, first.orientations,
                                                                          first.scales, first.opacities))
            self._local_normals[path] = local
        if local is None or local.shape[0] != g.count:
            n = gaussian_normals(g.positions, g.orientations, g.scales, g.opacities)
            local = normals_to_local(g.orientations, n)
            self._local_normals[path] = local
        blend = self._probe_blends.get(path)
        if blend is None or blend.labels.shape[0] != g.count:
            rest = first if first is not None and first.count == g.count else g
            blend = ProbeBlend.build(rest.positions, self.opts.probe_points)
            self._probe_blends[path] = blend
        normals = local_normals_to_world(g.orientations, local)
        t = self.clock.add("transfer", t)
        scale, probe = relight_factors(g, everything, mask, centre, normals, blend, self.opts)
        t = self.clock.add("probe", t)
        name = _safe_name(path)
        tex = probe_dir / f"{name}.{int(round(frame)):04d}.exr"
        h, w = self.opts.probe_texture
        probe.write_latlong_exr(tex, h, w)
        self.probe_files += 1
        rel = f"./{self.final_probe_dir.name}/{tex.name}"
        author.probe(name, frame, centre, probe.to_3dgs(), rel)
        self.clock.add("probe_write", t)
        return scale

    # ------------------------------------------------------------------ run
    def run(self, progress: bool = True) -> ProcessSummary:
        """Process the shot (module docstring); returns the summary."""
        t_start = time.perf_counter()
        warmup = jit_warmup.start()  # cold numba cache: compile the later kernels in a second process
        try:
            return self._run(t_start, progress)
        finally:
            jit_warmup.stop(warmup)

    def _run(self, t_start: float, progress: bool) -> ProcessSummary:
        self._open()
        self._read_static()
        self._shot_setup()
        out_path = Path(self.output_path)
        self.final_probe_dir = out_path.with_name(out_path.stem + "_probes")
        probe_dir = out_path.with_name(f".{out_path.stem}_probes.tmp{os.getpid()}")
        if probe_dir.exists():
            shutil.rmtree(probe_dir)
        probe_dir.mkdir(parents=True)
        try:
            with OutputLayer.create(self.input_path, self.output_path) as out:
                author = OutputAuthor(out.stage, self.frames)
                frames = self.frames
                bar = None
                if progress:
                    from tqdm import tqdm  # only for an interactive run

                    bar = tqdm(total=len(frames), unit="frame", desc="usdgs process", leave=False)
                t_frames = time.perf_counter()
                written_lights = False
                for f in frames:
                    self._frame(f, author, probe_dir)
                    if not written_lights and self.lights_used and self.lights_used[0].source == "estimated":
                        write_estimated_lights(out.stage, self.lights_used)
                        written_lights = True
                    if bar:
                        bar.update(1)
                if bar:
                    bar.close()
                self.clock.add("frames", t_frames)
                t0 = time.perf_counter()
            self.clock.add("save", t0)
            if self.final_probe_dir.exists():
                shutil.rmtree(self.final_probe_dir)
            if self.probe_files:
                os.replace(probe_dir, self.final_probe_dir)
        finally:
            if probe_dir.exists():
                shutil.rmtree(probe_dir, ignore_errors=True)
        self.clock.add("total", t_start)
        size = out_path.stat().st_size
        if self.final_probe_dir.exists():
            size += sum(p.stat().st_size for p in self.final_probe_dir.iterdir())
        return ProcessSummary(self.input_path, self.output_path, self.roles, self.lights_used, self.frames,
                              dict(self.clock.t), self.warnings, size, self.probe_files, author.samples_written,
                              dict(self.affected))
