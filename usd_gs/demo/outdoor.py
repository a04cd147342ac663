"""The outdoor demo shot (``usdgs demo make --outdoor``): a real sunlit capture, two avatars, no lights.

Layout on disk, for ``-o stages/outdoor.usda`` (like ``usd_gs.demo.stage``):

- ``stages/outdoor.usda``: small text root layer, Y-up, ``metersPerUnit`` 1, 24 fps, time codes
  1..F, ``defaultPrim`` World; ``/World`` (a ``SkelRoot``: CesiumMan is skinned) and
  ``/World/Camera``; its ``subLayers`` are ``./outdoor_data/{cesium_man,biker,seal}.usdc``.
- ``outdoor_data/seal.usdc``: ``/World/Seal``, role scene: the real capture
  ``scenes/luma-seal.splat`` (antimatter15 ``.splat``, Y-down, read by ``usd_gs.io.splat``)
  turned Y-up by a half turn about X and lifted so its pavement (the densest flat layer,
  ``usd_gs.relight.sun_estimation.ground_height``) lies on y = 0; baked into the points. Its
  statue casts its own baked shadow on the pavement; nothing above the horizon was captured.
- ``outdoor_data/biker.usdc``: ``/World/Biker``, role avatar, ``splats/biker.ply`` scaled to
  1.8 m (``usd_gs.demo.stage.BIKER_HEIGHT``), walking along :data:`BIKER_WALK` past the statue.
- ``outdoor_data/cesium_man.usdc``: ``/World/CesiumMan`` (skinned Gaussians of
  ``humans/CesiumMan.glb``, walking along :data:`CESIUM_WALK`) and its guide mesh, as in the
  room demo.

No UsdLux light is authored: ``usdgs process`` finds the capture open and estimates the sun
from the statue's baked shadow (``usd_gs.pipeline.capture_lights``). Deterministic.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Sdf, UsdSkel

from usd_gs.demo.stage import (
    DemoOptions,
    DemoResult,
    _new_layer_stage,
    _write_cesium_man,
    data_search_paths,
    define_camera,
    prepare_output,
    usd_matrix,
    write_walking_biker,
)
from usd_gs.errors import UserError
from usd_gs.io.splat import read_splat
from usd_gs.relight.sun_estimation import ground_height
from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim
from usd_gs.usd.schema import apply_role

SEAL_FILE = "scenes/luma-seal.splat"
OUTDOOR_FILES = {"seal": SEAL_FILE, "cesium_man": "humans/CesiumMan.glb", "biker": "splats/biker.ply"}
OUTDOOR_LAYERS = ("cesium_man", "biker", "seal")
Y_DOWN_TO_UP = np.diag([1.0, -1.0, -1.0])
"""The capture is Y-down: a half turn about X makes it Y-up (a rotation, so handedness is kept)."""


@dataclass(frozen=True)
class LinePath:
    """Walk along a straight line on y = 0 from ``start`` (x, z) at ``speed`` m/s towards
    ``heading_deg`` (the rotateY angle that turns +Z into the walking direction)."""

    start: tuple
    heading_deg: float
    speed: float

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (n, 3) metres, headings (n,) radians)`` at times ``t`` (s)."""
        t = np.asarray(t, np.float64).reshape(-1)
        h = math.radians(self.heading_deg)
        d = np.array([math.sin(h), 0.0, math.cos(h)])
        p = np.array([self.start[0], 0.0, self.start[1]]) + (self.speed * t)[:, None] * d
        return p, np.full(t.shape, h)


BIKER_WALK = LinePath(start=(-0.8, -0.7), heading_deg=0.0, speed=0.5)
"""The biker walks towards +Z along x = -0.8, west of the statue on sunlit pavement (the sun is
behind it to the north-east, so its shadow falls ahead of it to the south-west)."""

CESIUM_WALK = LinePath(start=(-0.2, -1.05), heading_deg=90.0, speed=0.89)
"""CesiumMan walks towards +X along z = -1.05, north of the statue (its walk clip's speed)."""

CAMERA_EYE = (-1.6, 2.3, 3.2)
CAMERA_TARGET = (-0.2, 0.2, -0.4)


@dataclass(frozen=True)
class OutdoorOptions:
    """What to generate: ``frames`` at 24 fps, CesiumMan's Gaussian count, the biker subset
    (None: every splat) and the seed."""

    frames: int = 24
    avatar_gaussians: int = 30000
    biker_gaussians: int | None = None
    seed: int = 0

    def check(self) -> None:
        if self.frames < 1:
            raise UserError(f"--frames must be >= 1, got {self.frames}")
        if self.avatar_gaussians < 1:
            raise UserError(f"--avatar-gaussians must be >= 1, got {self.avatar_gaussians}")


