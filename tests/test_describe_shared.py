"""describe_gaussian_prim with a ``shared`` dict (the main job's _open) gives every prim the same
description as alone: time samples and animation of the ancestors, world bounds to the bit."""

from __future__ import annotations

import numpy as np
from pxr import Gf, Usd, UsdGeom

from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import describe_gaussian_prim, find_gaussian_prims, write_gaussian_prim


def _stage():
    stage = Usd.Stage.CreateInMemory()
    world = UsdGeom.Xform.Define(stage, "/World")
    op = world.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 1.0)
    op.Set(Gf.Vec3d(1, 2, 0), 9.0)  # an animated ancestor: every prim below moves
    room = UsdGeom.Xform.Define(stage, "/World/Room")
    room.AddRotateYOp().Set(30.0)
    room.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    UsdGeom.Xform.Define(stage, "/Still")
    for i, parent in enumerate(["/World/Room", "/World/Room", "/World", "/Still", "/Still"]):
        g = random_gaussians(40 + i, degree=1, seed=i)
        prim = write_gaussian_prim(stage, f"{parent}/G{i}", g)
        if i == 1:
            UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(0.5, 0, 0), 4.0)  # its own samples too
    return stage


def test_shared_describe_equals_the_lone_one():
    stage = _stage()
    prims = find_gaussian_prims(stage)
    for tc in (Usd.TimeCode.EarliestTime(), Usd.TimeCode(5.0)):
        shared: dict = {}
        together = [describe_gaussian_prim(p, tc, shared=shared) for p in prims]
        alone = [describe_gaussian_prim(p, tc) for p in prims]
        for a, b in zip(together, alone, strict=True):
            assert (a.path, a.count, a.sh_degree, a.precision, a.time_samples, a.animated, a.role) == \
                (b.path, b.count, b.sh_degree, b.precision, b.time_samples, b.animated, b.role)
            assert a.world_bounds[0].tobytes() == b.world_bounds[0].tobytes()
            assert a.world_bounds[1].tobytes() == b.world_bounds[1].tobytes()
        # sorted by path: /Still/G3, /Still/G4, /World/G2, /World/Room/G0, /World/Room/G1
        assert [i.animated for i in alone] == [False, False, True, True, True]
        assert alone[4].time_samples == (1.0, 9.0) and alone[0].time_samples is None
        assert not np.allclose(alone[0].world_bounds[0], alone[3].world_bounds[0])
