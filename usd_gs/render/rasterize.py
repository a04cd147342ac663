"""Render a :class:`~usd_gs.gaussians.GaussianSet` with the CPU splat rasteriser, and write PNGs.

Thin wrapper over :func:`numba_kernels.rasterize.rasterize` (image formation documented
there: standard 3DGS EWA splatting, colour ``max(0, 0.5 + SH(dir))`` in the 3DGS basis,
front-to-back blending with early termination). Cameras follow ``usd_gs/render/camera.py``
(USD convention: looking down -Z, +Y up). numba is imported lazily inside the render
functions, so importing this module stays cheap.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.render.camera import Camera, cube_face_cameras

DEFAULT_DILATION = 0.3  # px^2 added to the 2D covariance diagonal (3DGS low-pass filter)


@dataclass
class RenderResult:
    """rgb (H,W,3) float32 linear colour composited over the background; alpha (H,W) float32
    coverage ``1 - T``; depth (H,W) float32 expected view depth ``sum(z w) / sum(w)`` of the
    blended splats (scene units along the view axis), 0 where nothing was blended."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


def _check_mask(gaussians: GaussianSet, mask) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.dtype != np.bool_ or m.shape != (gaussians.count,):
        raise UserError(f"{gaussians.label}: render mask must be a boolean array of shape ({gaussians.count},), "
                        f"got {m.dtype} {m.shape}")
    return np.ascontiguousarray(m)


def render_batch(gaussians: GaussianSet, cams: list[Camera], background=(0.0, 0.0, 0.0), mask=None,
                 dilation: float = DEFAULT_DILATION, antialiased: bool = False, order=None, blocks=None):
    """Render up to 63 cameras of equal image size in one pass (one cull/projection sweep).
    ``antialiased``: opacity-compensated dilation (``numba_kernels.rasterize.rasterize``), for
    renders whose radiance is measured (probes). ``order``: instead of ``mask``, the increasing
    indices of the Gaussians to draw (the same image; no pass over the others). ``blocks``: None,
    or bounds of row blocks that let the cull skip whole blocks per camera (the same image;
    ``numba_kernels.rasterize.rasterize``, e.g. ``usd_gs.point_blocks.PointBlocks.cull_bounds``).

    Returns (rgb (K,H,W,3), alpha (K,H,W), depth (K,H,W)) float32, as :func:`render` per camera.
    """
    from numba_kernels.rasterize import rasterize

    if not cams:
        raise UserError("render_batch: no cameras given")
    w, h = cams[0].width, cams[0].height
    if any(c.width != w or c.height != h for c in cams):
        raise UserError("render_batch: all cameras of one call must have the same image size")
    vm = [c.view_matrix() for c in cams]
    color, trans, depth, _ = rasterize(
        gaussians.positions, gaussians.orientations, gaussians.scales, gaussians.opacities, gaussians.sh,
        np.stack([v[0] for v in vm]), np.stack([v[1] for v in vm]), np.stack([c.intrinsics() for c in cams]),
        np.array([[c.near, c.far] for c in cams]), np.stack([c.position for c in cams]), w, h,
        include=_check_mask(gaussians, mask), dilation=dilation, antialiased=antialiased, order=order, blocks=blocks)
    bg = np.asarray(background, np.float32).reshape(3)
    rgb = color + trans[..., None] * bg
    alpha = (1.0 - trans).astype(np.float32)
    return rgb.astype(np.float32), alpha, depth


def render(gaussians: GaussianSet, camera: Camera, background=(0.0, 0.0, 0.0), mask=None,
           dilation: float = DEFAULT_DILATION) -> RenderResult:
    """Render ``gaussians`` (world space) seen by ``camera``.

    background: RGB added with the remaining transmittance. mask: optional (N,) bool, the
    Gaussians to draw (e.g. ``~avatar_mask`` for a probe). Returns :class:`RenderResult`.
    """
    rgb, alpha, depth = render_batch(gaussians, [camera], background, mask, dilation)
    return RenderResult(rgb[0], alpha[0], depth[0])


def render_cube_faces(gaussians: GaussianSet, position, size: int, mask=None, background=(0.0, 0.0, 0.0),
                      near: float = 0.01, dilation: float = DEFAULT_DILATION, antialiased: bool = False,
                      order=None, blocks=None):
    """Render the six OpenGL cube-map faces (+X, -X, +Y, -Y, +Z, -Z) seen from ``position``.

    Pixel (f, i, j) looks along ``numba_kernels.cubemap_dirs.cube_face_directions(size)[f, i, j]``.
    Returns (rgb (6,size,size,3), alpha (6,size,size), depth (6,size,size)) float32; depth is
    the expected view depth along each face's axis (not the distance along the ray). ``order``,
    ``blocks``: as for :func:`render_batch`.
    """
    return render_cubes(gaussians, [position], size, mask, background, near, dilation, antialiased, order, blocks)[0]


