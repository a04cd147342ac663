"""Generate the demo stage (``usdgs demo make``): a lit room, two avatars, an inserted object, a camera.

The demo is generated from ``../shared/data`` (never copied into the repository) because
its animated data is tens of MB. Layout on disk, for ``-o stages/demo.usda``:

- ``stages/demo.usda``: small text root layer. Stage metadata (Y-up, ``metersPerUnit`` 1,
  ``timeCodesPerSecond``/``framesPerSecond`` 24, time codes 1..F, ``defaultPrim`` World),
  ``/World`` (a ``UsdSkel.Root``, an Xformable) carrying the lamp ground truth in ``customData`` (below), and
  ``/World/Camera``. Its ``subLayers`` are the binary data layers (relative paths
  ``./demo_data/<name>.usdc``, strongest first in the order cesium_man, biker, guitar,
  room; they define disjoint prims, so the order does not matter).
- ``stages/demo_data/room.usdc``: ``/World/Room`` (Xform), scene Gaussians from
  :func:`usd_gs.demo.room.make_room` (static, SH degree 1) split into spatial bricks
  ``/World/Room/Brick_NNNN`` of at most ``room_brick_size`` Gaussians (``usd_gs.usd.bricks``),
  each with ``usdgs:role`` scene, so shadows re-author only the bricks they touch. Where
  CesiumMan's shadows fall (:data:`SHADOW_DETAIL`: a floor patch and the foot of the x = -4
  wall) the surfaces carry ``room_detail_density`` Gaussians per m^2 (small, dense splats,
  as a capture has on surfaces), elsewhere ``room_density``.
- ``stages/demo_data/cesium_man.usdc``: ``/World/CesiumMan``, role avatar, SH degree 0: a
  skinned Gaussian prim (UsdSkel, ``usd_gs.usd.skel``; ``/World`` is a ``SkelRoot``) holding the
  bind-pose surface Gaussians of ``humans/CesiumMan.glb`` (the samples, colours, sigmas and inset
  of :func:`usd_gs.demo.mesh_avatar.posed_avatar_frames`, each with its triangle's blended
  vertex weights), bound to ``/World/CesiumMan_Skeleton`` (the glTF skin: joints parents first,
  bind = inverse bind matrices inverted) whose ``SkelAnimation`` ``Animation`` samples the walk
  clip at every frame (:func:`usd_gs.demo.rig.author_gltf_skinned_avatar`); the walk's root motion
  (a circle, :data:`CESIUM_PATH`) is the skeleton's time-sampled ``xformOp:transform``. Every
  reader skins it per frame (linear blend skinning); Gaussian k is the same skin point in every
  frame. ``/World/CesiumMan_guide``: the posed glTF mesh as a
  ``UsdGeom.Mesh`` (purpose guide, triangles, ``subdivisionScheme`` none), points and
  extent time-sampled at every frame in the same world placement, topology static; its
  relationship ``usdgs:demo:guideFor`` targets ``/World/CesiumMan``. Every Gaussian centre
  of frame f is near the same barycentric point of the mesh of frame f, moved half its in-plane
  sigma inwards along the normal (``avatar_from_mesh.AVATAR_INSET``: the Gaussians'
  silhouette then matches the mesh's); skinning a centre with blended weights differs from
  blending the skinned corners by a second-order term (median 0.3 mm, at most about 1 cm
  near the joints).
- ``stages/demo_data/tpose_avatar.usdc`` (option ``rigged_avatar``): ``/World/TPoseAvatar``, role
  avatar: the captured T-pose avatar ``humans/tpose_avatar.ply`` bound to the MakeHuman skeleton
  (``usd_gs.demo.rig.write_rigged_avatar_layer``: ``/World/TPoseAvatar_Skeleton``, T-posed bind,
  the MakeHuman walk on the spot looped over the frames), standing at ``rig.RIGGED_PLACEMENT``.
- ``stages/demo_data/biker.usdc``: ``/World/Biker``, role avatar: the real capture
  ``splats/biker.ply`` with its canonical placement baked into the points (turned to face
  +Z, feet at y = 0, centred on the Y axis, uniformly scaled to :data:`BIKER_HEIGHT`), moved
  along a circle (:data:`BIKER_PATH`) by time-sampled ``xformOp:translate`` and
  ``xformOp:rotateY`` (degrees; it faces its walking direction).
- ``stages/demo_data/guitar.usdc``: ``/World/Guitar``, role object: ``splats/guitar.ply``
  (a guitar on a stand, stored Y-down) turned upright, front facing +Z, base at y = 0,
  scaled to :data:`GUITAR_HEIGHT` tall; placed beside the table by a static translate and
  turning slowly by a time-sampled ``xformOp:rotateY``.

Lamp ground truth (no ``UsdLux`` lights are authored: the pipeline estimates them) lives in
the root layer as ``customData`` of ``/World``, read with
``prim.GetCustomDataByKey("usdgs:demo:lampPositions")`` etc.: ``lampPositions`` double3[]
(metres, world), ``lampColors`` double3[] (linear RGB, max 1), ``lampIntensities``
double[] (irradiance at 1 m is ``intensity * colour``), plus ``roomSize`` double3 and
``generator`` (the options used, a string). Same order as ``make_room(...).lamps``.

Times: frame f (1..F) is at ``(f - 1) / 24`` s. Everything is deterministic: the same
options give byte-identical files (fixed seeds, no timestamps).
"""

