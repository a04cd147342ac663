"""Tiny generated shots for the hardening, fuzz and kill tests (no shared data needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def tiny_shot(path: Path, n_scene: int = 300, n_avatar: int = 60, frames: int = 2, seed: int = 0) -> Path:
    """A stage at ``path``: a static scene ``/World/Room`` (random Gaussians in a flat slab) and a
    moving ``/World/Avatar`` (translated along x at frames 1..``frames``), a SphereLight, Y up."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    stage = new_stage(None)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    stage.SetTimeCodesPerSecond(24)
    room = random_gaussians(n_scene, degree=1, seed=seed)
    room.positions[:, 1] *= 0.05  # a floor slab
    write_gaussian_prim(stage, "/World/Room", room)
    av = random_gaussians(n_avatar, degree=1, seed=seed + 1)
    av.positions *= 0.1
    av.positions[:, 1] += 1.0
    write_gaussian_prim(stage, "/World/Avatar", av)
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Avatar")).AddTranslateOp()
    for f in range(1, frames + 1):
        op.Set(Gf.Vec3d(0.1 * f, 0, 0), Usd.TimeCode(f))
    light = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    light.CreateIntensityAttr(50.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    save_stage_atomic(stage, path)
    return Path(path)


def leftovers(folder: Path) -> list[str]:
    """Temp files and folders (leading dot, ``.tmp`` in the name) anywhere under ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob(".*") if ".tmp" in p.name)


def digest(folder: Path) -> dict:
    import hashlib

    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(folder).rglob("*")) if p.is_file()}


__all__ = ["tiny_shot", "leftovers", "digest", "np"]
