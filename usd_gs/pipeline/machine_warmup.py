"""``usdgs warmup``: compile every kernel the commands use, once per machine (numba's disk cache).

The main job's own background warm-up (``usd_gs.pipeline.jit_warmup``) compiles the relighting
while a cold run starts. This module covers the rest, group by group, each group in its own
process (``python -P -m usd_gs.pipeline.machine_warmup GROUP``, launched by ``usd_gs.cli.warmup``):
:data:`GROUPS` are ``jit_warmup.GROUPS`` plus :data:`EXTRA_GROUPS`, whole runs on :func:`tiny_shot`
stages (``estimate`` the light estimation of closed and open captures, ``skin`` UsdSkel skinning
of Gaussians and a prim's rotating transform, ``directional`` whole runs lit by a DistantLight and
by a SphereLight, ``render`` the preview renders, ``process`` a whole run with estimated lights,
the catch-all run last).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux, UsdSkel

from numba_kernels.grid_neighbours import nearest
from usd_gs.gaussians import GaussianSet, matrix_to_quaternion
from usd_gs.io.atomic import atomic_output
from usd_gs.pipeline import jit_warmup
from usd_gs.pipeline.jit_warmup import _mark
from usd_gs.pipeline.options import ProcessOptions
from usd_gs.pipeline.shot import ShotProcessor
from usd_gs.render.preview import render_stage_frame
from usd_gs.synthetic import random_gaussians
from usd_gs.usd import skel as uskel
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic, write_gaussian_prim
from usd_gs.usd.schema import apply_role
from usd_gs.usd.stage import open_stage

#: the groups only ``usdgs warmup`` runs; ``process`` is a whole run on a tiny shot, the catch-all run last
EXTRA_GROUPS = ("estimate", "skin", "directional", "render", "process")
#: every group this module runs
GROUPS = jit_warmup.GROUPS + EXTRA_GROUPS


def _flat_patch(nx: int, nz: int, spacing: float, origin, colour, seed: int) -> GaussianSet:
    """``nx * nz`` flat Gaussians (normal +Y) on a grid in the plane y = origin[1], SH degree 1."""
    rng = np.random.default_rng(seed)
    gx, gz = np.meshgrid(np.arange(nx), np.arange(nz), indexing="ij")
    n = nx * nz
    g = random_gaussians(n, 1, seed=seed)
    g.positions[:] = (np.stack([gx.ravel(), np.zeros(n), gz.ravel()], axis=1) * spacing
                      + np.asarray(origin, np.float64)).astype(np.float32)
    g.orientations[:] = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0], np.float32)  # local z -> +Y
    g.scales[:] = np.array([0.6 * spacing, 0.6 * spacing, 0.05 * spacing], np.float32)
    g.opacities[:] = 0.9
    g.sh[:] = 0.0
    g.sh[:, 0] = ((np.asarray(colour, np.float32) * (0.9 + 0.2 * rng.random((n, 1)))) - 0.5) / 0.28209479177387814
    return g


def tiny_shot(folder, light: str = "none") -> Path:
    """Write a tiny shot to ``folder``/shot_<light>.usda and return its path: frames 1..2, Y-up,
    metres; ``/World/Floor`` (a 4 m floor, role scene, no ceiling: an open capture) with a small
    bright cluster ``/World/Lamp`` (scene, an emitter the light estimation can find), a skinned
    avatar ``/World/Rig/Avatar`` (UsdSkel, classic linear blend) and a dual-quaternion skinned one
    ``/World/Rig/AvatarDQ`` (role object), and the lights ``light`` names: ``none`` (estimated),
    ``sphere`` (a UsdLux SphereLight) or ``distant`` (a UsdLux DistantLight)."""

    stage = new_stage()
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    UsdGeom.Xform.Define(stage, "/World")
    floor = _flat_patch(20, 20, 0.2, (-2.0, 0.0, -2.0), (0.6, 0.55, 0.5), seed=3)
    apply_role(write_gaussian_prim(stage, "/World/Floor", floor, keep_raw=False), "scene")
    lamp = random_gaussians(24, 1, seed=4)
    lamp.positions[:] = lamp.positions * 0.01 + np.array([0.5, 2.2, 0.3], np.float32)
    lamp.scales[:] = 0.01
    lamp.opacities[:] = 0.95
    lamp.sh[:] = 0.0
    lamp.sh[:, 0] = (4.0 - 0.5) / 0.28209479177387814
    apply_role(write_gaussian_prim(stage, "/World/Lamp", lamp, keep_raw=False), "scene")
    UsdSkel.Root.Define(stage, "/World/Rig")
    bind = np.stack([np.eye(4), np.eye(4)])
    bind[1, :3, 3] = [0, 0.15, 0]
    sk = uskel.author_skeleton(stage, "/World/Rig/Skel", ["a", "a/b"], bind, bind.copy())
    rot = np.array(Gf.Matrix3d(Gf.Rotation(Gf.Vec3d(0, 0, 1), 30))).T
    q = matrix_to_quaternion(np.stack([np.eye(3), np.eye(3), np.eye(3), rot])).reshape(2, 2, 4)
    tr = np.array([[[0, 0, 0], [0, 0.15, 0]], [[0.3, 0, 0], [0, 0.15, 0]]], np.float64)
    uskel.author_animation(stage, "/World/Rig/Skel/Anim", sk, ["a", "a/b"], [1.0, 2.0], tr, q)
    for k, (name, role) in enumerate((("Avatar", "avatar"), ("AvatarDQ", "object"))):
        g = random_gaussians(96, 3 if k == 0 else 0, seed=5 + k)
        g.positions[:] = g.positions * 0.02 + np.array([0.4 * k, 0.15, 0.0], np.float32)  # feet on the floor
        prim = write_gaussian_prim(stage, f"/World/Rig/{name}", g, keep_raw=False)
        apply_role(prim, role, relight=True)
        w = np.clip((g.positions[:, 1] - 0.13) / 0.04, 0, 1)
        binding = uskel.bind_prim(prim, sk, np.tile([0, 1], (g.count, 1)), np.stack([1 - w, w], axis=1))
        if k == 1:
            binding.CreateSkinningMethodAttr(UsdSkel.Tokens.dualQuaternion)
    if light == "sphere":
        lt = UsdLux.SphereLight.Define(stage, "/World/Bulb")
        lt.CreateIntensityAttr(20.0)
        lt.CreateRadiusAttr(0.05)
        UsdGeom.Xformable(lt).AddTranslateOp().Set(Gf.Vec3d(0.5, 2.2, 0.3))
    elif light == "distant":
        lt = UsdLux.DistantLight.Define(stage, "/World/Sun")
        lt.CreateIntensityAttr(3.0)
        lt.CreateAngleAttr(0.53)
        UsdGeom.Xformable(lt).AddRotateXYZOp().Set(Gf.Vec3f(-60.0, 30.0, 0.0))
    elif light != "none":
        raise ValueError(f"tiny_shot: light must be none, sphere or distant, got {light!r}")
    return save_stage_atomic(stage, Path(folder) / f"shot_{light}.usda")


def _warm_up_extra(groups, folder: Path) -> None:
    """The :data:`EXTRA_GROUPS` (see :func:`warm_up`), on :func:`tiny_shot` stages in ``folder``."""

    if "estimate" in groups:  # closed (a number of point lights) and open (auto: classified, sun and sky)
        for mode in ("2", "auto"):
            ShotProcessor(str(tiny_shot(folder)), str(folder / "est.lit.usdc"),
                          ProcessOptions(lights=mode, frames="1-2")).shot_lights()
        # the nearest-point maps (a sun estimate's values spread to every receiver, a large prim's
        # self-shadow samples), which the tiny shot's sun does not reach
        pts = random_gaussians(64, 0, seed=3).positions
        nearest(pts[::4], pts)
        _mark("estimate")
    if "skin" in groups:  # usd_gs.usd.skel: linear blend and dual quaternions, world and prim-local
        stage = open_stage(str(tiny_shot(folder)))
        for name in ("Avatar", "AvatarDQ"):
            for world in (True, False):
                read_gaussian_prim(stage.GetPrimAtPath(f"/World/Rig/{name}"), Usd.TimeCode(2), world=world)
        # and a prim read under a rotating transform (numba_kernels.similarity)
        turn = np.eye(4)
        turn[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
        random_gaussians(8, 1).transformed(turn)
        _mark("skin")
    if "directional" in groups:  # a DistantLight's shadow maps (and a SphereLight's): whole runs
        for light in ("distant", "sphere"):
            src = tiny_shot(folder, light)
            ShotProcessor(str(src), str(folder / f"{src.stem}.lit.usdc"), ProcessOptions(lights="stage")).run(False)
        _mark("directional")
    if "render" in groups:  # usdgs render: the preview rasteriser, on an input and a processed stage

        src = tiny_shot(folder)
        out = folder / "render.lit.usdc"
        ShotProcessor(str(src), str(out), ProcessOptions(lights="2", frames="1")).run(False)
        for path in (src, out):
            render_stage_frame(open_stage(str(path)), 1.0, width=32)
        _mark("render")
    if "process" in groups:  # the catch-all: usdgs process on the tiny shot, estimated lights
        ShotProcessor(str(tiny_shot(folder)), str(folder / "shot.lit.usdc"), ProcessOptions(frames="1-2")).run(False)
        # the static part copied into the shot buffer with its values checked (the tiny shot's avatar
        # has a higher SH degree than its scene, so its buffer is made otherwise): degree 0 rows padded
        GaussianSet.concatenate([random_gaussians(8, 0, seed=1), random_gaussians(8, 1, seed=2)], finite=[])
        _mark("process")


def warm_up_groups(groups) -> None:
    """The main job's warm-up groups (``jit_warmup.warm_up``) and the :data:`EXTRA_GROUPS` among ``groups``."""
    extra = [g for g in groups if g in EXTRA_GROUPS]
    if extra:
        folder = Path(tempfile.mkdtemp(prefix="usdgs_warmup_shot_"))
        try:
            _warm_up_extra(extra, folder)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    base = tuple(g for g in groups if g in jit_warmup.GROUPS)
    if base:
        jit_warmup.warm_up(base)