from __future__ import annotations

import math
import os
import time as _time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdSkel, Vt

from usd_gs.demo.mesh_avatar import posed_meshes
from usd_gs.demo.monkey import PRIM_PATH, write_monkey_layer
from usd_gs.demo.rig import author_gltf_skinned_avatar, write_rigged_avatar_layer
from usd_gs.demo.room import DetailRegion, make_room
from usd_gs.errors import UserError
from usd_gs.io.gltf import load_skinned_mesh
from usd_gs.io.ply import read_ply
from usd_gs.usd.bricks import write_bricked
from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
from usd_gs.usd.schema import apply_role
from usd_gs.usd.stage import USD_EXTENSIONS

FPS = 24.0
"""Time codes (= frames) per second of the demo stage."""

DATA_FILES = {"cesium_man": "humans/CesiumMan.glb", "biker": "splats/biker.ply", "guitar": "splats/guitar.ply"}
"""The inputs, relative to the data directory (``../shared/data`` beside a checkout)."""

LAYER_NAMES = ("cesium_man", "biker", "guitar", "room")
"""Data layers, in ``subLayers`` order (file ``<name>.usdc`` in the data folder)."""

ROOM_SIZE = (8.0, 3.0, 8.0)
"""Room box in metres: x in [-4, 4], y in [0, 3], z in [-4, 4] (``make_room`` default)."""

CESIUM_WALK_SPEED = 0.89
"""m/s: the speed at which CesiumMan's stance foot slides backwards in its in-place walk clip
(median over the 2 s loop, measured with ``gltf_skin.pose``); root motion at this speed keeps
the planted foot still on the floor."""

BIKER_HEIGHT = 1.8
"""Metres: the biker capture (about 3.18 units tall) is scaled to this height."""

GUITAR_HEIGHT = 1.0
"""Metres: the guitar capture (guitar and stand, about 4.38 units tall) is scaled to this height."""


@dataclass(frozen=True)
class CirclePath:
    """Walk along a circle in the floor plane: centre ``(cx, cz)`` metres, ``radius`` metres,
    ``speed`` m/s (positive: counter-clockwise seen from +Y, i.e. from +X towards -Z), start
    angle ``phase0`` radians (position ``(cx + r cos a, 0, cz - r sin a)``)."""

    cx: float
    cz: float
    radius: float
    speed: float
    phase0: float

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (n, 3) float64 metres on y = 0, headings (n,) radians)`` at times ``t`` (s).

        The heading is the rotation about +Y that turns +Z into the walking direction
        (``rotateY(heading)`` maps (0, 0, 1) to (sin h, 0, cos h)).
        """
        t = np.asarray(t, np.float64).reshape(-1)
        a = self.phase0 + self.speed * t / self.radius
        pos = np.stack([self.cx + self.radius * np.cos(a), np.zeros_like(a), self.cz - self.radius * np.sin(a)], 1)
        sgn = 1.0 if self.speed >= 0 else -1.0
        vel = sgn * np.stack([-np.sin(a), np.zeros_like(a), -np.cos(a)], 1)  # d pos / d a, walking sense
        return pos, np.arctan2(vel[:, 0], vel[:, 2])


CESIUM_PATH = CirclePath(cx=-1.6, cz=-0.4, radius=1.0, speed=CESIUM_WALK_SPEED, phase0=math.radians(200.0))
"""CesiumMan's circle: x in [-2.6, -0.6], z in [-1.4, 0.6], clear of the furniture and at least
0.6 m (horizontally) from the lamp at (-2, 2.4, -2); periodic, so any frame count stays inside."""

BIKER_PATH = CirclePath(cx=-0.3, cz=1.9, radius=0.6, speed=-0.5, phase0=math.radians(-60.0))
"""The biker's circle (clockwise, 0.5 m/s): x in [-0.9, 0.3], z in [1.3, 2.5]; its centre is
2.6 m from CesiumMan's, so the two never touch."""

