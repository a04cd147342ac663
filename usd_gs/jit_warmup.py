"""Parallel JIT warm-up: compile the main job's later numba kernels in a second process.

numba compiles a kernel on its first call, in one thread, and ``usdgs process`` needs about
fifty of them (~50 s of compilation on a cold cache, against ~0.85 s per warm frame on the
2-core development machine). The kernels are cached on disk (``cache=True``), so a second
process that calls them first fills the cache, and the main process then loads them instead of
compiling. :func:`start` launches ``python -m usd_gs.jit_warmup`` when the cache is cold; it
calls the main job's steps on a few generated Gaussians in *reverse* pipeline order (probe
render, normals and SH transfer first, shadows next), while the main process compiles from the
front (light estimation, then shadows): the two meet in the middle and the compilation is
spread over both cores. The warm-up uses the same wrapper functions as the main job, so the
kernels see the same argument types and the cache entries match.

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


def warm_up() -> None:
    """Call the main job's steps on a tiny scene, last steps first (see the module doc)."""
    from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local

    from .gaussians import GaussianSet
    from .light_prims import ShotLight
    from .lights import alpha_weighted_centroid
    from .pipeline import ProcessOptions
    from .probe import render_probe
    from .relight import relight_sh
    from .shading import attenuation_factor, combine_lights, light_shares, scale_sh
    from .shadows import prepare_occluders
    from .shot_shadows import Receivers, receiver_points, shared_transmittance
    from .static_shadows import StaticSceneAtlas

    opts = ProcessOptions().check()
    avatar, scene = _tiny_scene()
    # relighting: probe render and fit, normals, SH transfer
    everything = GaussianSet.concatenate([scene, avatar], label="shot")
    mask = np.ones(everything.count, bool)
    mask[scene.count:] = False
    centre = alpha_weighted_centroid(avatar)
    probe = render_probe(everything, centre, opts.probe_size, opts.probe_degree, mask)
    n = gaussian_normals(avatar.positions, avatar.orientations, avatar.scales, avatar.opacities)
    normals = local_normals_to_world(avatar.orientations, normals_to_local(avatar.orientations, n))
    relight_sh(avatar.sh, normals, probe, q=opts.relight_q, gamma=opts.relight_gamma, t_max=opts.relight_t_max)
    # shadows: the static scene's atlas, a caster's shared atlas, the light combination
    light = ShotLight("Light_0", "point", np.array([0.3, 2.5, 0.1]))
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