def _record_compilations(report: str, groups) -> None:
    """Run :func:`warm_up_groups` for ``groups`` and write to ``report`` a JSON object: ``compiled``, the
    top-level numba compilations (``module.function``, one per new signature: a cache miss),
    ``compile_s`` their summed seconds and ``wall_s`` the group's wall time."""
    import json

    from numba.core import event

    compiled, stack = [], []

    class _Listener(event.Listener):
        def on_start(self, ev):
            stack.append(time.perf_counter())

        def on_end(self, ev):
            t = time.perf_counter() - stack.pop()
            if not stack:
                fn = getattr(ev.data.get("dispatcher"), "py_func", None)
                compiled.append((f"{fn.__module__}.{fn.__qualname__}" if fn is not None else "?", t))

    event.register("numba:compile", _Listener())
    t0 = time.perf_counter()
    warm_up_groups(groups)
    out = {"groups": list(groups), "compiled": [k for k, _ in compiled], "compile_s": sum(t for _, t in compiled),
           "wall_s": time.perf_counter() - t0}

    with atomic_output(report) as tmp:
        Path(tmp).write_text(json.dumps(out))


if __name__ == "__main__":
    wanted_groups = jit_warmup.groups_from_argv("usd_gs.pipeline.machine_warmup", GROUPS)
    report = os.environ.get("USDGS_JIT_WARMUP_REPORT")
    if report:  # which kernels this process compiled (not loaded from the cache), and how long
        _record_compilations(report, wanted_groups)
    else:
        warm_up_groups(wanted_groups)
