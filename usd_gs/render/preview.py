"""Preview renders of a USD stage's Gaussians (the logic behind ``usdgs render``).

What is drawn at frame ``f`` (a USD time code): every ``ParticleField3DGaussianSplat`` prim
found by :func:`usd_gs.usd.gaussian_prim.find_gaussian_prims` that is visible at ``f``
(``UsdGeom.Imageable.ComputeVisibility`` is not ``invisible``) and whose computed purpose is
``default`` or ``render`` (``guide`` and ``proxy`` prims are skipped), read in world space at
``f`` and concatenated in path order (SH zero-padded to the highest degree), then rendered
with the CPU splat rasteriser (:func:`usd_gs.render.rasterize.render`: 3DGS EWA splatting, colour
``max(0, 0.5 + SH(dir))`` in the 3DGS basis, composited over a background colour).

For a stage written by ``usdgs process`` the shadowed / relit SH coefficients are what the
stage composes to, so rendering the output stage shows the lit result and rendering its
first sublayer (:func:`input_stage`) shows the original.

Cameras (:func:`resolve_camera`): a ``UsdGeom.Camera`` prim given by path; by default the
first camera prim of the stage in path order; with none, a look-at camera (:func:`framing_camera`)
that frames all but the outermost 1 % of the drawn Gaussians' centres on each axis
(:func:`gaussian_framing_bounds`). Image width is chosen by
the caller; height follows the camera aperture (``width * verticalAperture /
horizontalAperture``), 16:9 for the look-at camera.

Colour values are the 3DGS display-referred colours (linear in the renderer's sense; write
them to PNG as they are, without an sRGB curve). This module imports numba only inside the
render call (through :mod:`usd_gs.render.rasterize`).
"""

from __future__ import annotations

import math
import os
import time as _time
from dataclasses import dataclass, field

import numpy as np

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.render import rasterize as _render
from usd_gs.render.camera import Camera
from usd_gs.usd.frames import as_time
from usd_gs.usd.output_layer import topology_layer_path

DEFAULT_WIDTH = 960
FALLBACK_ASPECT = 16.0 / 9.0
"""Width / height of the look-at fallback camera's image."""
FALLBACK_FOV_Y_DEG = 50.0
"""Vertical field of view of the look-at fallback camera (degrees)."""
FALLBACK_MARGIN = 1.05
"""The fallback camera stands this factor further back than the bounding sphere needs."""
FALLBACK_DIRECTION_Y_UP = (0.6, 0.5, 1.0)
"""Direction from the bounds' centre towards the fallback camera for Y-up stages (front, right,
above); for Z-up stages the same direction with (x, y, z) -> (x, -z, y)."""
SKIPPED_PURPOSES = ("guide", "proxy")


@dataclass
class RenderResult(_render.RenderResult):
    """A rendered frame: ``rgb`` (H,W,3) float32 composited over the background, ``alpha``
    (H,W) float32 coverage, ``depth`` (H,W) float32 expected view depth (scene units, 0 where
    empty), as :class:`usd_gs.render.rasterize.RenderResult`; plus the frame (time code), the camera,
    the number of Gaussians drawn, the prim paths they came from and the seconds spent reading
    the stage and rasterising."""

    frame: float = 0.0
    camera: Camera | None = None
    count: int = 0
    prims: list[str] = field(default_factory=list)
    read_s: float = 0.0
    render_s: float = 0.0


def stage_label(stage) -> str:
    """The stage's root layer file (or identifier) for error messages."""
    layer = stage.GetRootLayer()
    return layer.realPath or layer.identifier


def _tc(frame):
    """The frame's time code; None: the earliest time (the first sample of animated prims)."""
    from pxr import Usd

    return as_time(frame, Usd.TimeCode.EarliestTime())