GUITAR_POSITION = (2.3, 0.0, -0.45)
"""Metres: the guitar stands on the floor between the table (x <= 1.8) and the shelf (x >= 3.6)."""

GUITAR_HEADING_DEG = -35.0
GUITAR_TURN_DEG_PER_S = 12.0
"""The guitar's rotateY at time t: ``GUITAR_HEADING_DEG + GUITAR_TURN_DEG_PER_S * t`` degrees."""

CAMERA_EYE = (3.6, 1.7, 3.8)
CAMERA_TARGET = (-0.7, 0.8, -0.4)
CAMERA_FOCAL_MM = 24.0
CAMERA_APERTURE_MM = (36.0, 20.25)
CAMERA_CLIPPING = (0.05, 30.0)
"""``/World/Camera``: a 16:9 camera (24 mm lens on a 36 mm wide back: 74 x 46 degrees) in the
+X+Z corner looking at the action; clipping range in metres. Over the full loops of both
circles every avatar and the guitar stay inside the central 84% of the frame (NDC |x|, |y| <= 0.84)."""


SHADOW_DETAIL = (((-4.05, -0.05, -1.0), (0.2, 0.05, 2.8)), ((-4.05, 0.0, -0.9), (-3.95, 1.4, 0.7)))
"""Boxes (lo, hi, metres) of the room surfaces that get ``room_detail_density``: the floor
x in [-4, 0.2], z in [-1, 2.8] (16 m^2) and the x = -4 wall below 1.4 m for z in [-0.9, 0.7]
(2.2 m^2). They hold every point where CesiumMan's mesh shadow (strength > 0.1, either lamp)
falls inside the 2 m evaluation ROI over the whole walk loop (ray cast on a 2 cm grid over 48
frames: floor x in [-3.99, 0.01], z in [-0.79, 2.63]; wall y <= 1.29, z in [-0.69, 0.51]),
with a margin of 0.15-0.2 m; tests/test_demo_stage.py checks it."""


@dataclass(frozen=True)
class DemoOptions:
    """What to generate. ``biker_gaussians``/``guitar_gaussians`` None keep every splat of the
    capture, else a random subset of that size (``seed``)."""

    frames: int = 48
    avatar_gaussians: int = 30000
    room_density: float = 800.0
    room_detail_density: float | None = 6400.0
    biker_gaussians: int | None = None
    guitar_gaussians: int | None = None
    seed: int = 0
    room_brick_size: int = 500  # bricks a shadow touches are re-authored whole: small ones keep the output small
    monkey: bool = False  # add the SOG flipbook monkey (usd_gs/demo/monkey.py) as /World/Monkey
    rigged_avatar: bool = False  # add the T-pose capture rigged to MakeHuman, walking (usd_gs/demo/rig.py)

    def check(self) -> None:
        if self.frames < 1:
            raise UserError(f"--frames must be >= 1, got {self.frames}")
        if self.avatar_gaussians < 1:
            raise UserError(f"--avatar-gaussians must be >= 1, got {self.avatar_gaussians}")
        if not (self.room_density > 0 and math.isfinite(self.room_density)):
            raise UserError(f"--room-density must be a positive number of Gaussians per m^2, got {self.room_density}")
        d = self.room_detail_density
        if d is not None and not (d > 0 and math.isfinite(d)):
            raise UserError(f"--room-detail-density must be a positive number of Gaussians per m^2, got {d}")
        if self.room_brick_size < 1:
            raise UserError(f"room brick size must be >= 1, got {self.room_brick_size}")
        for name in ("biker_gaussians", "guitar_gaussians"):
            v = getattr(self, name)
            if v is not None and v < 1:
                raise UserError(f"{name} must be >= 1, got {v}")


