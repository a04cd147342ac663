"""Parallel JIT warm-up: compile the main job's relighting kernels in a second process.

numba compiles a kernel on its first call, in one thread, and ``usdgs process`` calls about
forty of them. The kernels are cached on disk (``cache=True``), so a second process that calls
them first fills the cache, and the main process then loads them instead of compiling.
:func:`start` launches ``python -m usd_gs.pipeline.jit_warmup GROUP ...`` when the cache is
cold. The main job compiles, in this order, light estimation, the shadow maps' preparation,
accumulation and refined sampling, then the relighting (normals, probe render, fit and
transfer), and authors the first frame's results while the second frame's shadows run. The
warm-up takes the :data:`BACKGROUND` groups, the relighting and then the authoring, touches a
marker file as each is done and exits; the main process compiles the rest itself and, before it
first relights (first authors), waits for that group's marker (:func:`wait_for`) instead of
compiling the same kernels a second time. The warm-up calls the same wrapper functions as the
main job, so the kernels see the same argument types and the cache entries match
(``tests/test_jit_warmup.py`` checks it). Compile times and the cold-start timeline:
docs/benchmarks.md (``benchmarks/bench_cold_start.py``).

Nothing here changes a result: the warm-up writes only numba cache files, which numba
replaces atomically, and a wait ends when the marker appears, the warm-up process ends, or
after :data:`WAIT_LIMIT` seconds. ``USDGS_JIT_WARMUP=0`` disables it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from numba_kernels import dgsm_build, dgsm_sample
from numba_kernels.capsule import within_capsule, within_capsule_scaled
from numba_kernels.cube_warp import warp_layer
from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local
from numba_kernels.sh_output import half_bits_where
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
from usd_gs.pipeline.options import ProcessOptions
from usd_gs.point_blocks import PointBlocks, block_starts
from usd_gs.relight.avatar import relight_factors
from usd_gs.relight.direct import direct_irradiance
from usd_gs.relight.far_field import FarLayers
from usd_gs.relight.parallax import ProbeBlend
from usd_gs.relight.probe import render_probe_faces
from usd_gs.relight.probe_merge import MergedPrim
from usd_gs.shadows.dgsm import prepare_occluders
from usd_gs.shadows.shading import attenuation_factor, combine_lights, light_shares, scale_sh, shade_sh_rows
from usd_gs.shadows.shot import Receivers, prim_spheres, prims_in_shadow, receiver_points, shared_transmittance
from usd_gs.shadows.static_scene import StaticSceneAtlas
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.lux import ShotLight
from usd_gs.usd.output_author import half_of, segments_equal, sh_display_changes

#: a kernel the warm-up compiles; its cache entry tells whether the cache is cold
SENTINEL = ("numba_kernels.rasterize", "_blend")
#: the groups of the main job's background warm-up, in the order :func:`warm_up` compiles them
GROUPS = ("refine", "relight", "author", "shadows")
#: the groups the background process compiles (the main job compiles the others itself)
BACKGROUND = ("relight", "author")
#: seconds the main process waits at most for one group
WAIT_LIMIT = 120.0


@dataclass
class WarmUp:
    """A running warm-up process and the folder where it marks each finished group."""

    proc: subprocess.Popen
    markers: Path
    done: set = field(default_factory=set)  # groups seen finished

    def wait(self, group: str) -> None:
        """Block until ``group`` is compiled (its marker exists), the process has ended, or
        :data:`WAIT_LIMIT` seconds have passed; returns at once for a group it does not compile
        or has been seen finished."""
        if group not in BACKGROUND or group in self.done:
            return
        t0 = time.perf_counter()
        while not (self.markers / group).exists() and self.proc.poll() is None:
            if time.perf_counter() - t0 > WAIT_LIMIT:
                break
            time.sleep(0.02)
        self.done.add(group)


_ACTIVE: list = [None]  # the warm-up of the run in progress in this process (start/stop)


def cache_is_cold() -> bool:
    """True if the numba cache holds no valid entry of the sentinel kernel (empty cache,
    another ``NUMBA_CACHE_DIR``, or sources changed since it was written)."""
    import importlib

    mod = importlib.import_module(SENTINEL[0])
    cache = getattr(getattr(mod, SENTINEL[1]), "_cache", None)
    try:
        return not cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - numba internals: when unsure, do not start a process
        return False


def start() -> WarmUp | None:
    """Launch the warm-up process for the :data:`BACKGROUND` groups if the cache is cold and
    ``USDGS_JIT_WARMUP`` is not ``0``; returns it (pass it to :func:`stop`) or None."""
    if os.environ.get("USDGS_JIT_WARMUP", "1") == "0" or not cache_is_cold():
        return None
    markers = Path(tempfile.mkdtemp(prefix="usdgs_warmup_"))
    env = dict(os.environ, NUMBA_NUM_THREADS="1", USDGS_JIT_WARMUP="0", USDGS_JIT_WARMUP_MARKERS=str(markers),
               USDGS_JIT_WARMUP_PACKAGE=_package_dir())
    # -P: no current directory on sys.path, so that a checkout's source tree does not shadow the
    # installed package the main process runs (numba cache entries belong to one source file)
    proc = subprocess.Popen([sys.executable, "-P", "-m", "usd_gs.pipeline.jit_warmup", *BACKGROUND], env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _ACTIVE[0] = WarmUp(proc, markers)
    return _ACTIVE[0]


def wait_for(group: str) -> None:
    """Called by the main job before it first needs ``group``'s kernels: :meth:`WarmUp.wait` on
    this process's running warm-up, nothing when there is none (warm cache)."""
    if _ACTIVE[0] is not None:
        _ACTIVE[0].wait(group)


