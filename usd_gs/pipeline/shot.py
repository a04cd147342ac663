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
import threading
import time
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from numba_kernels.capsule import within_capsule
from numba_kernels.cubemap_dirs import cube_face_solid_angles
from numba_kernels.jit_options import read_only
from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local
from numba_kernels.thread_chunks import as_task, thread_count
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
from usd_gs.io.atomic import check_writable_folder, remove_stale_temps, temp_tag
from usd_gs.pipeline import jit_warmup
from usd_gs.pipeline.capture_lights import direct_fraction, estimate_for_shot, sky_occlusion_params, write_lights
from usd_gs.pipeline.options import ProcessOptions, canonical
from usd_gs.pipeline.shot_cache import ShotCache
from usd_gs.pipeline.summary import ProcessSummary
from usd_gs.point_blocks import PointBlocks, within_ball
from usd_gs.relight.appearance import read_appearance
from usd_gs.relight.avatar import linear_faces, probe_transfer, relight_factors
from usd_gs.relight.direct import self_shadow_samples
from usd_gs.relight.far_field import KEEP, FarField, FarLayers
from usd_gs.relight.parallax import ProbeBlend
from usd_gs.relight.probe import PROBE_DILATION, render_probe_faces
from usd_gs.relight.probe_merge import MergedPrim, merge_capacity, merged_distance
from usd_gs.relight.sun_estimation import up_vector
from usd_gs.resources import check_memory
from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders
from usd_gs.shadows.shading import attenuation_factor, combine_lights, light_shares, scale_sh, shade_sh_rows
from usd_gs.shadows.shot import (
    Receivers,
    occluder_sphere,
    prim_boxes,
    prim_spheres,
    prims_in_shadow,
    receiver_points,
    shared_transmittance,
)
from usd_gs.shadows.sky_occlusion import (
    caster_hidden_parts,
    combine_hidden_parts,
    min_hidden_share,
    receiver_normals,
    sky_factors_from_shares,
)
from usd_gs.shadows.static_scene import (
    SERVE_RADIUS,
    SUN_ATLAS_PITCH,
    BlockExtents,
    StaticSceneAtlas,
    StaticSceneSunAtlas,
)
from usd_gs.usd.frames import outside_warning, parse_frames
from usd_gs.usd.gaussian_prim import (
    check_deferred,
    describe_gaussian_prim,
    find_gaussian_prims,
    read_gaussian_prim,
    retyped_gaussian_prims,
    retyped_message,
)
from usd_gs.usd.lux import ShotLight, read_stage_lights
from usd_gs.usd.output_author import OutputAuthor, SegmentHalves, segment_rows
from usd_gs.usd.output_layer import OutputLayer
from usd_gs.usd.roles import resolve_roles
from usd_gs.usd.skel import has_skel_binding
from usd_gs.usd.skel_bake import bake_skinning
from usd_gs.usd.stage import open_stage, root_metadata_warnings

__all__ = ["ProcessOptions", "ProcessSummary", "ShotProcessor", "default_output_path"]

#: the shadow-pass task key of a batch of far layers (:meth:`ShotProcessor._far_batches`)
FAR_BATCH = "far layers"


class _Clock:
    def __init__(self):
        self.t: dict[str, float] = {}

    def add(self, key: str, since: float) -> float:
        now = time.perf_counter()
        self.t[key] = self.t.get(key, 0.0) + (now - since)
        return now


NO_LIGHT_NOTE = ("no light on the stage or in the capture: relit prims keep their captured mean brightness, "
                 "shaded by the probe's directions only (author a UsdLux light for absolute relighting)")


def default_output_path(input_path: str) -> str:
    """``<stem>.lit.usdc`` beside the input."""
    p = Path(input_path)
    return str(p.with_name(p.stem + ".lit.usdc"))


def _safe_name(path: str) -> str:
    return path.rstrip("/").rsplit("/", 1)[-1]


def probe_names(paths) -> dict[str, str]:
    """Probe prim (and texture) name of each relit prim path: its leaf name when no other path
    of ``paths`` has the same leaf (the usual case, stable across runs), else the leaf name
    and the first 8 hex digits of the SHA-1 of the whole path (``Biker_1a2b3c4d``): unique
    and stable, whatever order the prims come in."""
    import hashlib

    paths = list(dict.fromkeys(paths))
    leaves = [_safe_name(p) for p in paths]
    return {p: leaf if leaves.count(leaf) == 1 else f"{leaf}_{hashlib.sha1(p.encode()).hexdigest()[:8]}"
            for p, leaf in zip(paths, leaves, strict=True)}


@dataclass
class FrameShadows:
    """One frame's shadow pass: the moving receivers (``drecv``), the static receivers some light
    is blocked for (``touched``, indices into the static receivers) with their combined
    transmittance ``t_touched``, and every moving receiver's combined transmittance ``t_dyn``."""

    drecv: Receivers
    touched: np.ndarray
    t_touched: np.ndarray
    t_dyn: np.ndarray
    t_dyn_lights: list | None = None  # per shadow light: (N_moving,) transmittance (relighting's visibility)
    # the sky the moving casters hide from the touched static receivers: (len(touched),) colour
    # factor (usd_gs.shadows.sky_occlusion), None when the shot's lights hold no sky
    sky_touched: np.ndarray | None = None


class _MovingCasters:
    """Per frame, what the shadow pass's tasks share about the moving prims, each computed once by
    the first task that asks for it (a lock each: the work runs in the tasks' threads, not serially
    before them): each moving caster's packed occluders (:meth:`packed`, from ``pack(q)``) and
    bounding sphere (:meth:`bound`), and each moving receiver's bounding sphere
    (:meth:`receiver_spheres`, for prim-level culling against a caster's beam). ``casters``: the
    moving casters; ``sets``: path -> this frame's set; ``drecv``: the moving receivers."""

    def __init__(self, casters: list, pack, sets: dict, drecv: Receivers, k_sigma: float):
        self.casters = list(casters)
        self._pack, self._sets, self._drecv, self._k = pack, sets, drecv, float(k_sigma)
        self._packed: dict = {}
        self._locks = {q: threading.Lock() for q in self.casters}
        self._spheres_lock = threading.Lock()
        self._spheres = None

    def packed(self, q: str):
        """Caster ``q``'s packed occluders (``prepare_occluders``)."""
        with self._locks[q]:
            if q not in self._packed:
                self._packed[q] = self._pack(q)
            return self._packed[q]

    def _sphere_sets(self) -> tuple[dict, dict]:
        with self._spheres_lock:
            if self._spheres is None:
                # (one threaded pass over the receivers; the same values as occluder_sphere)
                rs = prim_spheres(self._drecv, self._k)
                self._spheres = ({q: rs[q] if q in rs else occluder_sphere(self._sets[q], self._k)
                                  for q in self.casters},
                                 {p: rs[p] for p in self._drecv.ranges if self._sets[p].count})
            return self._spheres

    def bound(self, q: str):
        """Caster ``q``'s bounding sphere ``(centre, radius)`` of its ``k_sigma`` extent."""
        return self._sphere_sets()[0][q]

    def receiver_spheres(self) -> dict:
        """path -> bounding sphere of every moving receiver with Gaussians."""
        return self._sphere_sets()[1]


def run_tasks(tasks: list, meanwhile=None, costs=None, sizes=None) -> list:
    """The results of ``tasks`` (callables without arguments), in their order: in up to
    ``thread_count()`` threads (each task's kernels take their share of the threads,
    ``numba_kernels.thread_chunks.as_task``; numpy releases the GIL), or one after the other with
    one thread. ``meanwhile`` (a callable
    without arguments, or None) runs on the calling thread while the tasks run (with one thread:
    before them; also when there are no tasks); it must not share state with them. ``costs``
    (None, or one expected duration per task, None where unknown) starts the threads on the
    longest tasks first (unknown ones before all: the pass ends with short tasks, not with one
    long task on one core); ``sizes`` (None, or one number per task: a proxy of its work, e.g. the
    Gaussians it draws) orders the tasks without a cost among themselves, largest first. The
    results depend on neither."""
    workers = min(len(tasks), thread_count())
    if workers <= 1:
        if meanwhile is not None:
            meanwhile()
        return [task() for task in tasks]
    from concurrent.futures import ThreadPoolExecutor

    order = _start_order(len(tasks), costs, sizes)
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="usdgs-task") as pool:
        futures = {i: pool.submit(as_task(tasks[i])) for i in order}
        if meanwhile is not None:
            meanwhile()
        return [futures[i].result() for i in range(len(tasks))]


def _local_normals_of(g) -> np.ndarray:
    """(N, 3) float32 normals of set ``g`` (``gaussian_normals``) in each Gaussian's own frame."""
    return normals_to_local(g.orientations, gaussian_normals(g.positions, g.orientations, g.scales, g.opacities))


def _empty_rows(n: int) -> GaussianSet:
    """``n`` zero rows (degree 0) to leave room in a concatenated set."""
    return GaussianSet(np.zeros((n, 3), np.float32), np.zeros((n, 4), np.float32), np.zeros((n, 3), np.float32),
                       np.zeros(n, np.float32), np.zeros((n, 1, 3), np.float32))


def _start_order(n: int, costs=None, sizes=None) -> list[int]:
    """The order :func:`run_tasks` submits ``n`` tasks in: those without a cost first, by ``sizes``
    (largest first; ties and no sizes: as given), then the others by cost, longest first."""
    unknown = [i for i in range(n) if costs is None or costs[i] is None]
    if sizes is not None:
        unknown.sort(key=lambda i: -sizes[i])
    known = sorted((i for i in range(n) if costs is not None and costs[i] is not None), key=lambda i: -costs[i])
    return unknown + known


def _timed(task, key, seconds: dict):
    """``task`` that records its wall seconds in ``seconds[key]`` (one key per task; two tasks under
    one key, e.g. two lights at one place, leave the later one's time: a hint for the order only)."""

    def run():
        t = time.perf_counter()
        try:
            return task()
        finally:
            seconds[key] = time.perf_counter() - t

    run.__wrapped__ = task  # (what it runs, for tools that name tasks)
    return run


def _spread_samples(res, prims: list, maps: dict, drecv: Receivers):
    """``(idx, T)`` over every Gaussian of the moving receivers ``prims`` from ``res``, the
    ``(idx, T)`` of their sample Gaussians (``maps[p] = (sel, nearest)``; ``nearest`` None: every
    Gaussian was a sample): each Gaussian takes its nearest sample's transmittance (1 where that
    sample was outside the caster's shadow cone)."""
    idx, val = res
    if all(maps[p][1] is None for p in prims):
        return idx, val
    out_i, out_v = [], []
    for p in prims:
        a, b = drecv.ranges[p]
        sel, nearest = maps[p]
        inside = (idx >= a) & (idx < b)
        if nearest is None:
            out_i.append(idx[inside])
            out_v.append(val[inside])
            continue
        vs = np.ones(sel.size)
        vs[np.searchsorted(sel, idx[inside] - a)] = val[inside]
        full = vs[nearest]
        moved = np.flatnonzero(full < 1.0)
        out_i.append(a + moved)
        out_v.append(full[moved])
    return (np.concatenate(out_i).astype(np.int64) if out_i else np.zeros(0, np.int64),
            np.concatenate(out_v) if out_v else np.zeros(0))