QUICK = DemoOptions(frames=8, avatar_gaussians=5000, room_density=60.0, room_detail_density=None,
                    biker_gaussians=8000, guitar_gaussians=5000, room_brick_size=1000)
"""``--quick``: a tiny demo for tests (about 30k Gaussians in all, 8 frames)."""


@dataclass
class DemoResult:
    """What :func:`make_demo` wrote: the root layer, the data layers by name, Gaussian counts by
    prim path, the frame count and the wall time in seconds."""

    root: Path
    layers: dict[str, Path]
    counts: dict[str, int]
    frames: int
    seconds: float

    def files(self) -> list[Path]:
        return [self.root, *self.layers.values()]


# ----------------------------------------------------------------------------- the data directory
def data_search_paths(starts=None) -> list[Path]:
    """Candidate data directories: ``<ancestor>/shared/data`` for every ancestor (itself
    included) of each start directory (default: this package's directory and the CWD)."""
    if starts is None:
        starts = [Path(__file__).resolve().parent, Path.cwd().resolve()]
    out: list[Path] = []
    for s in starts:
        s = Path(s).resolve()
        for a in (s, *s.parents):
            c = a / "shared" / "data"
            if c not in out:
                out.append(c)
    return out


def _missing(d: Path) -> list[str]:
    return [rel for rel in DATA_FILES.values() if not (d / rel).is_file()]


def locate_data_dir(explicit=None, starts=None) -> Path:
    """The directory holding :data:`DATA_FILES`: ``explicit`` if given (checked), else the first
    of :func:`data_search_paths` that holds them all. ``UserError`` names what was searched."""
    need = ", ".join(DATA_FILES.values())
    if explicit is not None:
        d = Path(explicit)
        if not d.is_dir():
            raise UserError(f"--data {d}: no such directory (it must hold {need})")
        miss = _missing(d)
        if miss:
            raise UserError(f"--data {d}: missing {', '.join(miss)}")
        return d
    searched = data_search_paths(starts)
    for c in searched:
        if c.is_dir() and not _missing(c):
            return c
    raise UserError(f"demo data not found: none of {', '.join(str(c) for c in searched)} holds {need}; "
                    "pass --data DIR")


# ----------------------------------------------------------------------------- geometry helpers
def rotation_y(angle_rad: float) -> np.ndarray:
    """3x3 rotation about +Y (column-vector convention): maps (0, 0, 1) to (sin a, 0, cos a)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def usd_matrix(rot: np.ndarray, translation, scale: float = 1.0) -> np.ndarray:
    """4x4 USD (row-vector) matrix of ``p -> scale * rot @ p + translation``."""
    m = np.eye(4)
    m[:3, :3] = (scale * np.asarray(rot, np.float64)).T
    m[3, :3] = np.asarray(translation, np.float64)
    return m


def canonical_matrix(positions: np.ndarray, rot: np.ndarray, height: float) -> np.ndarray:
    """USD matrix that rotates a capture by ``rot``, then puts the lowest point on y = 0, the
    x/z bounding-box centre on the Y axis, and scales it uniformly to ``height`` metres tall."""
    p = np.asarray(positions, np.float64) @ np.asarray(rot, np.float64).T
    lo, hi = p.min(axis=0), p.max(axis=0)
    s = height / (hi[1] - lo[1])
    centre = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    return usd_matrix(rot, -s * centre, s)


BIKER_ROTATION = rotation_y(math.pi / 2)
"""biker.ply is Y-up and faces -X (profile views): rotateY(+90 deg) turns it to face +Z."""

GUITAR_ROTATION = rotation_y(-math.pi / 2) @ np.diag([1.0, -1.0, -1.0])
"""guitar.ply is Y-down (COLMAP): a half turn about X makes it upright (the stand's feet at the
bottom, the neck leaning back towards -X, strings facing +X); rotateY(-90 deg) then turns its
front to +Z."""


def look_at_matrix(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """USD (row-vector) camera-to-world matrix of a camera at ``eye`` looking at ``target``
    (USD cameras look down their local -Z with +Y up)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = eye - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3], m[3, :3] = x, y, z, eye
    return m


