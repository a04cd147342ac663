"""The static scene's shadows on the moving receivers come from one shot-long atlas per point light
and moving receiver prim (``ShotProcessor._static_atlas``): each is bounded by its own prim's
reach, so two avatars far apart pack only the occluders near each, and the output is bit for bit
that of one atlas of every occluder serving every prim. Prims with nothing time-sampled share one."""

import numba
import numpy as np
import pytest
from farm_compare import stage_differences

import usd_gs.pipeline.shot as shot
from usd_gs.cli import main
from usd_gs.shadows.static_scene import StaticSceneAtlas

FRAMES = [1, 2, 3]


def _shot(path):
    """A 10 m x 10 m floor slab with boxes on it, a sphere light 3 m above its centre, two walkers
    4 m apart (x = -2 and x = +2) and a held box between them."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    stage = new_stage(None)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(len(FRAMES))
    stage.SetTimeCodesPerSecond(24)
    room = random_gaussians(4000, degree=1, seed=1)
    room.positions[:, 1] = room.positions[:, 1] * 0.02 - 0.05  # the floor, x and z in [-5, 5] m
    boxes = random_gaussians(2000, degree=1, seed=2)
    boxes.positions *= 0.1
    boxes.positions[:, 1] += 0.6
    boxes.positions[:1000, 0] -= 2.3  # a box beside each walker, between it and the light
    boxes.positions[1000:, 0] += 2.3
    write_gaussian_prim(stage, "/World/Room", room)
    write_gaussian_prim(stage, "/World/Boxes", boxes)
    for i, x in enumerate((-2.0, 2.0)):
        walker = random_gaussians(300, degree=1, seed=10 + i)
        walker.positions *= 0.06
        walker.positions[:, 1] += 0.4
        prim = f"/World/Walker{i}"
        write_gaussian_prim(stage, prim, walker)
        op = UsdGeom.Xformable(stage.GetPrimAtPath(prim)).AddTranslateOp()
        for f in FRAMES:
            op.Set(Gf.Vec3d(x, 0.0, 0.1 * f), Usd.TimeCode(f))
    held = random_gaussians(200, degree=1, seed=20)
    held.positions *= 0.05
    write_gaussian_prim(stage, "/World/Held", held)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Held")).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.3, 1.0))
    light = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    light.CreateIntensityAttr(50.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    save_stage_atomic(stage, path)
    return path


ARGS = ["--scene", "/World/Room", "--scene", "/World/Boxes", "--avatar", "/World/Walker0", "--avatar",
        "/World/Walker1", "--object", "/World/Held", "--lights", "stage", "--aovs", "transmittance",
        "--precision", "float", "--sh-tolerance", "0", "-q"]


def _run(stage, out, mp, shared: str | None) -> dict:
    """Process ``stage`` into ``out``; ``shared`` None: as shipped (the tasks in threads where there
    are two); "every": one atlas of every occluder per light for all prims; "bounded": one bounded
    atlas per light for all prims (both on one thread).
    Returns ``{atlas key: occluders packed at its last packing}``."""
    kept = {}
    plain = shot.ShotProcessor._static_atlas

    def one_for_all(self, light, prim):
        key = ("one atlas", tuple(np.round(light.position, 6)))
        if key not in self._scene_packs:
            self._scene_packs[key] = StaticSceneAtlas(self._scene_block, light.position, self._centre_cfg,
                                                      bounded=shared == "bounded", keep=self._emitter_keep(light))
        return self._scene_packs[key]

    def recorded(self, light, prim):
        atlas = (plain if shared is None else one_for_all)(self, light, prim)
        kept[prim if shared is None else "one"] = atlas
        return atlas

    threads = numba.get_num_threads()
    with mp.context() as m:
        m.setattr(shot.ShotProcessor, "_static_atlas", recorded)
        if shared is not None:  # one atlas that every prim's task fills: the tasks one after the other
            numba.set_num_threads(1)
        try:
            assert main(["process", str(stage), "-o", str(out), *ARGS]) == 0
        finally:
            numba.set_num_threads(threads)
    return {k: a.kept for k, a in kept.items()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("atlas_per_prim")
    stage = _shot(tmp / "shot.usda")
    mp = pytest.MonkeyPatch()
    got = {mode: (tmp / f"{mode}.usdc", _run(stage, tmp / f"{mode}.usdc", mp, None if mode == "per_prim" else mode))
           for mode in ("per_prim", "every", "bounded")}
    return got


def test_per_prim_atlases_give_the_bits_of_one_atlas_of_every_occluder(runs):
    assert stage_differences(runs["per_prim"][0], runs["every"][0], FRAMES) == []
    assert stage_differences(runs["per_prim"][0], runs["bounded"][0], FRAMES) == []


def test_each_walker_atlas_packs_the_occluders_near_it_only(runs):
    kept = runs["per_prim"][1]
    assert set(kept) == {"/World/Walker0", "/World/Walker1", None}  # the held box under the shared key
    one = runs["bounded"][1]["one"]  # one reach around both walkers: most of the floor
    every = runs["every"][1]["one"]
    assert every == 6000
    for walker in ("/World/Walker0", "/World/Walker1"):
        assert 0 < kept[walker] < 0.6 * one, (walker, kept[walker], one)


def test_the_walkers_are_shadowed_by_the_box_beside_them(runs):
    """The case is not vacuous: each walker has Gaussians in the static scene's shadow."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(runs["per_prim"][0]))
    for walker in ("/World/Walker0", "/World/Walker1"):
        t = np.asarray(stage.GetPrimAtPath(walker).GetAttribute("primvars:usdgs:transmittance").Get(2))
        assert t.size == 300 and t.min() < 0.9, (walker, t.min())