def _self_shadow_task(g, part, light, cfg: DGSMConfig, buffers=None):
    """``(idx, T)`` of a prim's self-shadow samples ``part`` through its own DGSM (``cfg``'s kappa;
    ``buffers``: ``prepare_occluders``' to reuse)."""
    (idx, val), = shared_transmittance(g, [part], light, cfg, prepare_occluders(g, cfg, buffers))
    return idx, val


def _light_key(light) -> bytes:
    """What a light's shadows depend on (its kind, position and direction), as a dict key."""
    return light.kind.encode() + np.asarray(light.position, np.float64).tobytes() + \
        np.asarray(light.direction, np.float64).tobytes()


def _scene_task(block, drecv: Receivers, light, cfg: DGSMConfig, bias: float, atlas, candidates=None):
    """``(idx, T)`` of the moving receivers (``candidates``: those rows of ``drecv`` only) in the
    static scene's shot-long ``atlas``, or None."""
    part = receiver_points(block, drecv, light, cfg, roi="all", bias=bias, candidates=candidates)
    if part is None:
        return None
    return part[0], atlas.transmittance(part[1])


class _NotAtAnchor(Exception):
    """A per-prim value asked for at the anchor frame whose Gaussian count differs there."""


class ShotProcessor:
    """Runs the steps of the module docstring for one input stage. ``options`` is not modified."""

    def __init__(self, input_path: str, output_path: str | None, options: ProcessOptions,
                 lights: list[ShotLight] | None = None, anchor_frame: float | None = None,
                 shot_cache: ShotCache | None = None):
        """``lights``: shot-level lights to use at every frame (a chunk of a farm run, see
        :meth:`shot_lights`); ``anchor_frame``: the shot's first frame when this run is a chunk
        starting later (normals are estimated there, as in the whole-shot run); ``shot_cache``:
        the farm run's shared cache of what is computed from the anchor frame
        (``usd_gs.pipeline.shot_cache``; written after each frame that added to it)."""
        self.input_path = str(input_path)
        self.output_path = str(output_path or default_output_path(input_path))
        self.opts = options.check()
        self.preset_lights = lights
        self.anchor_frame = anchor_frame
        self.shot_cache = shot_cache
        self.clock = _Clock()
        self.warnings: list[str] = []
        # the shot's DGSM options: the user's with the stage's up axis (set by _open)
        self.dgsm = self.opts.dgsm
        self._centre_cfg = replace(self.dgsm, sampling="center")
        self.mpu = 1.0
        # caches that live for the whole shot
        self._shot_lights: list[ShotLight] | None = None
        # shot-long static-scene caches: per light its atlas, emitter masks and calibration; the
        # static prim sets (_static_receivers); the block's chunk extents
        self._scene_packs: dict = {}
        self._buffer = None  # the probe renders' concatenated shot (_shot_buffer)
        self._static_shared = None  # (static rows, whole set) the static receivers and the buffer share
        self._local_normals: dict = {}
        self._normals_ahead: dict = {}  # path -> (the set, its local normals): _estimate_normals_ahead
        self._probe_blends: dict = {}
        # this frame's moving prims merged for the other prims' probes (_merge_setup, _merged_prim)
        self._merge_due: dict = {}
        self._merge_locks: dict = {}
        self._merged: dict = {}
        self._far_fields: dict = {}  # relit prim -> its far-layer cache; ("layers", static count) -> their FarLayers
        self._unchecked: list = []  # the static prims' finite checks not made yet (_read_static, _check_static)
        self._packs: dict = {}  # (moving caster, use) -> its packed-occluder buffers (_pack_buffers)
        self._task_seconds: dict = {}  # the last shadow pass's seconds per task key (its task order)
        self._local_sh_cache: dict = {}
        self._constant: set[str] = set()  # prims with nothing time-sampled (_open)
        self._held_reads: dict = {}  # their sets, read once (_read)
        self._held_packs: dict = {}  # their packed occluders as casters (_packed_caster)
        # their shadows under each light that does not move: (kind, prim, light key) -> (idx, T)
        self._held_shadows: dict = {}
        self._held_sky: dict = {}  # (prim, smallest hidden share kept) -> the sky it hides (_sky_task)
        self._held_from = None  # the lights of the last processed frame (_hold_frame)
        self._samples: dict = {}  # (prim, samples, count) -> its nearest-sample map (_sample_map)
        self._static_normals: np.ndarray | None = None  # static receivers' normals (_sky_hidden)
        self._frame_now: float | None = None  # the frame being processed
        # (frame, the moving prims' sets or None, the error reading them or None): read ahead (_read_ahead)
        self._ahead: tuple | None = None
        self._calib_centre = None  # where estimated lights are calibrated (_calibration_centre)
        # what the run did
        self.affected: dict[str, int] = {}
        self.probe_files = 0
        self.lights_used: list[ShotLight] = []
        self._pending_writes: list = []  # the last frame's files and authoring, not done yet (flush_writes)
        self.capture = None  # usd_gs.pipeline.capture_lights.CaptureLights of an estimate
        self.capture_lines: list[str] = []  # what the estimate found (printed by usdgs process)

    # ------------------------------------------------------------------ set-up
    def _open(self):
        t0 = time.perf_counter()
        self.stage = open_stage(self.input_path, allow_missing=self.opts.allow_missing or None)
        prims = find_gaussian_prims(self.stage)
        retyped = [retyped_message(*r) for r in retyped_gaussian_prims(self.stage)]
        if not prims:
            more = f"; {len(retyped) - 1} more such prim(s)" if len(retyped) > 1 else ""
            raise UserError(f"{self.input_path}: no ParticleField3DGaussianSplat prims to process"
                            + (f" ({retyped[0]}{more})" if retyped else ""))
        self.warnings += retyped + root_metadata_warnings(self.stage, self.input_path)
        self.prims = {str(p.GetPath()): p for p in prims}
        shared: dict = {}  # (the prims' ancestors read once)
        infos = [describe_gaussian_prim(p, Usd.TimeCode.EarliestTime(), shared=shared) for p in prims]
        self.counts = {i.path: i.count for i in infos}
        self.degrees = {i.path: i.sh_degree for i in infos}
        # prims with nothing time-sampled (data, transforms) and not skinned (a skeleton's pose may move
        # without a time sample on the prim or its ancestors): the same set every frame
        self._constant = {i.path for i in infos if i.time_samples is None and not i.animated}
        self.roles, warnings = resolve_roles(infos, self.opts.scene_paths, self.opts.avatar_paths,
                                             self.opts.object_paths)
        # (listed once: a shot has thousands of bricks, and these are asked for several times a frame)
        #: the prims processed per frame (``ResolvedRole.per_frame``) and the relit avatars and
        #: objects among them, in the order of the roles
        self._moving_paths = tuple(r.path for r in self.roles if r.per_frame)
        self._relit_paths = tuple(r.path for r in self.roles
                                  if r.per_frame and r.relight and r.role in ("avatar", "object"))
        self.warnings += warnings
        self.frames = parse_frames(self.opts.frames, self.stage.GetStartTimeCode(), self.stage.GetEndTimeCode())
        outside = outside_warning(self.frames, self.stage.GetStartTimeCode(), self.stage.GetEndTimeCode(),
                                  self.input_path)
        if outside and self.anchor_frame is None:  # a chunk task is part of a run that warned already
            self.warnings.append(outside)
        up = UsdGeom.GetStageUpAxis(self.stage)
        self.dgsm = replace(self.opts.dgsm, up_axis="Z" if up == UsdGeom.Tokens.z else "Y")
        self._centre_cfg = replace(self.dgsm, sampling="center")
        self.mpu = UsdGeom.GetStageMetersPerUnit(self.stage) or 1.0
        self.clock.add("open", t0)

    def _read(self, path: str, frame: float):
        """A prim's Gaussians at ``frame``. A prim with nothing time-sampled (e.g. an inserted object
        or character that holds one pose, processed every frame since what lights it moves) is read
        once and its set reused at every frame: the same values (sets are never written in place)."""
        return self._once(self._held_reads, path, path, partial(self._read_usd, path, frame))

    def _once(self, store: dict, key, prim: str, compute):
        """``compute()``; for ``prim`` with nothing time-sampled, computed once and kept in
        ``store[key]`` (the held reads, packs and sky parts: values that do not change while the
        prim holds its pose)."""
        if prim not in self._constant:
            return compute()
        got = store.get(key)
        if got is None:
            got = store[key] = compute()
        return got

    def _read_usd(self, path: str, frame: float):
        # (the attribute types were checked by _open's describe_gaussian_prim)
        return read_gaussian_prim(self.prims[path], Usd.TimeCode(frame), check_types=False)

    def _read_static(self):
        """The static prims' sets; that their values are finite is checked where they are first
        concatenated (:meth:`_static_part`: while copied, one pass less over a large scene) or
        by :meth:`_check_static` before any other use (the same named errors)."""
        t0 = time.perf_counter()
        self._unchecked = []
        self.static = {r.path: read_gaussian_prim(self.prims[r.path], Usd.TimeCode.EarliestTime(), check_types=False,
                                                  defer_finite=self._unchecked)
                       for r in self.roles if not r.per_frame}
        self.clock.add("read", t0)

    def _check_static(self) -> None:
        """The finite checks that :meth:`_read_static` left (``check_deferred``: ``GaussianDataError``
        naming the first static prim, attribute and element that is not finite)."""
        unchecked, self._unchecked = self._unchecked, []
        check_deferred(unchecked)

    # ------------------------------------------------------------------ lights
    def _estimate(self, frames: list[float], k: int) -> list[ShotLight]:
        """Lights estimated from the capture (``usd_gs.pipeline.capture_lights``: open or closed,
        sun and sky or plausible point lights); what it found goes to ``capture_lines``."""

        if not hasattr(self, "static"):  # (shot_lights reads the static prims only for an estimate)
            self._read_static()
        self.capture = estimate_for_shot(self, frames, k)
        self.capture_lines = list(self.capture.lines)
        if not self.capture.lights:
            self.warnings.append("no lights could be estimated" if not self.capture.lines
                                 else self.capture.lines[-1])
        return self.capture.lights

    def _lights(self, frame: float) -> list[ShotLight]:
        if self.preset_lights is not None:
            return self.preset_lights
        t0 = time.perf_counter()
        mode = self.opts.lights
        if mode in ("auto", "stage"):
            lights, warns = read_stage_lights(self.stage, Usd.TimeCode(frame), include_domes=True)
            for w in warns:
                if w not in self.warnings:
                    self.warnings.append(w)
            domes = [lt for lt in lights if lt.kind == "dome"]
            if len(lights) > len(domes) or mode == "stage":
                if not lights:
                    raise UserError(f"{self.input_path}: --lights stage but the stage has no usable UsdLux light")
                self.clock.add("lights", t0)
                return lights
            k = self.opts.default_light_count
        else:
            k = self.opts.default_light_count if mode in ("indoor", "outdoor") else int(mode)
            domes = []
        if self.opts.lights_per_frame:
            lights = self._estimate([frame], k)
        else:
            if self._shot_lights is None:
                self._shot_lights = self._estimate(self.frames, k)
            lights = self._shot_lights
        self.clock.add("lights", t0)
        # a dome the stage authors is the user's: it replaces an estimated sky
        return [lt for lt in lights if not (domes and lt.kind == "dome")] + domes

    def shot_lights(self) -> list[ShotLight] | None:
        """The shot-level step of a chunked run: opens the input and returns the lights estimated
        once over the whole frame range (what every chunk must use), or None where each frame
        reads the stage's UsdLux lights or re-estimates (``lights_per_frame``). Sets ``frames``; reads
        the static prims only for an estimate."""
        self._open()
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
        self._static_recv = self._static_receivers(self._static_recv_paths)
        boxes = prim_boxes(self._static_recv, self.dgsm.k_sigma)
        self._spheres = prim_spheres(self._static_recv, self.dgsm.k_sigma, boxes)
        static_casters = [r.path for r in self.roles if not r.per_frame and r.casts_shadows]
        casters = self._static_receivers(static_casters)
        if casters is self._static_recv and self._centre_cfg.k_sigma == self.dgsm.k_sigma:
            # the static atlases' extents from the prims' boxes just computed (one pass, not two)
            self._scene_packs["block extents"] = BlockExtents(casters.gaussians, self.dgsm.k_sigma, *boxes)
        self._scene_block = casters.gaussians if static_casters else None
        self._scene_block_ranges = casters.ranges
        self._casters_dyn = [r.path for r in self.roles if r.per_frame and r.casts_shadows and r.role != "scene"]
        self._check_static()  # (a static prim in neither set)

    def _static_receivers(self, paths: list) -> Receivers:
        """The static prims ``paths`` concatenated (``Receivers``), once per shot and list of paths:
        the static receivers, the static casters and the light estimate's scene share it when they
        name the same prims, and the probe renders' shot buffer when they are every static prim
        (:meth:`_static_part`)."""
        key = ("static set", tuple(paths))
        if key not in self._scene_packs:
            parts = [(p, self.static[p]) for p in paths]
            shared = self._static_part() if tuple(paths) == tuple(self.static) else None
            if shared is None:
                self._check_static()
            self._scene_packs[key] = (Receivers.build(parts) if shared is None
                                      else Receivers(shared[0], Receivers.row_ranges(parts)))
        return self._scene_packs[key]

    def _point_blocks(self, ranges: dict) -> PointBlocks | None:
        """The static prims' rows of a static set (its prims' ``ranges``: the shot buffer's spans, the
        static casters' ranges) as ``PointBlocks`` for ball tests, once per shot and row layout (sets
        of the same layout are the same static prims in the same order: they share one); None where
        the prims do not tile the set's leading rows."""
        blocks = PointBlocks.of_ranges({p: ranges[p] for p in self.static if p in ranges})
        if blocks is None:
            return None
        return self._scene_packs.setdefault(("point blocks", tuple(blocks.starts.tolist())), blocks)

    def _static_part(self):
        """Every static prim concatenated in the shot buffer's order (:meth:`_shot_buffer`) into arrays
        with room after them for the moving prims' rows (their counts as described at the start):
        ``(the static rows, as views, the whole set)``, kept as ``self._static_shared``, so that the
        shot buffer is the same arrays, not a second copy of the static scene. None (each then has
        its own copy) where the buffer could differ from the plain concatenation: a moving prim of
        a higher SH degree, or raw log-scales, logit opacities or extras that concatenation keeps."""
        static = list(self.static.values())
        moving = self._moving_paths
        if not static or any(g.log_scales is not None or g.logit_opacities is not None or g.extras for g in static):
            return None
        degree = max(g.sh_degree for g in static)
        if any(self.degrees.get(p, degree + 1) > degree for p in moving):
            return None
        rows = sum(self.counts[p] for p in moving) + self._merge_rows([self.counts[p] for p in moving])
        finite: list | None = [] if self._unchecked else None
        whole = GaussianSet.concatenate(static + [_empty_rows(rows)], label="shot", finite=finite)
        if finite is not None and finite[0]:  # every static value is finite: their checks are made
            self._unchecked = []
        self._check_static()  # (what is left: raises, naming the first value that is not finite)
        n = whole.count - rows
        part = GaussianSet(whole.positions[:n], whole.orientations[:n], whole.scales[:n], whole.opacities[:n],
                           whole.sh[:n], label="receivers")
        self._static_shared = (part, whole)
        # each static prim's set becomes its rows of the whole (the same values, read-only as the
        # arrays read from USD are), so that those arrays are freed: one copy of the static scene
        at = 0
        for p, g in list(self.static.items()):
            if g.sh.shape[1] == whole.sh.shape[1]:
                self.static[p] = GaussianSet(*(read_only(getattr(whole, f)[at:at + g.count]) for f in
                                               ("positions", "orientations", "scales", "opacities", "sh")),
                                             label=g.label)
            at += g.count
        return self._static_shared

    # ------------------------------------------------------------------ per frame
    def _frame(self, frame: float, author, probe_dir: Path):
        """One frame: read what moves, the lights, then the shadow, relighting and authoring passes.
        The authoring is left for the next frame's shadow tasks to overlap (:meth:`flush_writes`)."""
        self._frame_now = frame
        t = time.perf_counter()
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead[0] == frame:
            if ahead[2] is not None:  # (raised where the plain read would have raised it)
                raise ahead[2]
            dyn = ahead[1]
        else:
            dyn = self._read_moving(frame)
        sets = {**self.static, **dyn}
        self.clock.add("read", t)
        lights = self._lights(frame)
        self.lights_used = lights
        self._held_from = lights  # (what a later frame that holds this one's results must have)
        t = time.perf_counter()
        jobs = self._relight_jobs(dyn, sets, frame, lights)
        self.clock.add("relight", t)
        # the probe renders and transfers need no shadow map: they run beside the shadow tasks
        # the previous frame's probe files and authoring run on this thread while this frame's shadow tasks run
        # and the next frame's moving prims are read ahead there too (a serial step less between frames)
        # (the far layers that several probes miss, e.g. at the first frame: one task renders them together)
        first = self._far_batches(jobs)
        shadows, transfers = self._shadow_pass(sets, [lt for lt in lights if lt.kind != "dome"],
                                               first + [partial(self._probe_task, path, job) for path, job in jobs],
                                               meanwhile=partial(self._beside_tasks, frame),
                                               extra_keys=[(FAR_BATCH, i) for i in range(len(first))]
                                               + [p for p, _ in jobs])
        transfers = transfers[len(first):]
        t = time.perf_counter()
        relit, probes = self._relight_pass(jobs, transfers, lights, shadows)
        self.clock.add("relight", t)
        direct = self.opts.direct_fraction if self.opts.direct_fraction is not None else self._direct_fraction()
        self._pending_writes.append(partial(self._write_frame, frame, author, probe_dir, probes, sets, shadows,
                                            relit, direct))

    def _beside_tasks(self, frame: float) -> float:
        """What runs on this thread while ``frame``'s shadow tasks run: the writes left pending
        (:meth:`flush_writes`), then :meth:`_read_ahead` of the next frame. Returns its seconds."""
        seconds = self.flush_writes()
        later = self.frames[self.frames.index(frame) + 1:] if frame in self.frames else []
        if later:
            t = time.perf_counter()
            self._read_ahead(later[0])
            seconds += self.clock.add("read", t) - t
        return seconds

    def _read_moving(self, frame: float) -> dict:
        """path -> the moving prim's set at ``frame`` (:meth:`_read`)."""
        return {p: self._read(p, frame) for p in self._moving_paths}

    def _read_ahead(self, frame: float) -> None:
        """:meth:`_read_moving` of ``frame`` (the next frame to process), kept for :meth:`_frame`
        (``_read`` is a pure function of the prim and the time: the same sets). An error reading
        them is kept too and raised when that frame reads, so a run stops at the same frame."""
        try:
            self._ahead = (frame, self._read_moving(frame), None)
        except Exception as exc:  # noqa: BLE001 - re-raised by _frame
            self._ahead = (frame, None, exc)

    def _hold_frame(self, frame: float) -> bool:
        """True when ``frame`` holds the last processed frame's results, which then stand for it (nothing
        is computed or authored: every value holds): no prim it processes per frame has anything
        time-sampled and its lights equal that frame's (a static insert in a static capture, e.g. under
        a moving camera). The relit prims count as relit at it."""
        if self._held_from is None or not self._all_constant:
            return False
        # (stage lights are read again by _frame where they moved; estimated ones are the shot's, or
        # estimated again per frame from the same prims: the same lights, so the frame holds)
        if canonical(self._lights(frame)) != canonical(self._held_from):
            return False
        for p in self._relit_paths:
            self.affected[p] = self.affected.get(p, 0) + 1
        return True

    def flush_writes(self) -> float:
        """Do the writes left pending, in the order they were left: the last processed frame's probes
        and shadowed and relit SH (:meth:`_frame` leaves them for the next frame's shadow tasks to
        overlap; the run calls this after its last frame), and what the run queued after them.
        Returns the seconds it took (0 when nothing was pending)."""
        writes, self._pending_writes = self._pending_writes, []
        if not writes:
            return 0.0
        t = time.perf_counter()
        jit_warmup.wait_for("author")  # cold cache: the warm-up process compiles the authoring's kernels
        for write in writes:
            write()
        return self.clock.add("write", t) - t

    def _shadow_pass(self, sets: dict, lights: list[ShotLight], extra=(), meanwhile=None,
                     extra_keys=None) -> tuple[FrameShadows, list]:
        """Every light's transmittance on every receiver, combined by the lights' shares; ``extra``
        tasks (callables without arguments, e.g. the probe renders) run in the same threads as the
        shadow tasks, ``meanwhile`` (returning its seconds, not counted as the pass's) on this
        thread while they run (``run_tasks`` calls it even without tasks); ``extra_keys``: a name per
        extra task that stays the same from frame to frame (default: its position), under which its
        time is kept for the next frame's order. The threads start on the tasks that took longest at
        the last frame. Returns ``(shadows, the extra tasks' results)``."""
        clk = self.clock
        t = time.perf_counter()
        srecv = self._static_recv
        drecv = Receivers.build([(p, sets[p]) for p in self._dyn_recv_paths])
        t = clk.add("prepare", t)

        cfg = self.dgsm
        # what casters with nothing time-sampled gave under lights that are no longer used
        used = {_light_key(lt) for lt in lights}
        self._held_shadows = {k: v for k, v in self._held_shadows.items() if k[2] in used}
        # the moving casters' packings and the moving prims' bounding spheres (prim-level culling
        # against each caster's beam, as for the bricks), made by the tasks that use them
        movers = _MovingCasters(self._casters_dyn if lights else [], lambda q: self._packed_caster(q, sets[q]),
                                sets, drecv, cfg.k_sigma)
        self._self_vis = {}  # this frame's self-shadowing of relit prims: (prim, id(light)) -> (N_moving,)
        s_light, d_light, touched = [], [], []
        # every light's casters, self-shadows and static-scene lookups side by side in threads
        # (their serial parts overlap), combined in a fixed order: the values of a serial run
        work = [self._light_tasks(light, sets, drecv, movers) for light in lights]
        extra = list(extra)
        sky = self._sky_task(sets)
        aside = []
        # longest first, by what each task took at the last frame (keyed by kind, prim and light)
        keys = ([("extra", k) for k in (range(len(extra)) if extra_keys is None else extra_keys)] + [("sky",)]
                + [(*step, _light_key(light)) for light, (_, _, steps) in zip(lights, work, strict=True)
                   for step in steps])
        last, self._task_seconds = self._task_seconds, {}
        every = extra + [sky or (lambda: None)] + [task for light_tasks, _, _ in work for task in light_tasks]
        results = run_tasks([_timed(task, key, self._task_seconds) for task, key in zip(every, keys, strict=True)],
                            (lambda: aside.append(meanwhile())) if meanwhile is not None else None,
                            costs=[last.get(key) for key in keys], sizes=self._task_sizes(keys, sets))
        t += sum(aside)  # (the shadow pass's clock leaves out what ran beside it)
        extra, shares, results = results[:len(extra)], results[len(extra)], results[len(extra) + 1:]
        start = 0
        for tasks, apply, _ in work:
            hits, td = apply(results[start:start + len(tasks)])
            start += len(tasks)
            s_light.append(hits)
            d_light.append(td)
            touched.extend(idx for idx, _ in hits)
        # static receivers: combine lights only where some light is blocked (each light's
        # transmittance there: the product of its casters')
        u = np.unique(np.concatenate(touched)) if touched else np.zeros(0, np.int64)
        t_static_u = np.ones(0, np.float32)
        if u.size:
            per = []
            for hits in s_light:
                t_light = np.ones(u.size)
                for idx, val in hits:
                    t_light[np.searchsorted(u, idx)] *= val
                per.append(t_light)
            t_static_u = combine_lights(per, light_shares(lights, srecv.gaussians.positions[u]))
        # moving receivers: the lights' shares only where some light is blocked (elsewhere every
        # light gives 1, and so does any mix of them: combine_lights snaps it to exactly 1)
        t_dyn = np.ones(drecv.gaussians.count, np.float32)
        dark = np.flatnonzero(np.logical_or.reduce([td < 1.0 for td in d_light])) if lights else []
        if len(dark):
            t_dyn[dark] = combine_lights([td[dark] for td in d_light],
                                         light_shares(lights, drecv.gaussians.positions[dark]))
        u, t_static_u, sky_u = self._sky_hidden(shares, u, t_static_u)
        clk.add("shadows", t)
        return FrameShadows(drecv, u, t_static_u, t_dyn, d_light, sky_u), extra

    def _task_sizes(self, keys: list, sets: dict) -> list[int]:
        """A proxy of each shadow-pass task's work, for the order of tasks that have not run yet (a
        shot's first frame, a new light): the Gaussians it draws or packs. A probe render (``extra``)
        draws the whole frame, the static scene's task builds its shot-long atlas over the static
        casters, a caster's and a self-shadow's DGSM packs the prim, the sky task is small. Where a
        batch of far layers runs (``extra`` keyed ``(FAR_BATCH, i)``, :meth:`_far_batches`), it
        starts first and the probe renders last: started early, they would wait for its layers."""
        total = sum(g.count for g in sets.values())
        scene = self._scene_block.count if self._scene_block is not None else 0
        sizes = {"extra": total, "sky": 0, "scene": scene}
        batches = [key[0] == "extra" and isinstance(key[1], tuple) and key[1][0] == FAR_BATCH for key in keys]

        def size(key, batch: bool):
            if key[0] == "extra" and any(batches):  # far layers first, the probes that use them last
                return 2 * total if batch else 1
            return sizes[key[0]] if key[0] in sizes else sets[key[1]].count

        return [size(key, batch) for key, batch in zip(keys, batches, strict=True)]

    def _sky_task(self, sets: dict):
        """The frame's ``hidden_sky_shares`` as a task (``usd_gs.shadows.sky_occlusion``: the sky the
        moving casters hide from the static receivers around them) when the shot's lights hold a
        sky, else None."""
        params = sky_occlusion_params(self, self.lights_used or [])
        if params is None or not self._casters_dyn or not self._static_recv.gaussians.count:
            return None
        up = up_vector(self.dgsm.up_axis)
        if self._static_normals is None:  # once per shot: the static receivers do not move
            g = self._static_recv.gaussians
            self._static_normals = receiver_normals(g, np.arange(g.count))
        h_min = min_hidden_share(params, self.opts.sh_tolerance)
        if h_min >= 1.0:
            return lambda: (np.zeros(0, np.int64), np.zeros(0, np.float32))
        # a caster with nothing time-sampled hides the same sky at every frame: its parts are held
        self._held_sky = {k: v for k, v in self._held_sky.items() if k[1] == h_min}
        srecv, spheres, normals = self._static_recv, self._spheres, self._static_normals

        def task():
            parts = []
            for q in self._casters_dyn:
                parts.extend(self._once(self._held_sky, (q, h_min), q,
                                        partial(caster_hidden_parts, sets[q], srecv, spheres, up, h_min, normals)))
            return combine_hidden_parts(parts, h_min)

        return task

    def _sky_hidden(self, shares, u: np.ndarray, t_u: np.ndarray):
        """``(touched, their transmittance, their sky factor or None)`` from :meth:`_sky_task`'s
        ``shares`` (None: no sky): the touched set widened by the receivers the sky part alone
        darkens (transmittance 1)."""
        if shares is None:
            return u, t_u, None
        idx, k = sky_factors_from_shares(shares, sky_occlusion_params(self, self.lights_used or []), sun_t=(u, t_u))
        if idx.size == 0:
            return u, t_u, np.ones(u.size, np.float32)
        both = np.union1d(u, idx)
        t2 = np.ones(both.size, np.float32)
        t2[np.searchsorted(both, u)] = t_u
        k2 = np.ones(both.size, np.float32)
        k2[np.searchsorted(both, idx)] = k
        return both, t2, k2

    def _light_tasks(self, light, sets: dict, drecv: Receivers, movers: _MovingCasters):
        """One light's shadow work as independent tasks (callables without arguments, which read no
        USD and change no cache but the light's own static atlas): every moving caster's DGSM
        sampled on the static receivers in its beam and on the other moving receivers
        (:meth:`_caster_task`), each relit caster's self-shadow, and the static
        scene's shadow on the moving receivers from its shot-long atlas (built once per shot and
        light, voxel columns on demand: ``StaticSceneAtlas`` for a point light,
        ``StaticSceneSunAtlas`` for a directional one). Returns ``(tasks, apply, steps)``: ``apply(results)``
        combines the tasks' results in a fixed order into ``(hits, moving transmittance)``, ``hits``
        a list of ``(idx, T)`` per caster, the static receivers it shadows (T < 1), the same values whether the
        tasks ran one after the other or side by side, in any order; ``steps`` names each task
        (its kind and prim)."""
        tasks, steps = [], []
        for q in self._casters_dyn:
            tasks.append(partial(self._caster_task, q, light, sets[q], drecv, movers))
            steps.append(("cast", q))
            # self-shadowing: its own DGSM (sharing the atlas would widen every pixel's radial range
            # to the caster's own depth: measured 2x the demo's shadow time), with its own kappa:
            # on the outdoor ground truth kappa 1 / 0.5 / 0.25 give 29.1 / 30.4 / 32.0 dB (exact
            # visibility 41.8 dB): the overlapping splats of one skin layer over-absorb for the
            # points just above it
            task = self._self_task(q, sets[q], drecv, light)
            if task is not None:
                tasks.append(task)
                steps.append(("self", q))
        block = self._scene_block
        if block is not None and block.count and drecv.ranges:
            # (atlas key, its prims): for a point light an atlas per moving receiver prim, each packing
            # what its own reach needs, the prims with nothing time-sampled sharing one (each looks up
            # once per light); for a directional light one lattice atlas
            groups = [(None, list(drecv.ranges))]
            if light.kind == "point":
                held = [p for p in drecv.ranges if p in self._constant]
                groups = [(p, [p]) for p in drecv.ranges if p not in self._constant] + ([(None, held)] if held else [])
            for key, prims in groups:
                atlas = self._static_atlas(light, key) if light.kind == "point" else self._static_sun_atlas(light)
                tasks.append(self._scene_shadow_task(block, drecv, light, atlas, prims))
                steps.append(("scene", key))

        def apply(results):
            hits = []  # the static receivers each caster shadows, with their transmittance
            td = np.ones(drecv.gaussians.count)
            for (kind, q), res in zip(steps, results, strict=True):
                if kind == "cast":
                    (idx, val), (idx_d, val_d) = res
                    below = val < 1.0
                    hits.append((idx[below], val[below]))
                    td[idx_d] *= val_d
                elif kind == "self":
                    idx_o, val_o = res
                    if idx_o.size:
                        # self-shadowing shades only the relighting's direct term (the transmittance
                        # primvar and the attenuation of unrelit prims keep other prims' shadows only)
                        own = self._self_vis.setdefault((q, id(light)), np.ones(drecv.gaussians.count))
                        a, b = drecv.ranges[q]
                        sel, nearest = self._sample_map(q, self.opts.self_shadow_samples,
                                                        drecv.gaussians.positions[a:b])
                        vs = np.ones(sel.size)
                        vs[np.searchsorted(a + sel, idx_o)] = val_o
                        own[a:b] *= vs[nearest]  # each Gaussian takes its nearest sample's self-shadow
                elif res is not None:
                    td[res[0]] *= res[1]
            return hits, td

        return tasks, apply, steps

    def _pack_buffers(self, q: str, use, n: int):
        """``(occ (n, 16), cov6 (n, 6))`` float64 buffers that moving caster ``q``'s packed occluders
        for ``use`` are written into every frame (``prepare_occluders``' ``out``; kept for the shot
        while the count stays: a fresh 20-30 MB buffer per frame costs its page faults, several
        times the packing). Each frame's packing overwrites the last; nothing keeps it longer."""
        key = (q, use)
        got = self._packs.get(key)
        if got is None or got[0].shape[0] != n:
            got = (np.empty((n, 16)), np.empty((n, 6)))
            self._packs[key] = got
        return got

    def _caster_task(self, q: str, light, g, drecv: Receivers, movers: _MovingCasters):
        """Caster ``q``'s one DGSM for ``light`` over the static and the moving receivers' voxels:
        ``((idx, T) static, (idx, T) moving)`` (``shared_transmittance``)."""
        cfg = self.dgsm
        srecv = self._static_recv
        bound = movers.bound(q)
        held = ("cast", q, _light_key(light)) if q in self._constant else None
        res_s = self._held_shadows.get(held) if held is not None else None
        part_s = None
        if res_s is None:
            hit = prims_in_shadow(self._spheres, g, light, cfg.k_sigma, bound)
            if hit:
                cand = np.concatenate([np.arange(*srecv.ranges[p]) for p in hit])
                part_s = receiver_points(g, srecv, light, cfg, roi=self.opts.roi, candidates=cand, sphere=bound)
        part_d = None
        dhit = [p for p in prims_in_shadow(movers.receiver_spheres(), g, light, cfg.k_sigma, bound) if p != q]
        maps = {p: self._receiver_sample_map(p, drecv) for p in dhit}
        if dhit:
            cand = np.concatenate([drecv.ranges[p][0] + maps[p][0] for p in dhit])
            part_d = receiver_points(g, drecv, light, cfg, roi=self.opts.roi, candidates=cand, sphere=bound)
        if held is None:
            res_s, res_d = shared_transmittance(g, [part_s, part_d], light, cfg, movers.packed(q))
        else:
            # a caster that does not move under a light that does not move: its shadows on the static
            # receivers are the same at every frame, from a DGSM of those receivers alone (one per shot:
            # a chunk of a farm run gets the whole run's values); the moving receivers' from their own
            if res_s is None:
                res_s = self._held_shadows[held] = shared_transmittance(g, [part_s], light, cfg, movers.packed(q))[0]
            res_d = shared_transmittance(g, [part_d], light, cfg, movers.packed(q))[0]
        return res_s, _spread_samples(res_d, dhit, maps, drecv)

    def _scene_shadow_task(self, block, drecv: Receivers, light, atlas, prims: list):
        """The task giving ``(idx, T)`` of the moving receivers of ``prims`` (paths in ``drecv``) in
        the static scene's shot-long ``atlas`` (``_scene_task``), or None. A receiver prim with
        nothing time-sampled takes its values once per light and holds them (their values do not
        depend on what else is looked up)."""
        cfg, bias = self._centre_cfg, self.opts.contact_bias / self.mpu
        held = [p for p in prims if p in self._constant]
        rows = [np.arange(*drecv.ranges[p]) for p in prims if p not in self._constant]
        if not held:
            whole = len(prims) == len(drecv.ranges)
            return partial(_scene_task, block, drecv, light, cfg, bias, atlas, None if whole else np.concatenate(rows))
        key = _light_key(light)
        moving = np.concatenate(rows) if rows else np.zeros(0, np.int64)

        def task():
            parts = []
            if moving.size:
                parts.append(_scene_task(block, drecv, light, cfg, bias, atlas, moving))
            for p in held:
                a, b = drecv.ranges[p]
                got = self._held_shadows.get(("scene", p, key))
                if got is None:  # (relative to the prim's first row: other prims' counts may change)
                    res = _scene_task(block, drecv, light, cfg, bias, atlas, np.arange(a, b))
                    got = (np.zeros(0, np.int64), np.zeros(0)) if res is None else (res[0] - a, res[1])
                    self._held_shadows[("scene", p, key)] = got
                parts.append((a + got[0], got[1]))
            parts = [r for r in parts if r is not None]
            if not parts:
                return None
            return np.concatenate([r[0] for r in parts]), np.concatenate([r[1] for r in parts])

        return task

    def _packed_caster(self, q: str, g):
        """Moving caster ``q``'s packed occluders for this frame (``prepare_occluders``), written into
        its shot-long buffers; once per shot for a prim with nothing time-sampled."""
        return self._once(self._held_packs, q, q,
                          lambda: prepare_occluders(g, self.dgsm, self._pack_buffers(q, "cast", g.count)))

    def _self_task(self, q: str, g, drecv: Receivers, light):
        """The task giving ``(idx, T)`` of relit prim ``q``'s self-shadow samples through its own DGSM
        for ``light`` (``idx`` in ``drecv``), or None (no self-shadowing). For a prim with nothing
        time-sampled under a light that does not move, computed once per shot and held."""
        held = ("self", q, _light_key(light)) if q in self._constant else None
        a = drecv.ranges[q][0] if q in drecv.ranges else 0
        got = self._held_shadows.get(held) if held is not None else None
        if got is not None:
            return lambda: (a + got[0], got[1])
        part_o = self._self_points(q, g, drecv, light)
        if part_o is None:
            return None
        cfg_o = replace(self.dgsm, kappa=self.opts.self_shadow_kappa)
        buffers = self._pack_buffers(q, ("self", id(light)), g.count)

        def task():
            idx, val = _self_shadow_task(g, part_o, light, cfg_o, buffers)
            if held is not None:  # (relative to the prim's first row: other prims' counts may change)
                self._held_shadows[held] = (idx - a, val)
            return idx, val

        return task

    def _receiver_sample_map(self, p: str, drecv: Receivers):
        """``(sel, nearest)`` of moving receiver ``p`` for the shadows other moving casters put on it
        (:meth:`_sample_map` of ``moving_receiver_samples``); ``(every index, None)`` when that is 0
        or the prim is not larger."""
        a, b = drecv.ranges[p]
        n = self.opts.moving_receiver_samples
        if n <= 0 or b - a <= n:
            return np.arange(b - a), None
        return self._sample_map(p, n, drecv.gaussians.positions[a:b])

    def _sample_map(self, p: str, n: int, positions: np.ndarray):
        """``(sel, nearest)`` of prim ``p`` (``self_shadow_samples``: ``sel`` every k-th of its
        Gaussians, at most ``n``, ``nearest`` (N,) the position in ``sel`` of each Gaussian's
        nearest sample), once per shot, from its Gaussians at the shot's first frame (``anchor_frame``
        in a farm chunk that starts later: the map of the whole-shot run). Gaussian k is the same
        surface point in every frame, so the map holds for the shot; a changed count gets a new
        map, from ``positions`` (this frame's) unless the first frame has that count too."""
        key = (p, int(n), len(positions))
        got = self._samples.get(key)
        if got is None:
            first = self._first_frame()

            def at_anchor():
                g = self._read(p, first) if first != self._frame_now else None
                if g is not None and g.count != len(positions):
                    raise _NotAtAnchor
                return self_shadow_samples(positions if g is None else g.positions, n)

            got = self._from_anchor(("samples", p, int(n)), at_anchor, len(positions))
            if got is None:  # the count differs from the anchor frame's: this frame's map
                got = self_shadow_samples(positions, n)
            self._samples[key] = got
        return got

    def _first_frame(self) -> float:
        """The shot's first (anchor) frame: ``anchor_frame`` in a farm chunk, else the first frame."""
        return self.anchor_frame if self.anchor_frame is not None else self.frames[0]

    def _from_anchor(self, key: tuple, compute, count: int | None = None):
        """``compute()``, a tuple of arrays computed from the shot's anchor frame, or the farm run's
        shot cache's copy (``usd_gs.pipeline.shot_cache``: the same arrays; stored there when
        computed here); a copy whose last array does not have ``count`` rows (one per Gaussian of the
        prim; None: any) is not used. None where ``compute`` raises ``_NotAtAnchor`` (the prim's
        count at the anchor frame differs from this frame's: its value is this frame's, not the
        shot's)."""
        got = self._anchor_copy(key, count)
        if got is not None:
            return got
        try:
            got = tuple(compute())
        except _NotAtAnchor:
            return None
        if self.shot_cache is not None:
            self.shot_cache.put(key, got)
        return got

    def _anchor_copy(self, key: tuple, count: int | None = None, count_load: bool = True):
        """The shot cache's copy under ``key`` that :meth:`_from_anchor` uses (its last array with
        ``count`` rows; None: any), or None; ``count_load`` False: a look that is not counted as a
        load (deciding whether something must be computed)."""
        cache = self.shot_cache
        if cache is None:
            return None
        got = cache.get(*key) if count_load else cache.peek(*key)
        return got if got is not None and (count is None or got[-1].shape[0] == count) else None

    def _self_points(self, q: str, g, drecv: Receivers, light):
        """:func:`receiver_points` of a relit prim's own Gaussians for its own DGSM (self-shadowing,
        moved ``self_shadow_bias`` toward the light), or None (not relit, not a receiver, or off)."""
        if not self.opts.self_shadow or q not in drecv.ranges or q not in self._relit_paths or not g.count:
            return None
        if light.kind != "directional" and self.opts.self_shadow_lights == "distant":
            return None  # point lights: measured 2x the demo's shadow time (self_shadow_lights='all' for them)
        a, b = drecv.ranges[q]
        sel, _ = self._sample_map(q, self.opts.self_shadow_samples, g.positions)
        part = receiver_points(g, drecv, light, self._centre_cfg, roi="all", bias=self.opts.self_shadow_bias / self.mpu,
                               candidates=a + sel)
        if part is None:
            return None
        local, _ = self._prim_local_normals(q, g, self._frame_now)
        nrm = local_normals_to_world(g.orientations, local)
        idx, pts, w = part
        off = self.opts.self_shadow_normal * float(np.median(g.scales.max(axis=1)))
        pts = pts + off * np.repeat(np.asarray(nrm, np.float64)[idx - a], len(w), axis=0)
        return idx, pts, w

    @property
    def _all_constant(self) -> bool:
        """True when no prim processed per frame has anything time-sampled."""
        return all(p in self._constant for p in self._moving_paths)


    def _relight_jobs(self, dyn: dict, sets: dict, frame: float, lights=()) -> list:
        """``[(path, relight_factors keyword arguments without visibility)]`` of every relit avatar
        and object at ``frame`` (:meth:`_relight_inputs`)."""
        jobs = []
        relit = self._relit_paths
        if relit:
            everything, spans = self._shot_buffer(dyn)
            self._merge_setup(dyn)
            self._estimate_normals_ahead({p: sets[p] for p in relit}, frame)
        for path in relit:
            jobs.append((path, self._relight_inputs(path, sets[path], everything, spans[path], frame, lights, spans)))
        self._normals_ahead = {}
        return jobs

    def _merge_setup(self, dyn: dict) -> None:
        """This frame's moving prims that another relit prim's probe draws (``dyn``: path -> set), to be
        merged per cell of ``probe_merge_cell`` metres (``usd_gs.relight.probe_merge``) by the first
        probe task that draws them (:meth:`_merged_prim`): the merges run in the shadow pass's
        threads, beside its other tasks, not before them."""
        slots = self._buffer[3]
        relit = set(self._relit_paths)
        self._merge_due = {p: g for p, g in dyn.items() if p in slots and g.count and relit - {p}}
        self._merge_locks = {p: threading.Lock() for p in self._merge_due}
        self._merged = {}

    def _merged_prim(self, path: str) -> MergedPrim | None:
        """Moving prim ``path`` merged at this frame, in its rows of the shot buffer (computed once,
        by the first caller; thread-safe), or None where it merges into more clusters than its rows
        hold (it is then drawn as it is)."""
        with self._merge_locks[path]:
            if path not in self._merged:
                buf, (a, room) = self._buffer[1], self._buffer[3][path]
                m = MergedPrim.of(self._merge_due[path], self.opts.probe_merge_cell / self.mpu)
                if m.count > room:
                    m = None
                else:
                    b, k = a + m.count, buf.sh.shape[1]
                    buf.positions[a:b] = m.positions
                    buf.orientations[a:b] = m.orientations
                    buf.scales[a:b] = m.scales
                    buf.opacities[a:b] = m.opacities
                    buf.sh[a:b, m.sh.shape[1]:] = 0.0
                    buf.sh[a:b, : m.sh.shape[1]] = m.sh[:, :k]
                self._merged[path] = m
            return self._merged[path]

    def _merged_mask(self, mask: np.ndarray, path: str, centre, spans: dict) -> None:
        """Prim ``path``'s probe at ``centre`` draws every other moving prim merged where a cluster
        lies at least ``merged_distance`` away, its Gaussians as they are elsewhere (``mask`` updated
        in place; the merged rows of the rest stay unselected)."""
        slots = self._buffer[3]
        if not slots:
            return
        mask[min(a for a, _ in slots.values()):] = False
        far_at = merged_distance(self.opts.probe_merge_cell / self.mpu, self.opts.probe_size,
                                 self.opts.probe_supersample)
        for q in self._merge_due:
            m = self._merged_prim(q) if q != path else None
            if m is None:
                continue
            far = m.far_clusters(centre, far_at)
            if far.any():
                a, b = spans[q]
                if far.all():
                    mask[a:b] = False
                else:
                    mask[a:b] &= ~far[m.labels]
                mask[slots[q][0]:slots[q][0] + m.count] = far

    def _probe_task(self, path: str, job: dict):
        """Prim ``path``'s probe render and transfer (``probe_transfer`` of its :meth:`_relight_jobs`
        entry ``job``), drawing the other moving prims merged where they are far enough
        (:meth:`_merged_mask`); a task of the shadow pass."""
        self._merged_mask(job["mask"], path, job["centre"], self._buffer[2])
        return probe_transfer(**job)

    def _estimate_normals_ahead(self, prims: dict, frame: float) -> None:
        """The relit prims' normals that :meth:`_prim_local_normals` is about to estimate from this
        frame's Gaussians (``prims``: path -> set), estimated side by side in threads (the estimate
        has serial parts: one prim at a time leaves a core idle), kept for it in ``_normals_ahead``.
        Only where it would estimate them from these sets (:meth:`_normals_step`), and not where the
        shot cache holds the shot's."""
        due = {}
        for path, g in prims.items():
            step = self._normals_step(path, g, frame)
            if step == "estimate" or (step == "shot" and self._anchor_copy(("normals", path), g.count,
                                                                           count_load=False) is None):
                due[path] = g
        if len(due) > 1:
            jit_warmup.wait_for("relight")  # (a cold cache: the warm-up process compiles the normals' kernels)
            done = run_tasks([partial(_local_normals_of, g) for g in due.values()])
            self._normals_ahead = {p: (g, n) for (p, g), n in zip(due.items(), done, strict=True)}

    def _relight_pass(self, jobs: list, transfers: list, lights=(),
                      shadows: FrameShadows | None = None) -> tuple[dict, list]:
        """``({path: (N, 3) colour factor}, [(path, probe centre, probe)])`` for every relit avatar and
        object (``usd_gs.relight.avatar``: direct lights with their DGSM visibility, probe, transfer;
        gamma included) from its :meth:`_relight_jobs` entry and its ``probe_transfer``
        (``transfers``, in the same order); the probes are written with the frame's authoring
        (:meth:`_write_frame`)."""
        relit, probes = {}, []
        t = time.perf_counter()
        keep = not lights and self.opts.keep_level_without_lights
        if keep and NO_LIGHT_NOTE not in self.warnings:
            self.warnings.append(NO_LIGHT_NOTE)
        # the prims' factors side by side (pure functions of their inputs), their probes written in order
        tasks = [partial(relight_factors, **job, visibility=self._visibility(path, lights, shadows),  # (keyed by
                         transfer=pt, keep_level=keep)  # the shadow lights, not the calibrated copies)
                 for (path, job), pt in zip(jobs, transfers, strict=True)]
        results = run_tasks(tasks)
        self.clock.add("probe", t)
        for (path, job), (scale, probe) in zip(jobs, results, strict=True):
            relit[path] = scale
            probes.append((path, job["centre"], probe))
        return relit, probes

    def _write_frame(self, frame: float, author, probe_dir: Path, probes: list, *author_args) -> None:
        """A processed frame's files and samples: each relit prim's probe (:meth:`_write_probe`, in
        order), then the shadowed and relit SH (:meth:`_author_pass` with ``author_args``); it runs
        beside the next frame's shadow tasks (:meth:`flush_writes`)."""
        for path, centre, probe in probes:
            self._write_probe(path, frame, centre, probe, author, probe_dir)
        self._author_pass(frame, author, *author_args)

    def _visibility(self, path: str, lights, shadows: FrameShadows | None) -> list:
        """Per light, the (N,) visibility of prim ``path``'s Gaussians (None: 1; domes None)."""
        out = []
        k = 0
        for lt in lights:
            if lt.kind == "dome":
                out.append(None)
                continue
            v = None
            if shadows is not None and shadows.t_dyn_lights is not None and path in shadows.drecv.ranges:
                a, b = shadows.drecv.ranges[path]
                v = np.asarray(shadows.t_dyn_lights[k][a:b], np.float64)
                own = self._self_vis.get((path, id(lt)))
                if own is not None:
                    v = v * own[a:b]
            out.append(v)
            k += 1
        return out

    def _emitter_mask(self, lights, everything, spans) -> np.ndarray:
        """(everything.count,) bool, once per shot and light set: False for the static scene
        Gaussians that make up a modelled light (within ``emitter_radius``, or 3 x its radius, of a
        point, sphere, rect or disk light's centre; :meth:`_emitter_keep`'s rule), so that the probe
        render does not count them again."""
        key = ("probe-emitters", tuple((lt.kind, tuple(np.round(lt.position, 6))) for lt in lights
                                       if lt.kind == "point"), everything.count)
        if key not in self._scene_packs:
            keep = np.ones(everything.count, bool)
            roles = {r.path: r.role for r in self.roles}
            scene = [p for p in self.static if roles.get(p) == "scene"]
            blocks = self._point_blocks(spans)
            for lt in lights:
                if lt.kind != "point":
                    continue
                r = max(self.opts.emitter_radius / self.mpu, 3.0 * lt.radius,
                        0.5 * float(np.hypot(lt.width, lt.height)))
                if blocks is not None:  # one block-by-block test over the static part
                    inside = blocks.within(everything.positions[:blocks.starts[-1]], lt.position, r)
                for p in scene:
                    a, b = spans[p]
                    keep[a:b] &= ~(inside[a:b] if blocks is not None else
                                   within_capsule(everything.positions[a:b], lt.position, lt.position, r))
            self._scene_packs[key] = keep
        return self._scene_packs[key]

    def _appearance(self, path: str, frame: float, n: int):
        """The prim's albedo or RGCA ZH fields (``usd_gs.relight.appearance``) at ``frame``, or None;
        the attribute check is cached per prim."""

        key = ("appearance", path)
        if self._scene_packs.get(key) is False:
            return None
        app = read_appearance(self.prims[path], Usd.TimeCode(frame), n)
        if app is None:
            self._scene_packs[key] = False
        return app

    def _calibrated(self, lights, everything, spans, centre) -> list:
        """The lights for the relighting: estimated point lights (not the estimated RectLights, whose
        radiance is their Gaussians' own, relit as area lights) get the radiant intensity that their
        emitter Gaussians show at one point of the shot (a render of those Gaussians alone: ``sum``
        of linear radiance x solid angle, times the squared distance), once per shot and light; the
        stage's lights are used as authored. The point is the first relit prim's centroid at the
        shot's first frame (``anchor_frame`` in a farm chunk), so chunks match the whole-shot run;
        ``centre`` is the fallback when that prim cannot be read."""

        out = []
        for lt in lights:
            if lt.source != "estimated" or lt.kind != "point" or lt.form == "rect":
                out.append(lt)  # (an estimated RectLight carries the radiance its Gaussians show)
                continue
            key = ("calibrated", tuple(np.round(lt.position, 6)))
            if key not in self._scene_packs:
                def calibrate(light=lt):
                    at = self._calibration_centre(centre)
                    mine = ~self._emitter_mask([light], everything, spans)
                    size = self.opts.probe_size
                    # (the emitter's few Gaussians by index: no pass over the shot's others, the same image)
                    rgb, alpha, _ = render_probe_faces(everything, at, size, None, order=np.flatnonzero(mine))
                    lin = linear_faces(rgb, alpha, self.opts.color_space)
                    e = (lin * cube_face_solid_angles(size)[..., None]).reshape(-1, 3).sum(axis=0)
                    return (e * float(np.sum((np.asarray(light.position, np.float64) - at) ** 2)),)

                self._scene_packs[key] = self._from_anchor(("calibrated", *(float(v) for v in key[1])), calibrate)[0]
            out.append(replace(lt, color=self._scene_packs[key], intensity=1.0, radius=0.0, shape="point"))
        return out

    def _bake_skinning(self, out_stage) -> None:
        """``--bake-skinning``: every UsdSkel-bound prim's skinned Gaussians as time samples at the
        processed frames in the output layer, its binding blocked there (``usd_gs.usd.skel_bake``)."""
        t0 = time.perf_counter()
        for path, prim in self.prims.items():
            if has_skel_binding(prim):
                bake_skinning(out_stage, path, self.frames)
        self.clock.add("bake_skinning", t0)

    def _calibration_centre(self, fallback):
        """The first relit prim's alpha-weighted centroid at the shot's first frame (cached)."""
        if self._calib_centre is None:
            relit = self._relit_paths
            first = self._first_frame()
            g = self._read(relit[0], first) if relit else None
            self._calib_centre = alpha_weighted_centroid(g) if g is not None and g.count else np.asarray(fallback)
        return self._calib_centre

    def _direct_fraction(self) -> float:
        """The share of a lit receiver's light that the shadowing lights bring, when
        ``--direct-fraction`` is not given (``usd_gs.pipeline.capture_lights.direct_fraction``)."""

        return direct_fraction(self, self.lights_used)

    def _write_lights(self, stage, lights, probe_dir: Path) -> None:
        """The estimated lights under /UsdGs/Lights (``usd_gs.pipeline.capture_lights.write_lights``;
        an estimated sky's texture goes into the probe folder)."""

        self.probe_files += write_lights(self, stage, lights, probe_dir / "sky.exr",
                                         f"./{self.final_probe_dir.name}/sky.exr")

    def _author_pass(self, frame: float, author, sets: dict, shadows: FrameShadows, relit: dict,
                     f: float) -> None:
        """Static prims only where shadowed now or before; dynamic ones always. Results are
        per-Gaussian colour factors, which commute with SH band rotations: they are applied to the
        prim-local SH that the attribute holds (the world-space SH are rotated). ``f``: the frame's
        direct fraction (``usd_gs.shadows.shading``). Reads only its arguments, the shot's static data
        and the input stage (it runs beside the next frame's shadow tasks)."""
        srecv, drecv = self._static_recv, shadows.drecv
        u, t_static_u, t_dyn = shadows.touched, shadows.t_touched, shadows.t_dyn
        sky_u = shadows.sky_touched if shadows.sky_touched is not None else np.ones(u.size, np.float32)
        affected = []
        paths = self._static_recv_paths
        block = getattr(self, "_static_sh_block", None)
        if block is None:
            # once per shot: the static receivers' prim-local SH in one array (their rows in srecv),
            # or False where the prims differ in SH degree (then one prim at a time)
            ends = np.array([srecv.ranges[p][1] for p in paths], np.int64)
            offsets = np.concatenate([[0], ends])
            local = [self._local_sh(p, frame, sets[p]) for p in paths]
            regular = (len({s.shape[1] for s in local}) == 1
                       and all(srecv.ranges[p][0] == offsets[i] for i, p in enumerate(paths)))
            if regular and srecv.gaussians.sh.shape[1] == local[0].shape[1] and all(
                    sh is sets[p].sh for sh, p in zip(local, paths, strict=True)):
                sh_block = srecv.gaussians.sh  # every prim's SH as stored: the receivers' rows
            else:
                sh_block = np.concatenate(local).astype(np.float32, copy=False) if regular else None
            # and as the float16 the output holds, for a half-precision output of an all-float32 block
            # within the half range (else the author converts, or names the value that overflows)
            # (converted prim by prim where first authored: SegmentHalves)
            halve = (sh_block is not None and author.precision == "half" and sh_block.dtype == np.float32
                     and sh_block.size > 0)
            block = (offsets, sh_block, SegmentHalves(sh_block, offsets) if halve else None) if regular else False
            self._static_sh_block = block
        if block is not False:
            # every static receiver at once: the same values as the prim-by-prim loop below
            offsets, sh_block, halves = block
            owner = np.searchsorted(offsets[1:], u, side="right")
            touched = np.zeros(len(paths), bool)
            touched[owner] = True
            shadowed = np.zeros(len(paths), bool)
            shadowed[owner[(t_static_u < 1) | (sky_u < 1)]] = True  # the prims whose SH is attenuated
            cand = np.flatnonzero([touched[k] or not author.is_clean(p) for k, p in enumerate(paths)])
            every = len(cand) == len(paths)  # (then the rows are the block's, in order: no gathers)
            rows, sub = (None, offsets) if every else segment_rows(offsets, cand)
            counts = np.diff(sub)
            # (the touched receivers lie in the candidates' rows, which increase)
            at = u if every else np.searchsorted(rows, u)
            tp = np.ones(sub[-1], np.float32)
            tp[at] = t_static_u
            ks = np.ones(sub[-1], np.float32)
            ks[at] = sky_u
            sh_in = sh_block if every else sh_block[rows]
            sh_out = sh_in
            lit = np.repeat(shadowed[cand], counts)
            if lit.any():  # (in this thread: it runs beside the next frame's kernel-heavy shadow tasks)
                sh_out = shade_sh_rows(sh_in, lit, tp, ks, f, threads=False)
            done = author.receivers(frame, [paths[k] for k in cand], sub, tp, sh_out, sh_in,
                                    None if halves is None else halves.rows(cand, None if every else rows))
            affected += [paths[k] for k, d in zip(cand, done, strict=True) if d]
        else:
            owner = np.searchsorted(np.array([srecv.ranges[p][1] for p in paths]), u, side="right")
        for k, p in enumerate(paths if block is False else ()):
            sel = owner == k
            if not sel.any() and author.is_clean(p):
                continue
            a, b = srecv.ranges[p]
            tp = np.ones(b - a, np.float32)
            tp[u[sel] - a] = t_static_u[sel]
            kp = np.ones(b - a, np.float32)
            kp[u[sel] - a] = sky_u[sel]
            sh_in = self._local_sh(p, frame, sets[p])
            shaded = (tp < 1).any() or (kp < 1).any()
            sh_out = scale_sh(sh_in, attenuation_factor(tp, f) * kp[:, None]) if shaded else sh_in
            if author.receiver(p, frame, tp, sh_out, sh_in):
                affected.append(p)
        for p in self._dyn_recv_paths:
            a, b = drecv.ranges[p]
            tp = t_dyn[a:b]
            sh_in = self._local_sh(p, frame, sets[p])
            if p in relit:  # the factor holds gamma and the prim's shadows (its lights' visibility)
                sh_out = scale_sh(sh_in, relit[p])
            else:
                sh_out = scale_sh(sh_in, attenuation_factor(tp, f)) if (tp < 1).any() else sh_in
            if author.receiver(p, frame, tp, sh_out, sh_in) or p in relit:
                affected.append(p)
        for p, scale in relit.items():
            author.light_scale(p, frame, scale)
            if p not in drecv.ranges:
                sh_in = self._local_sh(p, frame, sets[p])
                author.receiver(p, frame, np.ones(sets[p].count, np.float32), scale_sh(sh_in, scale), sh_in)
        for p in affected:
            self.affected[p] = self.affected.get(p, 0) + 1

    def _local_sh(self, path: str, frame: float, g):
        """(N, K, 3) SH of prim ``path`` in its own frame (what its SH attribute holds) at
        ``frame``: ``g.sh`` (world space) when the prim's world transform has no rotation or its SH
        have degree 0 (no band to rotate), else
        read unrotated (once per shot for static prims and those with nothing time-sampled). A
        skinned prim's attribute holds the bind
        pose: its bind-pose SH (once per shot; the results are per-Gaussian colour factors, which
        commute with the skinning's band rotations)."""
        if path in self._local_sh_cache:  # (holds static and skinned prims only)
            return self._local_sh_cache[path]
        prim = self.prims[path]
        static = path in self.static or path in self._constant
        skinned = has_skel_binding(prim)
        tc = Usd.TimeCode.EarliestTime() if static else Usd.TimeCode(frame)
        if skinned:
            sh = read_gaussian_prim(prim, tc, world=False, skin=False, check_types=False).sh
        elif g.sh.shape[1] == 1:  # degree 0: the world transform leaves the SH as authored (GaussianSet.transformed)
            sh = g.sh
        else:
            m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc).ExtractRotationMatrix())
            plain = self.__dict__.setdefault("_no_rotation", {})  # rotation matrix bytes -> no rotation?
            key = m.tobytes()
            if key not in plain:  # (bricks share their parent's transform: decided once)
                s = abs(np.linalg.det(m)) ** (1.0 / 3.0)
                plain[key] = bool(s > 0 and np.allclose(m / s, np.eye(3), atol=1e-9))
            sh = g.sh if plain[key] else read_gaussian_prim(prim, tc, world=False, check_types=False).sh
        if static or skinned:
            self._local_sh_cache[path] = sh
        return sh

    def _merge_rows(self, counts) -> int:
        """Rows the shot buffer keeps after the prims' own for moving prims of ``counts`` Gaussians
        merged (:meth:`_merged_prim`; 0 when ``probe_merge_cell`` is 0)."""
        return sum(merge_capacity(n) for n in counts) if self.opts.probe_merge_cell > 0.0 else 0

    def _shot_buffer(self, dyn: dict):
        """Every Gaussian of the frame in one set for probe renders: the static part is copied
        once per shot, each frame only overwrites the dynamic prims' slots. After every prim's
        rows, each moving prim has ``merge_capacity`` rows for its merged Gaussians
        (:meth:`_merged_prim`), which no probe draws unless its mask selects them."""
        counts = tuple((p, g.count, g.sh_degree) for p, g in dyn.items())
        if self._buffer is None or self._buffer[0] != counts:
            order = list(self.static) + list(dyn)
            sets = {**self.static, **dyn}
            offsets = np.cumsum([0] + [sets[p].count for p in order])
            spans = {p: (int(offsets[i]), int(offsets[i + 1])) for i, p in enumerate(order)}
            slots, at = {}, int(offsets[-1])
            for p, g in dyn.items():
                room = self._merge_rows([g.count])
                if room:
                    slots[p] = (at, room)
                    at += room
            shared = self._static_shared
            if (shared is not None and shared[1].count == at and shared[0].count == offsets[len(self.static)]
                    and all(g.sh.shape[1] <= shared[1].sh.shape[1] for g in dyn.values())):
                # the static receivers' arrays, their room filled with the moving prims below: the
                # values of the plain concatenation (same SH width, no raw fields), without its copy
                self._buffer = (counts, shared[1], spans, slots)
            else:
                room = [_empty_rows(at - int(offsets[-1]))] if at > offsets[-1] else []
                buf = GaussianSet.concatenate([sets[p] for p in order] + room, label="shot")
                self._buffer = (counts, buf, spans, slots)
                return buf, spans
        _, buf, spans, _ = self._buffer
        k = buf.sh.shape[1]
        for p, g in dyn.items():
            a, b = spans[p]
            buf.positions[a:b] = g.positions
            buf.orientations[a:b] = g.orientations
            buf.scales[a:b] = g.scales
            buf.opacities[a:b] = g.opacities
            if g.sh.shape[1] < k:  # (else the copy below overwrites every coefficient)
                buf.sh[a:b] = 0.0
            buf.sh[a:b, : g.sh.shape[1]] = g.sh[:, :k]
        return buf, spans

    def _static_atlas(self, light, prim: str | None):
        """The static casters' shot-long DGSM for a point light (``usd_gs.shadows.static_scene``),
        without the light's own emitter Gaussians (:meth:`_emitter_keep`), for the lookups on
        moving receiver ``prim`` (None: for the receivers with nothing time-sampled): one per prim,
        bounded by that prim's reach (the same bits as one atlas for every prim; avatars apart pack
        only the occluders near each)."""
        key = ("atlas", tuple(np.round(light.position, 6)), prim)
        if key not in self._scene_packs:
            if "block extents" not in self._scene_packs:
                self._scene_packs["block extents"] = BlockExtents(self._scene_block, self._centre_cfg.k_sigma)
            self._scene_packs[key] = StaticSceneAtlas(self._scene_block, light.position, self._centre_cfg,
                                                      keep=self._emitter_keep(light),
                                                      extents=self._scene_packs["block extents"],
                                                      blocks=self._point_blocks(self._scene_block_ranges),
                                                      serve_radius=SERVE_RADIUS / self.mpu)
        return self._scene_packs[key]

    def _static_sun_atlas(self, light):
        """The static casters' shot-long DGSM for a directional light (``StaticSceneSunAtlas``,
        lattice pitch ``SUN_ATLAS_PITCH`` metres)."""
        key = ("sun atlas", tuple(np.round(light.direction, 9)))
        if key not in self._scene_packs:
            self._scene_packs[key] = StaticSceneSunAtlas(self._scene_block, light.direction, self._centre_cfg,
                                                         SUN_ATLAS_PITCH / self.mpu)
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
                keep = ~within_ball(self._point_blocks(self._scene_block_ranges), block.positions, light.position, r)
            self._scene_packs[key] = keep
        return self._scene_packs[key]

    def _prim_local_normals(self, path: str, g, frame: float):
        """``(local normals (N, 3), the prim at the anchor frame or None)`` of a relit prim: estimated
        once per shot, at the shot's first frame (``anchor_frame`` in a farm chunk that starts
        later, so that chunks match the whole-shot run), in each Gaussian's own frame, then carried
        by its rotation; re-estimated when the Gaussian count changes."""
        local = self._local_normals.get(path)
        first = None

        def estimate(h):
            ahead = self._normals_ahead.pop(path, None)  # (:meth:`_estimate_normals_ahead`)
            return (ahead[1] if ahead is not None and ahead[0] is h else _local_normals_of(h),)

        step = self._normals_step(path, g, frame)
        if step == "anchor":
            def at_anchor():  # a chunk: normals and clusters from the shot's first frame
                nonlocal first
                first = self._read(path, self.anchor_frame)
                return estimate(first)

            local = self._local_normals[path] = self._from_anchor(("normals", path), at_anchor)[0]
            if local.shape[0] != g.count:
                step = "estimate"
        if step in ("shot", "estimate"):
            local = (self._from_anchor(("normals", path), partial(estimate, g), g.count) if step == "shot"
                     else estimate(g))[0]
            self._local_normals[path] = local
        return local, first

    def _normals_step(self, path: str, g, frame: float) -> str:
        """How :meth:`_prim_local_normals` gets relit prim ``path``'s normals for its set ``g`` at
        ``frame``: ``'held'`` (the shot's, of ``g``'s count), ``'anchor'`` (a chunk's first sight of
        the prim: from the shot's anchor frame), ``'shot'`` (the shot's first frame: estimated from
        ``g`` as the shot's, or the shot cache's copy) or ``'estimate'`` (from ``g``: its count
        changed, or a prim first seen after the first frame)."""
        local = self._local_normals.get(path)
        if local is None and self.anchor_frame is not None and self.anchor_frame != frame:
            return "anchor"
        if local is not None and local.shape[0] == g.count:
            return "held"
        return "shot" if local is None and frame == self._first_frame() else "estimate"

    def _relight_inputs(self, path, g, everything, span, frame, lights=(), spans=None) -> dict:
        """The keyword arguments of ``relight_factors`` for prim ``path`` at ``frame`` but its
        ``visibility`` (everything that reads USD or the shot's caches happens here)."""
        jit_warmup.wait_for("relight")  # cold cache: the warm-up process compiles these kernels
        t = time.perf_counter()
        centre = alpha_weighted_centroid(g)
        mask = np.ones(everything.count, bool)
        if lights and spans is not None:
            mask &= self._emitter_mask(lights, everything, spans)  # modelled lights: not again in the probe
            lights = self._calibrated(lights, everything, spans, centre)
        mask[span[0]:span[1]] = False
        local, first = self._prim_local_normals(path, g, frame)
        blend = self._probe_blends.get(path)
        if blend is None or blend.labels.shape[0] != g.count:
            def build(h):
                b = ProbeBlend.build(h.positions, self.opts.probe_points)
                return b.labels, b.weights

            def at_anchor():
                # a chunk: the probe clusters of the whole-shot run, from the shot's first frame (the
                # normals may have been estimated there already by the shadow pass: read it again)
                h = first if first is not None else self._read(path, self.anchor_frame)
                if h.count != g.count:
                    raise _NotAtAnchor
                return build(h)

            got = None
            if blend is None and frame == self._first_frame():
                got = self._from_anchor(("blend", path), partial(build, g), g.count)
            elif blend is None and self.anchor_frame is not None:
                got = self._from_anchor(("blend", path), at_anchor, g.count)
            blend = ProbeBlend.from_arrays(*got) if got is not None else ProbeBlend.build(g.positions,
                                                                                           self.opts.probe_points)
            self._probe_blends[path] = blend
        normals = local_normals_to_world(g.orientations, local)
        job = dict(g=g, everything=everything, mask=mask, centre=centre, normals=normals, blend=blend, opts=self.opts,
                   lights=lights, appearance=self._appearance(path, frame, g.count), far=self._far_field(path, spans))
        self.clock.add("transfer", t)
        return job

    def _far_batches(self, jobs: list) -> list:
        """The far layers (``usd_gs.relight.far_field.FarLayers.batch``) that two or more of this frame's
        probe renders (``jobs``, :meth:`_relight_jobs`) would each render, as tasks of the shadow pass
        (started before the probes: a ``FarBatch``'s ``run`` each, one per static part; [] for none)."""
        stores: dict = {}
        for _, job in jobs:
            far = job.get("far")
            if far is not None:
                stores.setdefault(id(far.store), (far.store, []))[1].append(
                    (far, job["everything"], job["centre"], self.opts.probe_size, job["mask"], PROBE_DILATION,
                     self.opts.probe_supersample))
        batches = [store.batch(requests) for store, requests in stores.values() if len(requests) > 1]
        return [b.run for b in batches if b is not None]

    def _far_field(self, path: str, spans) -> FarField | None:
        """Prim ``path``'s far-layer cache for its probe renders (``usd_gs.relight.far_field``), or
        None when ``probe_far_radius`` is 0 or the shot has no static Gaussians."""
        radius = self.opts.probe_far_radius / self.mpu
        static_count = max((spans[p][1] for p in self.static if p in spans), default=0) if spans else 0
        if radius <= 0.0 or static_count == 0:
            return None
        far = self._far_fields.get(path)
        if far is None or far.static_count != static_count:
            layers = self._far_fields.get(("layers", static_count))
            if layers is None:  # one store per static part, shared by the relit prims (and a farm run's chunks)
                layers = FarLayers(KEEP * len(self._relit_paths), backing=self.shot_cache,
                                   blocks=self._point_blocks(spans))
                self._far_fields[("layers", static_count)] = layers
            far = self._far_fields[path] = FarField(radius, self.opts.probe_far_tolerance, static_count, layers)
        return far

    def _write_probe(self, path, frame, centre, probe, author, probe_dir: Path) -> None:
        """The prim's probe at ``frame``: its lat-long EXR in the probe folder and its /UsdGs/Probes sample."""
        name = probe_names(self._relit_paths)[path]
        tex = probe_dir / f"{name}.{int(round(frame)):04d}.exr"
        h, w = self.opts.probe_texture
        probe.write_latlong_exr(tex, h, w)
        self.probe_files += 1
        rel = f"./{self.final_probe_dir.name}/{tex.name}"
        author.probe(name, frame, centre, probe.to_3dgs(), rel)

    # ------------------------------------------------------------------ run
    def run(self, progress: bool = True) -> ProcessSummary:
        """Process the shot (module docstring); returns the summary."""
        t_start = time.perf_counter()
        warmup = jit_warmup.start()  # cold numba cache: compile the later kernels in a second process
        try:
            return self._run(t_start, progress)
        finally:
            jit_warmup.stop(warmup)

    def _save_shot_cache(self) -> None:
        """Write the farm run's shot cache when this frame added to it; a cache that cannot be
        written (or read: ``problem``) costs the other chunks time, not results: a warning."""
        cache = self.shot_cache
        if cache is None:
            return
        t0 = time.perf_counter()
        if cache.problem and cache.problem not in self.warnings:
            self.warnings.append(cache.problem)
        try:
            cache.save()
        except OSError as exc:
            msg = f"{cache.path}: shot cache not written ({exc}); other chunks compute its values again"
            if msg not in self.warnings:
                self.warnings.append(msg)
        self.clock.add("shot_cache", t0)

    def _deinstance(self, out_stage) -> None:
        """Instanced Gaussian prims (read through instance proxies) cannot take the output's
        opinions: their instance roots get ``instanceable = false`` in the output layer, outermost
        first, so the proxies become ordinary prims there (the input is not changed)."""
        roots = set()
        for prim in self.prims.values():
            if not prim.IsInstanceProxy():
                continue
            p = prim.GetParent()
            while p and not p.IsPseudoRoot():
                if p.IsInstance():
                    roots.add(p.GetPath())
                p = p.GetParent()
        for path in sorted(roots, key=lambda q: q.pathElementCount):
            out_stage.OverridePrim(path).SetInstanceable(False)

    def _commit_probes(self, probe_dir: Path) -> None:
        """Put this run's probe folder in place of the previous one with two renames (the old one is
        moved aside first and removed after), so no moment leaves a half-deleted folder."""
        final = self.final_probe_dir
        old = final.with_name(f".{final.name}.old.{temp_tag()}")
        if final.exists():
            os.replace(final, old)
        try:
            if self.probe_files:
                os.replace(probe_dir, final)
        finally:
            if old.exists():
                shutil.rmtree(old, ignore_errors=True)

    def check_output(self) -> None:
        """``UserError`` before any work when the output cannot be written: an existing directory
        at the output path or at its probe folder's path, or a folder that is missing or read-only."""
        out_path = Path(self.output_path)
        if out_path.is_dir():
            raise UserError(f"{out_path}: is an existing directory; -o must name the output stage file")
        probes = out_path.with_name(out_path.stem + "_probes")
        if probes.exists() and not probes.is_dir():
            raise UserError(f"{probes}: exists and is not a folder; the probe textures go there")
        check_writable_folder(out_path.parent, str(out_path))

    def memory_estimate(self) -> float:
        """Bytes of the run's largest working set, estimated before it starts: one DGSM (the
        dense per-pixel index of the atlas and its occupied depth bins, at most one pixel per
        receiver sample) plus the shot's Gaussians (every prim, about 250 bytes each with SH)."""
        cfg = self.dgsm
        w2 = float(cfg.atlas_size) ** 2
        per_receiver = {"mc": cfg.n_samples, "stencil7": 7}.get(cfg.sampling, 1)
        n = float(sum(self.counts.values()))
        bins = min(w2, n * per_receiver) * cfg.K * 12.0
        return w2 * 16.0 + bins + n * 250.0

    def _run(self, t_start: float, progress: bool) -> ProcessSummary:
        self.check_output()
        self._open()
        check_memory(self.memory_estimate(), f"{self.input_path}: this run (atlas {self.dgsm.atlas_size}, K "
                     f"{self.dgsm.K}, {sum(self.counts.values()):,} Gaussians)", "--atlas-size (or K in --config)")
        self._read_static()
        self._shot_setup()
        out_path = Path(self.output_path)
        self.final_probe_dir = out_path.with_name(out_path.stem + "_probes")
        remove_stale_temps(out_path.parent)  # what killed runs left (their pid no longer runs)
        probe_dir = out_path.with_name(f".{out_path.stem}_probes.{temp_tag()}")
        if probe_dir.exists():
            shutil.rmtree(probe_dir)
        probe_dir.mkdir(parents=True)
        try:
            with OutputLayer.create(self.input_path, self.output_path) as out:
                self._deinstance(out.stage)
                author = OutputAuthor(out.stage, self.frames, self.opts.aovs, self.opts.precision,
                                      self.opts.sh_tolerance)
                frames = self.frames
                bar = None
                if progress:
                    from tqdm import tqdm  # only for an interactive run

                    bar = tqdm(total=len(frames), unit="frame", desc="usdgs process", leave=False)
                t_frames = time.perf_counter()
                written_lights = False
                for f in frames:
                    if not self._hold_frame(f):
                        self._frame(f, author, probe_dir)
                    self._save_shot_cache()
                    if not written_lights and self.lights_used and self.lights_used[0].source == "estimated":
                        # (after the frame's pending probes and SH: /UsdGs/Probes before /UsdGs/Lights)
                        self._pending_writes.append(partial(
                            self._write_lights, out.stage,
                            [lt for lt in self.lights_used if lt.source == "estimated"], probe_dir))
                        written_lights = True
                    if bar:
                        bar.update(1)
                self.flush_writes()  # the last frame's
                if bar:
                    bar.close()
                self.clock.add("frames", t_frames)
                if self.opts.bake_skinning:
                    self._bake_skinning(out.stage)
                t0 = time.perf_counter()
            self.clock.add("save", t0)
            self._commit_probes(probe_dir)
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