def frame_times(frames: int) -> np.ndarray:
    """(F,) seconds of frames 1..F: ``(f - 1) / FPS``."""
    return np.arange(frames, dtype=np.float64) / FPS


# ----------------------------------------------------------------------------- layers
def _new_layer_stage(frames: int):
    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    stage.SetTimeCodesPerSecond(FPS)
    stage.SetFramesPerSecond(FPS)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    return stage


def _set_samples(layer, attr, values: dict[float, object]) -> None:
    """Author time samples of one attribute at the Sdf level (call inside ``Sdf.ChangeBlock``)."""
    path = attr.GetPath()
    for t, v in values.items():
        layer.SetTimeSample(path, t, v)


def _subsample(g, n: int | None, seed: int):
    if n is None or n >= g.count:
        return g
    idx = np.sort(np.random.default_rng(seed).choice(g.count, size=n, replace=False))
    return g.subset(idx)


def room_detail(opts: DemoOptions) -> list:
    """The ``make_room`` detail regions of ``opts`` (:data:`SHADOW_DETAIL` at
    ``room_detail_density``; none when that is None or not above ``room_density``)."""

    d = opts.room_detail_density
    if d is None or d <= opts.room_density:
        return []
    return [DetailRegion(lo, hi, float(d)) for lo, hi in SHADOW_DETAIL]


def _write_room(opts: DemoOptions, path: Path):
    room = make_room(size=ROOM_SIZE, density=opts.room_density, seed=opts.seed, detail=room_detail(opts),
                     label="/World/Room")
    stage = _new_layer_stage(opts.frames)
    write_bricked(stage, "/World/Room", room.gaussians, opts.room_brick_size, keep_raw=False, role="scene")
    save_stage_atomic(stage, path)
    return room


def _write_cesium_man(opts: DemoOptions, glb: Path, path: Path, walk=None) -> int:
    mesh = load_skinned_mesh(glb)
    times = frame_times(opts.frames)
    meshes = posed_meshes(mesh, times, loop=True)
    where, heading = (walk or CESIUM_PATH).at(times)  # walk: any path with .at(t) (the outdoor demo's line)
    stage = _new_layer_stage(opts.frames)
    UsdSkel.Root.Define(stage, "/World")  # the root layer's /World is a SkelRoot too (it is the stronger opinion)
    placement = {float(f): usd_matrix(rotation_y(float(h)), p)
                 for f, (p, h) in enumerate(zip(where, heading, strict=True), start=1)}
    prim = author_gltf_skinned_avatar(stage, mesh, "/World/CesiumMan", "/World/CesiumMan_Skeleton", times,
                                      np.arange(1, opts.frames + 1, dtype=np.float64), opts.avatar_gaussians,
                                      seed=opts.seed, loop=True, skel_xforms=placement)
    apply_role(prim, "avatar")

    points = {}
    extents = {}
    for f, ((verts, _), p, h) in enumerate(zip(meshes, where, heading, strict=True), start=1):
        rot = rotation_y(float(h))
        v = (verts @ rot.T + p).astype(np.float32)
        points[float(f)] = Vt.Vec3fArray.FromNumpy(v)
        extents[float(f)] = Vt.Vec3fArray.FromNumpy(np.stack([v.min(axis=0), v.max(axis=0)]))

    guide = UsdGeom.Mesh.Define(stage, "/World/CesiumMan_guide")
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    guide.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    guide.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    faces = np.ascontiguousarray(mesh.faces, np.int32)
    guide.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    guide.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    pts_attr = guide.CreatePointsAttr()
    ext_attr = guide.CreateExtentAttr()
    guide.GetPrim().CreateRelationship("usdgs:demo:guideFor", custom=True).SetTargets(
        [Sdf.Path("/World/CesiumMan")])
    layer = stage.GetRootLayer()
    with Sdf.ChangeBlock():
        _set_samples(layer, pts_attr, points)
        _set_samples(layer, ext_attr, extents)
    save_stage_atomic(stage, path)
    return opts.avatar_gaussians


