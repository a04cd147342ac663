"""Parallel JIT warm-up: compile the main job's later numba kernels in a second process.

numba compiles a kernel on its first call, in one thread, and ``usdgs process`` needs about
fifty of them (~30 s of compilation on a cold cache, against ~0.85 s per warm frame on the
2-core development machine). The kernels are cached on disk (``cache=True``), so a second
process that calls them first fills the cache, and the main process then loads them instead
of compiling. :func:`start` launches ``python -m usd_gs.jit_warmup`` when the cache is cold;
it calls the main job's steps on a few generated Gaussians in *reverse* pipeline order
(relighting first, then the shadow maps' refined sampling and accumulation, then the rest),
while the main process compiles from the front (light estimation, then the shadow maps): the
two meet in the middle and the compilation is spread over both cores. The warm-up calls the
same wrapper functions as the main job, so the kernels see the same argument types and the
cache entries match (``tests/test_jit_warmup.py`` checks it).

Nothing here changes a result: the warm-up writes only numba cache files, which numba
replaces atomically. ``USDGS_JIT_WARMUP=0`` disables it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace

import numpy as np

#: a kernel the warm-up compiles first; its cache entry tells whether the cache is cold
SENTINEL = ("numba_kernels.rasterize", "_blend")


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


def start() -> subprocess.Popen | None:
    """Launch the warm-up process if the cache is cold and ``USDGS_JIT_WARMUP`` is not ``0``;
    returns the process (pass it to :func:`stop`) or None."""
    if os.environ.get("USDGS_JIT_WARMUP", "1") == "0" or not cache_is_cold():
        return None
    env = dict(os.environ, NUMBA_NUM_THREADS="1", USDGS_JIT_WARMUP="0")
    return subprocess.Popen([sys.executable, "-m", "usd_gs.jit_warmup"], env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def stop(proc: subprocess.Popen | None) -> None:
    """End the warm-up process (it has nothing left to give once the main job is done)."""
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _tiny_scene():
    from .synthetic import random_gaussians

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
    from numba_kernels import dgsm_build

    w, k = dgsm_build.TILE, 4
    values = np.tile(np.array([1.0, 0.0, 1.0, 0.0], np.float32), (w * w, 1))
    tiles = (np.array([0, occ_count], np.int64), np.arange(occ_count, dtype=np.int64), np.zeros(0, np.int64),
             np.tile(np.array([0.0, 0.0, 1.0, -2.0]), (occ_count, 1)))
    return dgsm_build.Atlas(w, k, 4.0, 0, k - 1, np.arange(w * w, dtype=np.int32), values,
                            np.arange(w * w, dtype=np.int64), 0, 0, tiles)


def warm_up() -> None:
    """Call the main job's kernels on tiny inputs, in the reverse of the order the main job
    first needs them (module doc): relighting (normals, probe render, fit, SH transfer), then
    the shadow maps' refined sampling and accumulation, then the rest of the shadow path.
    Measured on the 2-core machine, default 48-frame demo: this order balances the two
    processes best (relighting first 64 s, shadow maps first 64-66 s, no warm-up 86 s)."""
    from numba_kernels import dgsm_build, dgsm_sample
    from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local

    from .avatar_relight import relight_factors
    from .gaussians import GaussianSet
    from .light_prims import ShotLight
    from .lights import alpha_weighted_centroid
    from .pipeline import ProcessOptions
    from .probe_parallax import ProbeBlend
    from .shading import attenuation_factor, combine_lights, light_shares, scale_sh
    from .shadows import prepare_occluders
    from .shot_shadows import Receivers, receiver_points, shared_transmittance
    from .static_shadows import StaticSceneAtlas

    opts = ProcessOptions().check()
    avatar, scene = _tiny_scene()
    light = ShotLight("Light_0", "point", np.array([0.3, 2.5, 0.1]))
    # relighting: normals, the probe render (the longest compile), probe fit and SH transfer
    centre = alpha_weighted_centroid(avatar)
    everything = GaussianSet.concatenate([scene, avatar], label="shot")
    mask = np.ones(everything.count, bool)
    mask[scene.count:] = False
    n = gaussian_normals(avatar.positions, avatar.orientations, avatar.scales, avatar.opacities)
    normals = local_normals_to_world(avatar.orientations, normals_to_local(avatar.orientations, n))
    scale, probe = relight_factors(avatar, everything, mask, centre, normals,
                                   ProbeBlend.build(avatar.positions, opts.probe_points), opts)
    scale_sh(avatar.sh, opts.relight_gamma * scale)
    probe.to_latlong(*opts.probe_texture)
    # shadow-map sampling with exact refinement, and accumulation, on a hand-made atlas
    occ, dir_dep = np.zeros((4, 16)), 0
    atlas = _fake_atlas(len(occ))
    pts = np.ascontiguousarray(light.position + np.array([[0.01, 0.02, 1.0]]) * np.linspace(0.5, 3.5, 16)[:, None])
    dgsm_sample.lookup_point_refined(atlas, light.position, pts, occ, dir_dep, opts.dgsm.refine_contrast)
    out = np.ones((4, atlas.K), np.float32)
    dgsm_build.accumulate_pixels(light.position, occ, dir_dep, atlas.pixels[:4], atlas.width, atlas.K, atlas.t_max,
                                 0, atlas.K - 1, atlas.tiles, True, opts.dgsm.bin_skip, out,
                                 np.zeros(4, np.int64), np.zeros(4, np.int64))
    # the rest of the shadow path: the static scene's atlas, a caster's shared atlas, light combination
    centre_cfg = replace(opts.dgsm, sampling="center")
    recv = Receivers.build([("/scene", scene)])
    drecv = Receivers.build([("/avatar", avatar)])
    part = receiver_points(scene, drecv, light, centre_cfg, roi="all", bias=opts.contact_bias)
    StaticSceneAtlas(scene, light.position, centre_cfg).transmittance(part[1])
    parts = [receiver_points(avatar, recv, light, opts.dgsm, roi=opts.roi),
             receiver_points(avatar, drecv, light, opts.dgsm, exclude="/avatar", roi=opts.roi)]
    (idx, val), _ = shared_transmittance(avatar, parts, light, opts.dgsm, prepare_occluders(avatar, opts.dgsm))
    t = np.ones(scene.count)
    t[idx] *= val
    tp = combine_lights([t, t], light_shares([light, light], scene.positions))
    scale_sh(scene.sh, attenuation_factor(tp.astype(np.float32), opts.direct_fraction))


if __name__ == "__main__":
    warm_up()