#: cube renders drawn in one rasteriser pass by :func:`render_cubes` (six faces each: at most 63 cameras)
CUBES_PER_PASS = 10


def render_cubes(gaussians: GaussianSet, positions, size: int, mask=None, background=(0.0, 0.0, 0.0),
                 near: float = 0.01, dilation: float = DEFAULT_DILATION, antialiased: bool = False,
                 order=None, blocks=None) -> list:
    """:func:`render_cube_faces` of the same Gaussians seen from each of ``positions`` (P, 3), drawn
    up to :data:`CUBES_PER_PASS` at a time in one pass (one cull and projection sweep over the
    Gaussians for all their faces): each cube's ``(rgb, alpha, depth)`` bit for bit as
    :func:`render_cube_faces` gives it alone (cameras are independent in the rasteriser)."""
    positions = [np.asarray(p, np.float64).reshape(3) for p in positions]
    out = []
    for i in range(0, len(positions), CUBES_PER_PASS):
        part = positions[i:i + CUBES_PER_PASS]
        cams = [cam for p in part for cam in cube_face_cameras(p, size, near=near)]
        rgb, alpha, depth = render_batch(gaussians, cams, background, mask, dilation, antialiased, order, blocks)
        out.extend((rgb[6 * k:6 * k + 6], alpha[6 * k:6 * k + 6], depth[6 * k:6 * k + 6]) for k in range(len(part)))
    return out


def to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear float RGB(A) in [0, 1] -> uint8 with the sRGB transfer curve (alpha stays linear)."""
    a = np.clip(np.nan_to_num(np.asarray(rgb, np.float64)), 0.0, 1.0)
    c = a[..., :3]
    c = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)
    out = np.concatenate([c, a[..., 3:]], axis=-1) if a.shape[-1] == 4 else c
    return np.round(out * 255.0).astype(np.uint8)


def write_png(path, image: np.ndarray, srgb: bool = False) -> Path:
    """Write an 8-bit PNG with Pillow, atomically (``usd_gs.io.atomic``).

    image: (H,W) grey, (H,W,3) RGB or (H,W,4) RGBA. Float arrays are clipped to [0, 1] and
    scaled by 255 as they are (the default: 3DGS colours are already display-referred, the
    captures were trained on sRGB photos), or, with ``srgb=True``, treated as linear values
    and encoded with the sRGB transfer curve (alpha stays linear). uint8 arrays are written as
    they are. Returns the path.
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4):
        raise ValueError(f"write_png: expected (H,W), (H,W,3) or (H,W,4), got {img.shape}")
    if img.dtype != np.uint8:
        if srgb and img.shape[2] >= 3:
            img = to_srgb8(img)
        else:
            img = np.round(np.clip(np.nan_to_num(img.astype(np.float64)), 0, 1) * 255).astype(np.uint8)
    from PIL import Image

    from usd_gs.io.atomic import atomic_output

    mode = {1: "L", 3: "RGB", 4: "RGBA"}[img.shape[2]]
    path = Path(path)
    with atomic_output(path) as tmp:
        Image.fromarray(img[..., 0] if mode == "L" else img, mode).save(tmp, format="PNG")
    return path


def cube_faces_cross(faces: np.ndarray) -> np.ndarray:
    """Lay six (6,S,S,C) OpenGL cube faces out as a horizontal cross (3S, 4S, C) for previews.

    Each face is flipped left-right (cube-map faces are mirror images), so the cross shows what
    a viewer at the centre sees, +Y up: rows [ . +Y . . ], [ +X +Z -X -Z ], [ . -Y . . ]
    (with Y up, turning right from +Z faces -X).
    """
    f = np.asarray(faces)
    s = f.shape[1]
    out = np.zeros((3 * s, 4 * s) + f.shape[3:], f.dtype)
    place = {2: (0, 1), 0: (1, 0), 4: (1, 1), 1: (1, 2), 5: (1, 3), 3: (2, 1)}
    for face, (r, c) in place.items():
        out[r * s:(r + 1) * s, c * s:(c + 1) * s] = f[face][:, ::-1]
    return out