def _write_capture(opts: DemoOptions, ply: Path, path: Path, prim_path: str, role: str, rot: np.ndarray,
                   height: float, n: int | None, seed: int, translate: dict, rotate_y: dict) -> int:
    """A real capture placed canonically (baked into the points) and moved by xform time samples
    (``translate``/``rotate_y``: {time code: value}; one entry at time None = a default value)."""

    full = read_ply(ply)
    m = canonical_matrix(full.positions, rot, height)  # from the full capture: --quick keeps the same frame
    g = _subsample(full, n, seed).transformed(m, label=prim_path)
    g = replace(g, log_scales=None, logit_opacities=None, extras={})
    stage = _new_layer_stage(opts.frames)
    prim = write_gaussian_prim(stage, prim_path, g, keep_raw=False)
    apply_role(prim, role)
    xf = UsdGeom.Xformable(prim)
    t_op = xf.AddTranslateOp()
    r_op = xf.AddRotateYOp()
    layer = stage.GetRootLayer()
    with Sdf.ChangeBlock():
        for op, values, conv in ((t_op, translate, lambda v: Gf.Vec3d(*map(float, v))), (r_op, rotate_y, float)):
            spec = layer.GetAttributeAtPath(op.GetAttr().GetPath())
            for t, v in values.items():
                if t is None:
                    spec.default = conv(v)
                else:
                    layer.SetTimeSample(spec.path, float(t), conv(v))
    save_stage_atomic(stage, path)
    return g.count


def write_walking_biker(opts: DemoOptions, ply: Path, path: Path, walk) -> int:
    """``/World/Biker`` (role avatar) from the biker capture ``ply``, walking along ``walk`` (a path
    with ``.at(times)`` -> (positions, headings in radians)) at the demo's frames; its count."""
    where, heading = walk.at(frame_times(opts.frames))
    return _write_capture(
        opts, ply, path, "/World/Biker", "avatar", BIKER_ROTATION, BIKER_HEIGHT, opts.biker_gaussians, opts.seed + 1,
        translate={f: p for f, p in enumerate(where, start=1)},
        rotate_y={f: math.degrees(h) for f, h in enumerate(heading, start=1)})


def _write_root(opts: DemoOptions, path: Path, data_folder: str, room) -> None:
    stage = _new_layer_stage(opts.frames)
    # SkelRoot: CesiumMan is a skinned Gaussian prim (UsdSkel skins only below a SkelRoot)
    world = UsdSkel.Root.Define(stage, "/World").GetPrim()
    lamps = room.lamps
    world.SetCustomDataByKey("usdgs:demo:lampPositions", Vt.Vec3dArray([Gf.Vec3d(*map(float, lp.position))
                                                                        for lp in lamps]))
    world.SetCustomDataByKey("usdgs:demo:lampColors", Vt.Vec3dArray([Gf.Vec3d(*map(float, lp.color))
                                                                     for lp in lamps]))
    world.SetCustomDataByKey("usdgs:demo:lampIntensities", Vt.DoubleArray([float(lp.intensity) for lp in lamps]))
    world.SetCustomDataByKey("usdgs:demo:roomSize", Gf.Vec3d(*map(float, room.size)))
    world.SetCustomDataByKey("usdgs:demo:generator", generator_string(opts))

    define_camera(stage, CAMERA_EYE, CAMERA_TARGET)
    stage.GetRootLayer().documentation = ("usd-gs demo stage, generated by 'usdgs demo make' from ../shared/data "
                                          "(see usd_gs/demo/stage.py); regenerate rather than edit.")
    # A copy that no stage listens to: a stage would try to load the relative sublayers right
    # away, relative to its anonymous root layer, and warn.
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(stage.GetRootLayer())
    names = (*LAYER_NAMES, "monkey") if opts.monkey else LAYER_NAMES
    if opts.rigged_avatar:
        names = (*names, "tpose_avatar")
    layer.subLayerPaths = [f"./{data_folder}/{name}.usdc" for name in names]
    save_stage_atomic(layer, path)