def stop(warm) -> None:
    """End the warm-up process (it has nothing left to give once the main job is done) and
    remove its markers; ``warm`` is a :class:`WarmUp`, a bare ``Popen`` or None."""
    if warm is None:
        return
    proc = warm.proc if isinstance(warm, WarmUp) else warm
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if isinstance(warm, WarmUp):
        shutil.rmtree(warm.markers, ignore_errors=True)
        if _ACTIVE[0] is warm:
            _ACTIVE[0] = None


def _package_dir() -> str:
    """Folder of the ``usd_gs`` package this process imported."""
    return str(Path(__file__).resolve().parents[1])


def _mark(group: str) -> None:
    folder = os.environ.get("USDGS_JIT_WARMUP_MARKERS")
    if folder:
        Path(folder, group).touch()


def _tiny_scene():
    avatar = random_gaussians(64, 3, seed=1)
    avatar.positions[:] = avatar.positions * 0.05 + np.array([0.0, 1.0, 0.0], np.float32)
    scene = random_gaussians(256, 3, seed=2)
    scene.positions[:, 1] = 0.0
    for g in (avatar, scene):  # SH read from USD arrive as read-only views (a numba type of their own)
        g.sh.flags.writeable = False
    return avatar, scene


def _fake_atlas(occ_count: int):
    """A tiny point-light atlas with contrasting voxels and one culling tile listing every
    occluder: enough to reach the refinement and accumulation kernels without building one."""
    w, k = dgsm_build.TILE, 4
    values = np.tile(np.array([1.0, 0.0, 1.0, 0.0], np.float32), (w * w, 1))
    tiles = (np.array([0, occ_count], np.int64), np.arange(occ_count, dtype=np.int64), np.zeros(0, np.int64),
             np.tile(np.array([0.0, 0.0, 1.0, -2.0]), (occ_count, 1)))
    return dgsm_build.Atlas(w, k, 4.0, 0, k - 1, np.arange(w * w, dtype=np.int32), values,
                            np.arange(w * w, dtype=np.int64), 0, 0, tiles)