def locate_outdoor_data(explicit=None) -> Path:
    """The data directory holding :data:`OUTDOOR_FILES` (``explicit`` or the first
    ``shared/data`` found as in ``usd_gs.demo.stage.data_search_paths``)."""

    cands = [Path(explicit)] if explicit is not None else data_search_paths()
    for d in cands:
        if all((d / f).is_file() for f in OUTDOOR_FILES.values()):
            return d
    where = str(cands[0]) if explicit is not None else "shared/data beside the checkout or the current directory"
    raise UserError(f"{where}: does not hold {', '.join(OUTDOOR_FILES.values())} (the outdoor demo's inputs)")


def seal_scene(path):
    """The seal capture turned Y-up with its pavement on y = 0 (a ``GaussianSet``, metres)."""

    g = read_splat(path)
    up = g.transformed(usd_matrix(Y_DOWN_TO_UP, (0.0, 0.0, 0.0)), label="/World/Seal")
    h = ground_height(up, np.array([0.0, 1.0, 0.0]), np.zeros(3), 3.0, None, 0.5, 0.85, 0.02)
    h = 0.0 if h is None else h
    return g.transformed(usd_matrix(Y_DOWN_TO_UP, (0.0, -h, 0.0)), label="/World/Seal")


def _write_seal(opts: OutdoorOptions, src: Path, path: Path) -> int:
    g = seal_scene(src)
    g = replace(g, log_scales=None, logit_opacities=None, extras={})
    stage = _new_layer_stage(opts.frames)
    prim = write_gaussian_prim(stage, "/World/Seal", g, keep_raw=False)
    apply_role(prim, "scene")
    save_stage_atomic(stage, path)
    return g.count


def _write_root(opts: OutdoorOptions, path: Path, data_folder: str) -> None:
    stage = _new_layer_stage(opts.frames)
    world = UsdSkel.Root.Define(stage, "/World").GetPrim()
    world.SetCustomDataByKey("usdgs:demo:generator", "usdgs demo make --outdoor " + " ".join(
        f"{k}={getattr(opts, k)}" for k in ("frames", "avatar_gaussians", "biker_gaussians", "seed")))
    define_camera(stage, CAMERA_EYE, CAMERA_TARGET)
    stage.GetRootLayer().documentation = ("usd-gs outdoor demo stage, generated by 'usdgs demo make --outdoor' "
                                          "from ../shared/data (see usd_gs/demo/outdoor.py); regenerate rather "
                                          "than edit.")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(stage.GetRootLayer())
    layer.subLayerPaths = [f"./{data_folder}/{name}.usdc" for name in OUTDOOR_LAYERS]
    save_stage_atomic(layer, path)


def make_outdoor_demo(output="stages/outdoor.usda", options: OutdoorOptions | None = None, data_dir=None,
                      log=None):
    """Write the outdoor shot (module docstring) to ``output`` and its data layers beside it;
    returns a ``usd_gs.demo.stage.DemoResult``."""

    t0 = _time.perf_counter()
    opts = options or OutdoorOptions()
    opts.check()
    root, folder = prepare_output(output)
    data = locate_outdoor_data(data_dir)
    layers = {name: folder / f"{name}.usdc" for name in OUTDOOR_LAYERS}
    say = log or (lambda *_: None)
    demo = DemoOptions(frames=opts.frames, avatar_gaussians=opts.avatar_gaussians, seed=opts.seed)
    counts = {}
    say("  seal capture (Y-down -> Y-up, pavement on y = 0) ...")
    counts["/World/Seal"] = _write_seal(opts, data / SEAL_FILE, layers["seal"])
    say(f"  CesiumMan ({opts.avatar_gaussians} Gaussians x {opts.frames} frames) ...")
    counts["/World/CesiumMan"] = _write_cesium_man(demo, data / OUTDOOR_FILES["cesium_man"], layers["cesium_man"],
                                                   walk=CESIUM_WALK)
    say("  biker ...")
    counts["/World/Biker"] = write_walking_biker(replace(demo, biker_gaussians=opts.biker_gaussians),
                                                 data / OUTDOOR_FILES["biker"], layers["biker"], BIKER_WALK)
    _write_root(opts, root, folder.name)
    return DemoResult(root, layers, counts, opts.frames, _time.perf_counter() - t0)