def define_camera(stage, eye, target):
    """``/World/Camera``: the demo's perspective camera (focal length, aperture and clipping of
    this module's ``CAMERA_*`` constants) at ``eye`` looking at ``target`` (metres, Y-up)."""

    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(CAMERA_FOCAL_MM)
    cam.CreateHorizontalApertureAttr(CAMERA_APERTURE_MM[0])
    cam.CreateVerticalApertureAttr(CAMERA_APERTURE_MM[1])
    cam.CreateClippingRangeAttr(Gf.Vec2f(*CAMERA_CLIPPING))
    cam.AddTransformOp().Set(Gf.Matrix4d(look_at_matrix(eye, target).tolist()))
    return cam


def generator_string(opts: DemoOptions) -> str:
    """The options as one deterministic line, recorded in ``/World`` customData."""
    return "usdgs demo make " + " ".join(f"{k}={v}" for k, v in asdict(opts).items())


# ----------------------------------------------------------------------------- entry point
def data_folder_for(root: Path) -> Path:
    """The folder of the binary layers: ``<root stem>_data`` beside the root layer."""
    root = Path(root)
    return root.with_name(root.stem + "_data")


def prepare_output(output) -> tuple[Path, Path]:
    """``(root layer path, data folder)`` of a demo shot written to ``output`` (a USD file name):
    absolute paths, the data folder created; ``UserError`` naming ``output`` otherwise."""

    root = Path(os.path.abspath(os.fspath(output)))
    if root.suffix.lower() not in USD_EXTENSIONS:
        raise UserError(f"{output}: output must end in {', '.join(USD_EXTENSIONS)}")
    folder = data_folder_for(root)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{output}: cannot create the data folder {folder} ({exc.strerror or exc})") from None
    return root, folder


def make_demo(output="stages/demo.usda", options: DemoOptions | None = None, data_dir=None, log=None) -> DemoResult:
    """Write the demo stage (module docstring) to ``output`` and its data layers beside it.

    ``data_dir`` None searches for ``shared/data`` (:func:`locate_data_dir`). Missing parent
    folders are created. The data layers are written first and the root layer last, each
    atomically. ``log``: optional ``print``-like callable for progress lines.
    """

    t0 = _time.perf_counter()
    opts = options or DemoOptions()
    opts.check()
    root, folder = prepare_output(output)
    data = locate_data_dir(data_dir)
    layers = {name: folder / f"{name}.usdc" for name in (*LAYER_NAMES, "monkey") if name != "monkey" or opts.monkey}
    if opts.rigged_avatar:
        layers["tpose_avatar"] = folder / "tpose_avatar.usdc"
    say = log or (lambda *_: None)

    counts: dict[str, int] = {}
    detail = f", {opts.room_detail_density:g} where CesiumMan's shadows fall" if room_detail(opts) else ""
    say(f"  room ({opts.room_density:g} Gaussians/m^2{detail}) ...")
    room = _write_room(opts, layers["room"])
    counts["/World/Room"] = room.gaussians.count
    say(f"  CesiumMan ({opts.avatar_gaussians} Gaussians x {opts.frames} frames) ...")
    counts["/World/CesiumMan"] = _write_cesium_man(opts, data / DATA_FILES["cesium_man"], layers["cesium_man"])

    times = frame_times(opts.frames)
    say("  biker ...")
    counts["/World/Biker"] = write_walking_biker(opts, data / DATA_FILES["biker"], layers["biker"], BIKER_PATH)
    say("  guitar ...")
    counts["/World/Guitar"] = _write_capture(
        opts, data / DATA_FILES["guitar"], layers["guitar"], "/World/Guitar", "object", GUITAR_ROTATION,
        GUITAR_HEIGHT, opts.guitar_gaussians, opts.seed + 2,
        translate={None: GUITAR_POSITION},
        rotate_y={f: GUITAR_HEADING_DEG + GUITAR_TURN_DEG_PER_S * t for f, t in enumerate(times, start=1)})
    if opts.monkey:

        say("  monkey (SOG flipbook) ...")
        counts[PRIM_PATH] = write_monkey_layer(opts.frames, data, layers["monkey"], FPS)
    if opts.rigged_avatar:

        say("  rigged T-pose avatar (MakeHuman skeleton, walk) ...")
        counts["/World/TPoseAvatar"] = write_rigged_avatar_layer(opts.frames, data, layers["tpose_avatar"], FPS)
    _write_root(opts, root, folder.name, room)
    return DemoResult(root, layers, counts, opts.frames, _time.perf_counter() - t0)
