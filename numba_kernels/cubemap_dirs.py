"""Cube-map texel directions and exact texel solid angles (OpenGL cube-map convention).

Faces, in this order (index f): ``+X, -X, +Y, -Y, +Z, -Z``. Images are (size, size)
arrays indexed ``[i, j]`` = [row, column], row 0 first in memory. Pixel-centre face
coordinates: ``u = 2 (j + 0.5) / size - 1`` (columns), ``v = 2 (i + 0.5) / size - 1``
(rows), both in (-1, 1). The (unnormalised) direction of texel (i, j) on each face is
(OpenGL spec, table "selection of cube map images", with s = u, t = v):

====  =================
face  direction
====  =================
+X    ( 1, -v, -u)
-X    (-1, -v,  u)
+Y    ( u,  1,  v)
-Y    ( u, -1, -v)
+Z    ( u, -v,  1)
-Z    (-u, -v, -1)
====  =================

i.e. ``dir = forward + u * right + v * down`` with the per-face ``(forward, right, down)``
frames of :data:`FACE_FRAMES`. A renderer projects a world direction ``d`` onto face f by
``u = <d, right> / <d, forward>``, ``v = <d, down> / <d, forward>`` (valid when
``<d, forward> > 0`` and |u|, |v| <= 1). Note: as in OpenGL, ``right x down = -forward``,
so each face image is the mirror image of what a standard pinhole camera with the same
forward axis would see; use these frames (not a look-at camera) to render faces.

All directions are in the world frame the caller uses (Y-up or Z-up does not matter here).
"""

from __future__ import annotations

import numpy as np

FACE_NAMES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")

# FACE_FRAMES[f] = (forward, right, down), each a unit vector.
FACE_FRAMES = np.array(
    [
        [[1, 0, 0], [0, 0, -1], [0, -1, 0]],
        [[-1, 0, 0], [0, 0, 1], [0, -1, 0]],
        [[0, 1, 0], [1, 0, 0], [0, 0, 1]],
        [[0, -1, 0], [1, 0, 0], [0, 0, -1]],
        [[0, 0, 1], [1, 0, 0], [0, -1, 0]],
        [[0, 0, -1], [-1, 0, 0], [0, -1, 0]],
    ],
    dtype=np.float64,
)


def pixel_centres(size: int) -> np.ndarray:
    """(size,) float64 face coordinates of pixel centres, ``2 (j + 0.5) / size - 1``."""
    size = int(size)
    if size < 1:
        raise ValueError(f"cube face size must be >= 1, got {size}")
    return (2.0 * (np.arange(size, dtype=np.float64) + 0.5)) / size - 1.0


def cube_face_directions(size: int) -> np.ndarray:
    """Unit view directions of every texel centre: (6, size, size, 3) float64.

    ``out[f, i, j]`` is the normalised direction of face f, row i, column j (see module doc).
    """
    c = pixel_centres(size)
    v, u = np.meshgrid(c, c, indexing="ij")  # v varies along rows (i), u along columns (j)
    fwd = FACE_FRAMES[:, 0][:, None, None, :]
    right = FACE_FRAMES[:, 1][:, None, None, :]
    down = FACE_FRAMES[:, 2][:, None, None, :]
    d = fwd + u[None, :, :, None] * right + v[None, :, :, None] * down
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _area_element(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solid angle of the face rectangle [0, x] x [0, y] on the plane at distance 1 (signed)."""
    return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))


def cube_face_solid_angles(size: int) -> np.ndarray:
    """Exact solid angle (steradians) of every texel: (6, size, size) float64.

    Each texel [x0, x1] x [y0, y1] subtends ``A(x1,y1) - A(x0,y1) - A(x1,y0) + A(x0,y0)`` with
    ``A(x, y) = atan2(x y, sqrt(x^2 + y^2 + 1))``; the six faces sum to 4 pi (to ~1e-14).
    """
    size = int(size)
    edges = np.linspace(-1.0, 1.0, size + 1, dtype=np.float64)
    y0, x0 = np.meshgrid(edges[:-1], edges[:-1], indexing="ij")
    y1, x1 = np.meshgrid(edges[1:], edges[1:], indexing="ij")
    w = _area_element(x1, y1) - _area_element(x0, y1) - _area_element(x1, y0) + _area_element(x0, y0)
    return np.broadcast_to(w, (6, size, size)).copy()


def direction_to_face_uv(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse mapping: unit (or any non-zero) directions (..., 3) -> (face, u, v).

    face: int64 in 0..5 (major axis, ties broken toward X then Y), u, v float64 in [-1, 1]
    with the conventions of the module docstring (pixel column ``j = (u + 1) size / 2 - 0.5``).
    """
    d = np.asarray(dirs, dtype=np.float64)
    ax = np.abs(d)
    major = np.argmax(ax, axis=-1)  # 0: x, 1: y, 2: z (first max wins)
    comp = np.take_along_axis(d, major[..., None], axis=-1)[..., 0]
    face = 2 * major + (comp < 0)
    frames = FACE_FRAMES[face]  # (..., 3, 3)
    fwd_dot = np.einsum("...k,...k->...", d, frames[..., 0, :])
    u = np.einsum("...k,...k->...", d, frames[..., 1, :]) / fwd_dot
    v = np.einsum("...k,...k->...", d, frames[..., 2, :]) / fwd_dot
    return face.astype(np.int64), np.clip(u, -1.0, 1.0), np.clip(v, -1.0, 1.0)


def sample_cube_faces(faces: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Bilinear samples (..., C) float64 of cube ``faces`` (6, S, S, C) at directions ``dirs``
    (..., 3): within the face each direction falls on (:func:`direction_to_face_uv`), texel
    centres at ``j = (u + 1) S / 2 - 1/2``, clamped to the face's edge texels (within half a texel
    of a seam the nearer face's edge stands for its neighbour)."""
    size = faces.shape[1]
    f, u, v = direction_to_face_uv(dirs)
    x = np.clip((u + 1.0) * 0.5 * size - 0.5, 0.0, size - 1.0)
    y = np.clip((v + 1.0) * 0.5 * size - 0.5, 0.0, size - 1.0)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    x1 = np.minimum(x0 + 1, size - 1)
    y1 = np.minimum(y0 + 1, size - 1)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    im = np.asarray(faces).astype(np.float64, copy=False)
    top = im[f, y0, x0] * (1.0 - fx) + im[f, y0, x1] * fx
    bot = im[f, y1, x0] * (1.0 - fx) + im[f, y1, x1] * fx
    return top * (1.0 - fy) + bot * fy