# ----------------------------------------------------------------------------- which Gaussians
def camera_prims(stage) -> list:
    """Every ``UsdGeom.Camera`` prim of the stage (active, defined), sorted by path."""
    from pxr import UsdGeom

    cams = [p for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
    cams.sort(key=lambda p: p.GetPath().pathString)
    return cams


def is_drawn(prim, frame=None) -> bool:
    """True when ``prim`` is visible at ``frame`` and its computed purpose is default/render."""
    from pxr import UsdGeom

    img = UsdGeom.Imageable(prim)
    if not img:
        return True  # not imageable: nothing says it is hidden
    if img.ComputeVisibility(_tc(frame)) == UsdGeom.Tokens.invisible:
        return False
    return img.ComputePurpose() not in SKIPPED_PURPOSES


def drawn_gaussian_prims(stage, frame=None) -> list:
    """The Gaussian prims drawn at ``frame`` (module docstring), sorted by path."""
    from usd_gs.usd.gaussian_prim import find_gaussian_prims

    return [p for p in find_gaussian_prims(stage) if is_drawn(p, frame)]


def read_stage_gaussians(stage, frame=None) -> tuple[GaussianSet, list[str]]:
    """(world-space Gaussians of every drawn prim at ``frame`` concatenated in path order,
    their prim paths). Bad data raises the readers' ``UserError`` naming prim and attribute."""
    from usd_gs.usd.gaussian_prim import read_gaussian_prim

    tc = _tc(frame)
    prims = drawn_gaussian_prims(stage, tc)
    sets = [read_gaussian_prim(p, tc, world=True) for p in prims]
    gs = GaussianSet.concatenate(sets, label=f"{stage_label(stage)} (frame {tc.GetValue():g})")
    return gs, [p.GetPath().pathString for p in prims]


def _finite_world_bounds(info) -> tuple[np.ndarray, np.ndarray] | None:
    """A prim description's ``world_bounds`` when it has finite ones, else None."""
    b = info.world_bounds
    return b if b is not None and np.all(np.isfinite(b[0])) and np.all(np.isfinite(b[1])) else None


def gaussian_world_bounds(stage, frames) -> tuple[np.ndarray, np.ndarray] | None:
    """(min (3,), max (3,)) float64 union of the world bounds (authored ``extent``, else the
    centres) of the drawn Gaussian prims over ``frames``; None when there are none."""
    from usd_gs.usd.gaussian_prim import describe_gaussian_prim

    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for f in frames:
        tc = _tc(f)
        for p in drawn_gaussian_prims(stage, tc):
            b = _finite_world_bounds(describe_gaussian_prim(p, tc))
            if b is not None:
                lo = np.minimum(lo, b[0])
                hi = np.maximum(hi, b[1])
    if not np.all(hi >= lo):
        return None
    return lo, hi


#: share of the drawn Gaussian centres left out on each side of each axis by the default framing
#: (:func:`gaussian_framing_bounds`): a capture's stray splats and the 3-sigma reach of its large
#: background splats do not push the look-at camera away from what the stage shows
FRAMING_QUANTILE = 0.01
#: centres sampled per prim and frame for the framing (every k-th, in order)
FRAMING_SAMPLES = 20000


def gaussian_framing_bounds(stage, frames) -> tuple[np.ndarray, np.ndarray] | None:
    """(min (3,), max (3,)) float64 world box that the default look-at camera frames: per axis, the
    :data:`FRAMING_QUANTILE` and ``1 - FRAMING_QUANTILE`` quantiles of the drawn Gaussian prims'
    world-space centres over ``frames`` (up to :data:`FRAMING_SAMPLES` evenly spaced centres per
    prim and frame, each prim's samples weighted by its count), widened to hold every skinned
    prim's world bounds (their centres move with the skeleton). :func:`gaussian_world_bounds`
    where no centre can be read; None when nothing is drawn."""
    from pxr import UsdGeom

    from usd_gs.usd.gaussian_layer import POSITIONS
    from usd_gs.usd.gaussian_prim import data_attribute, describe_gaussian_prim, read_array
    from usd_gs.usd.skel import has_skel_binding

    pts, weights, boxes = [], [], []
    for f in frames:
        tc = _tc(f)
        for p in drawn_gaussian_prims(stage, tc):
            if has_skel_binding(p):
                b = _finite_world_bounds(describe_gaussian_prim(p, tc))
                if b is not None:
                    boxes.append(b)
                continue
            local = read_array(data_attribute(p, POSITIONS)[0], tc)
            if local is None or len(local) == 0:
                continue
            local = np.asarray(local).reshape(-1, 3)
            step = max(1, len(local) // FRAMING_SAMPLES)
            m = np.array(UsdGeom.Xformable(p).ComputeLocalToWorldTransform(tc), np.float64)
            x = local[::step].astype(np.float64) @ m[:3, :3] + m[3, :3]
            x = x[np.all(np.isfinite(x), axis=1)]
            if len(x):
                pts.append(x)
                weights.append(np.full(len(x), len(local) / len(x)))
    if not pts:
        return gaussian_world_bounds(stage, frames)
    x, w = np.concatenate(pts), np.concatenate(weights)
    lo, hi = np.empty(3), np.empty(3)
    for axis in range(3):
        order = np.argsort(x[:, axis], kind="stable")
        cum = np.cumsum(w[order])
        cum /= cum[-1]
        lo[axis] = x[order[np.searchsorted(cum, FRAMING_QUANTILE)], axis]
        hi[axis] = x[order[min(np.searchsorted(cum, 1.0 - FRAMING_QUANTILE), len(order) - 1)], axis]
    for b_lo, b_hi in boxes:
        lo, hi = np.minimum(lo, b_lo), np.maximum(hi, b_hi)
    return lo, hi


# ----------------------------------------------------------------------------- cameras
def framing_camera(lo, hi, width: int = DEFAULT_WIDTH, height: int | None = None, up_axis: str = "Y",
                   fov_y_deg: float = FALLBACK_FOV_Y_DEG) -> Camera:
    """A look-at camera that sees the whole box ``[lo, hi]`` (world units).

    The box's bounding sphere (centre ``c``, radius ``r``, at least 1e-3) fits inside the
    narrower of the two fields of view (vertical ``fov_y_deg``; horizontal from the aspect),
    with :data:`FALLBACK_MARGIN`: every point of the box projects inside the image in front
    of ``near``. The camera looks at ``c`` from :data:`FALLBACK_DIRECTION_Y_UP` (mapped to
    Z-up when ``up_axis`` is 'Z'), with the stage's up axis up in the image.
    ``height`` defaults to ``width / FALLBACK_ASPECT``.
    """
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    width = int(width)
    if height is None:
        height = max(1, int(round(width / FALLBACK_ASPECT)))
    c = 0.5 * (lo + hi)
    r = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    half_y = math.radians(0.5 * fov_y_deg)
    half_x = math.atan(math.tan(half_y) * width / height)
    d = FALLBACK_MARGIN * r / math.sin(min(half_x, half_y))
    x, y, z = FALLBACK_DIRECTION_Y_UP
    if up_axis == "Z":
        direction, up = np.array([x, -z, y]), (0.0, 0.0, 1.0)
    else:
        direction, up = np.array([x, y, z]), (0.0, 1.0, 0.0)
    direction /= np.linalg.norm(direction)
    near = 0.5 * (d - r)  # > 0: d >= 1.05 r
    far = 2.0 * (d + r)
    return Camera.look_at(c + d * direction, c, up=up, width=width, height=height, fov_y_deg=fov_y_deg,
                          near=near, far=far)


def resolve_camera(stage, path: str | None = None, frame=None, width: int = DEFAULT_WIDTH,
                   bounds_frames=None) -> Camera:
    """The camera to render ``stage`` with at ``frame``.

    ``path``: a ``UsdGeom.Camera`` prim path (``UserError`` naming the stage and path when
    there is no prim there or it is not a camera). None: the first camera prim in path
    order, else :func:`framing_camera` around the drawn Gaussians' :func:`gaussian_framing_bounds`
    over ``bounds_frames`` (default ``[frame]``; pass every frame of a sequence for a camera that
    does not move). ``width`` in pixels; height from the camera aperture.
    """
    from pxr import UsdGeom

    from usd_gs.usd.stage import prim_path

    label = stage_label(stage)
    if path is not None:
        p = prim_path(path)
        prim = stage.GetPrimAtPath(p)
        if not prim or not prim.IsValid():
            found = ", ".join(str(c.GetPath()) for c in camera_prims(stage)[:10]) or "none"
            raise UserError(f"{label}: --camera {p}: no prim at this path (cameras in the stage: {found})")
        if not prim.IsA(UsdGeom.Camera):
            raise UserError(f"{label}: --camera {p}: prim is a '{prim.GetTypeName() or 'typeless'}' prim, "
                            "not a UsdGeom.Camera")
        return Camera.from_usd(prim, _tc(frame).GetValue() if frame is not None else None, width=width)
    cams = camera_prims(stage)
    if cams:
        return Camera.from_usd(cams[0], _tc(frame).GetValue() if frame is not None else None, width=width)
    bounds = gaussian_framing_bounds(stage, [frame] if bounds_frames is None else bounds_frames)
    if bounds is None:
        raise UserError(f"{label}: no camera prim and no visible Gaussian prims to frame; pass --camera")
    up = str(UsdGeom.GetStageUpAxis(stage))
    return framing_camera(bounds[0], bounds[1], width=width, up_axis=up)


# ----------------------------------------------------------------------------- rendering
def render_stage_frame(stage, frame, camera: Camera | str | None = None, width: int = DEFAULT_WIDTH,
                       background=(0.0, 0.0, 0.0)) -> RenderResult:
    """Render the drawn Gaussians of ``stage`` at ``frame`` (module docstring).

    ``camera``: a :class:`Camera`, a camera prim path, or None (:func:`resolve_camera`'s
    default); ``width`` only matters when the camera is resolved here. ``background``: RGB
    added with the remaining transmittance. A frame with no drawn Gaussians gives the
    background with alpha 0.
    """
    t0 = _time.perf_counter()
    if not isinstance(camera, Camera):
        camera = resolve_camera(stage, camera, frame, width)
    gs, prims = read_stage_gaussians(stage, frame)
    t1 = _time.perf_counter()
    bg = np.asarray(background, np.float32).reshape(3)
    h, w = camera.height, camera.width
    if gs.count == 0:
        rgb = np.broadcast_to(bg, (h, w, 3)).astype(np.float32)
        res = _render.RenderResult(rgb, np.zeros((h, w), np.float32), np.zeros((h, w), np.float32))
    else:
        res = _render.render(gs, camera, background=bg)
    t2 = _time.perf_counter()
    return RenderResult(res.rgb, res.alpha, res.depth, frame=float(_tc(frame).GetValue()), camera=camera,
                        count=gs.count, prims=prims, read_s=t1 - t0, render_s=t2 - t1)


# ----------------------------------------------------------------------------- comparison
def input_stage_path(stage) -> str:
    """The absolute path of the first sublayer of ``stage``'s root layer (for a stage written
    by ``usdgs process``: its input), passing over the stitched output's own topology layer
    (``<stem>.topology.usdc`` of a chunked run: ``usd_gs.farm.clips``). ``UserError`` when there
    is none."""
    layer = stage.GetRootLayer()
    subs = list(layer.subLayerPaths)
    if layer.realPath:
        own = topology_layer_path(layer.realPath).name
        subs = [s for s in subs if os.path.basename(s) != own] or subs
    if not subs:
        raise UserError(f"{stage_label(stage)}: --compare needs a processed stage (the output of 'usdgs process', "
                        "whose first sublayer is its input), but this stage has no sublayers")
    sub = subs[0]
    path = layer.ComputeAbsolutePath(sub) if not layer.anonymous else sub
    if not os.path.exists(path):
        raise UserError(f"{stage_label(stage)}: first sublayer '{sub}' ({path}) does not exist")
    return path


def input_stage(stage):
    """The first sublayer of ``stage`` opened as a stage of its own (see :func:`input_stage_path`)."""
    from usd_gs.usd.stage import open_stage

    return open_stage(input_stage_path(stage))


def side_by_side(left: np.ndarray, right: np.ndarray, gap: int = 4, fill=1.0) -> np.ndarray:
    """``[left | gap columns of fill | right]`` for two (H,W,...) images of equal shape."""
    left = np.asarray(left)
    right = np.asarray(right)
    if left.shape != right.shape:
        raise ValueError(f"side_by_side: image shapes differ: {left.shape} vs {right.shape}")
    h, w = left.shape[:2]
    out = np.empty((h, 2 * w + gap) + left.shape[2:], np.result_type(left, right))
    out[:, :w] = left
    out[:, w:w + gap] = fill
    out[:, w + gap:] = right
    return out