def warm_up(groups=GROUPS) -> None:
    """Call the main job's kernels on tiny inputs, group by group (module doc): ``refine`` the
    shadow maps' refined sampling, ``relight`` normals, probe render, fit and SH transfer (and the
    merge of other moving prims for the probes), ``author``
    the output's SH passes (shadowed rows, float16, display-change bound, held-value comparison),
    ``shadows`` the rest of the shadow path (accumulation, the static scene's atlas, a caster's
    shared atlas, light combination). Marks each group when done (see :func:`start`). The rest of
    what the commands compile is warmed by ``usd_gs.pipeline.machine_warmup`` (``usdgs warmup``)."""
    opts = ProcessOptions().check()
    avatar, scene = _tiny_scene()
    light = ShotLight("Light_0", "point", np.array([0.3, 2.5, 0.1]))
    occ, dir_dep = np.zeros((4, 16)), 0
    atlas = _fake_atlas(len(occ))
    if "refine" in groups:  # shadow-map sampling with exact refinement, on a hand-made atlas
        pts = np.ascontiguousarray(light.position + np.array([[0.01, 0.02, 1.0]]) * np.linspace(0.5, 3.5, 16)[:, None])
        dgsm_sample.lookup_point_refined(atlas, light.position, pts, occ, dir_dep, opts.dgsm.refine_contrast)
        _mark("refine")
    if "relight" in groups:  # normals, the probe render (the longest compile), probe fit and SH transfer
        centre = alpha_weighted_centroid(avatar)
        everything = GaussianSet.concatenate([scene, avatar], label="shot")
        mask = np.ones(everything.count, bool)
        mask[scene.count:] = False
        n = gaussian_normals(avatar.positions, avatar.orientations, avatar.scales, avatar.opacities)
        normals = local_normals_to_world(avatar.orientations, normals_to_local(avatar.orientations, n))
        scale, probe = relight_factors(avatar, everything, mask, centre, normals,
                                       ProbeBlend.build(avatar.positions, opts.probe_points), opts)
        scale_sh(avatar.sh, opts.relight_gamma * scale)
        direct_irradiance(light, avatar.positions, normals)  # each light's direct term (a point light)
        probe.to_latlong(*opts.probe_texture)
        # the far field's ball tests over the static part (FarLayers.clear, block by block)
        layers = FarLayers(blocks=PointBlocks(block_starts([(0, scene.count)])))
        layers.clear(everything.positions[:scene.count], centre, 0.5, 1.0)
        # a render by indices, its cull skipping cameras block by block (as FarField.render draws)
        render_probe_faces(everything, centre, 2, None, order=np.flatnonzero(mask),
                           blocks=layers.cull_bounds(everything))
        MergedPrim.of(avatar, opts.probe_merge_cell)  # a moving prim merged for the other prims' probes
        flat = np.zeros((6, 2, 2), np.float32)  # and its layer moved to the probe's centre
        warp_layer(np.zeros((6, 2, 2, 3), np.float32), flat, flat, np.zeros(3), centre, 1.0)
        _mark("relight")
    if "author" in groups:  # the authoring of the static receivers' SH (after the first frame's relighting)
        sh = np.ascontiguousarray(scene.sh, np.float32)
        lit = np.ones(scene.count, bool)
        t = np.full(scene.count, 0.5, np.float32)
        sh_out = shade_sh_rows(sh, lit, t, t, 1.0, threads=False)
        offsets = np.array([0, scene.count], np.int64)
        sh_display_changes(sh_out, sh, offsets, rows=lit)
        halves = half_of(sh)
        half_bits_where(lit, sh_out, halves, threads=False)
        segments_equal(halves, halves, np.zeros(1, np.int64), np.array([halves.size], np.int64))
        _mark("author")
    if "shadows" in groups:
        out = np.ones((4, atlas.K), np.float32)
        dgsm_build.accumulate_pixels(light.position, occ, dir_dep, atlas.pixels[:4], atlas.width, atlas.K,
                                     atlas.t_max, 0, atlas.K - 1, atlas.tiles, True, opts.dgsm.bin_skip, out,
                                     np.zeros(4, np.int64), np.zeros(4, np.int64))
        centre_cfg = replace(opts.dgsm, sampling="center")
        recv = Receivers.build([("/scene", scene)])
        spheres = prim_spheres(recv, opts.dgsm.k_sigma)  # the static receivers' bounding spheres, once per shot
        prims_in_shadow(spheres, avatar, light, opts.dgsm.k_sigma)  # (float64 centres: the beam kernel's own types)
        drecv = Receivers.build([("/avatar", avatar)])
        part = receiver_points(scene, drecv, light, centre_cfg, roi="all", bias=opts.contact_bias)
        keep = ~within_capsule(scene.positions, light.position, light.position, opts.emitter_radius)  # _emitter_keep
        atlas = StaticSceneAtlas(scene, light.position, centre_cfg, keep=keep,
                                 blocks=PointBlocks(block_starts([(0, scene.count)])))
        # (the per-point capsule test of the sun estimation's off-ray Gaussians; the atlas's goes by bricks)
        within_capsule_scaled(scene.positions, light.position, np.zeros(3), 1.0, scene.scales, 3.0)
        for _ in range(2):  # (the second lookup is a later frame's: its reach test)
            atlas.transmittance(part[1])
        parts = [receiver_points(avatar, recv, light, opts.dgsm, roi=opts.roi),
                 receiver_points(avatar, drecv, light, opts.dgsm, exclude="/avatar", roi=opts.roi)]
        (idx, val), _ = shared_transmittance(avatar, parts, light, opts.dgsm, prepare_occluders(avatar, opts.dgsm))
        t = np.ones(scene.count)
        t[idx] *= val
        tp = combine_lights([t, t], light_shares([light, light], scene.positions))
        scale_sh(scene.sh, attenuation_factor(tp.astype(np.float32), 0.5))  # the main job: a measured float
        _mark("shadows")


def groups_from_argv(module: str, known: tuple) -> tuple:
    """The warm-up groups a ``python -m module GROUP ...`` process was asked for (all of ``known``
    when none); ``SystemExit`` for an unknown group, or when this is another copy of the package
    than the launching process's (``USDGS_JIT_WARMUP_PACKAGE``: its cache entries would not be used)."""
    unknown = set(sys.argv[1:]) - set(known)
    if unknown:
        raise SystemExit(f"{module}: unknown group(s) {sorted(unknown)}; groups are {known}")
    wanted = os.environ.get("USDGS_JIT_WARMUP_PACKAGE")
    if wanted and wanted != _package_dir():
        raise SystemExit(f"{module}: this is {_package_dir()}, the main process runs {wanted}")
    return tuple(sys.argv[1:]) or known


if __name__ == "__main__":
    warm_up(groups_from_argv("usd_gs.pipeline.jit_warmup", GROUPS))
