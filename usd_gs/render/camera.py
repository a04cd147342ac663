"""Pinhole cameras for rendering splats: look-at, USD cameras, cube-map faces.

Conventions:

- A camera has a world-space ``position`` and ``rotation`` (3x3, float64, world-from-camera,
  column-vector convention ``world = rotation @ local + position``). As for USD cameras
  (``UsdGeom.Camera``) the camera looks down its local **-Z** axis with **+Y up** and
  **+X right**. ``rotation`` is orthogonal; it is a proper rotation for physical cameras
  and has determinant -1 for the cube-map faces (an OpenGL cube-map face is the mirror image
  of what a pinhole camera with the same forward axis sees; see :func:`cube_face_cameras`).
- Intrinsics in pixels: ``fx``, ``fy`` (focal lengths), ``cx``, ``cy`` (principal point).
  The image spans ``[0, width] x [0, height]`` with row 0 at the top; pixel (row i,
  column j) has its centre at ``(j + 0.5, i + 0.5)``. A camera-space point (X, Y, Z) with
  depth ``z = -Z > 0`` lands at ``u = cx + fx X / z``, ``v = cy - fy Y / z``.
- ``near`` / ``far``: view-depth range (scene units); splats with centre depth
  ``<= near`` or ``> far`` are not drawn.

Cube faces: OpenGL cube-map order ``+X, -X, +Y, -Y, +Z, -Z`` and orientation, the same as
``numba_kernels/cubemap_dirs.py``: pixel (f, i, j) of a face of ``size`` looks along
``forward_f + u right_f + v down_f`` with ``u = 2 (j + 0.5) / size - 1``,
``v = 2 (i + 0.5) / size - 1`` (OpenGL spec table with s = u, t = v: +X (1, -v, -u),
-X (-1, -v, u), +Y (u, 1, v), -Y (u, -1, -v), +Z (u, -v, 1), -Z (-u, -v, -1)).

This module imports numpy only (and the numpy-only ``numba_kernels.cubemap_dirs``; ``pxr`` is
imported inside :meth:`Camera.from_usd`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from numba_kernels.cubemap_dirs import FACE_FRAMES, FACE_NAMES
from usd_gs.errors import UserError
from usd_gs.usd.frames import as_time

# OpenGL cube-map faces, shared with numba_kernels/cubemap_dirs.py (a numpy-only module):
# names +X, -X, +Y, -Y, +Z, -Z and (6, 3, 3) float64 (forward, right, down) per face.
CUBE_FACE_NAMES = FACE_NAMES
CUBE_FACE_FRAMES = FACE_FRAMES

# Camera-space to view-space (x right, y down, z depth): diag(1, -1, -1).
_FLIP = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class Camera:
    """Pinhole camera; see the module docstring for conventions and units."""

    position: np.ndarray
    rotation: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float = 0.01
    far: float = 1.0e6

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, np.float64).reshape(3)
        rot = np.asarray(self.rotation, np.float64).reshape(3, 3)
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy", "near", "far"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(rot))):
            raise UserError("camera: position and rotation must be finite")
        if np.max(np.abs(rot.T @ rot - np.eye(3))) > 1e-6:
            raise UserError("camera: rotation is not orthogonal (|R^T R - I| > 1e-6)")
        if self.width < 1 or self.height < 1:
            raise UserError(f"camera: image size must be >= 1x1, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and np.isfinite(self.cx) and np.isfinite(self.cy)):
            raise UserError(f"camera: focal lengths must be > 0 (fx={self.fx}, fy={self.fy})")
        if not (0 < self.near < self.far):
            raise UserError(f"camera: need 0 < near < far, got near={self.near}, far={self.far}")

    # ------------------------------------------------------------ construction
    @classmethod
    def look_at(cls, eye, target, up=(0.0, 1.0, 0.0), width: int = 640, height: int = 480,
                fov_y_deg: float = 60.0, near: float = 0.01, far: float = 1.0e6) -> Camera:
        """Camera at ``eye`` looking at ``target`` with ``up`` roughly up in the image.

        ``fov_y_deg`` is the full vertical field of view; pixels are square and the principal
        point is the image centre.
        """
        eye = np.asarray(eye, np.float64)
        fwd = np.asarray(target, np.float64) - eye
        if not np.linalg.norm(fwd) > 0:
            raise UserError("camera look_at: target equals eye")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(up, np.float64))
        if not np.linalg.norm(right) > 1e-12:
            raise UserError("camera look_at: up is parallel to the view direction")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, fwd)
        rot = np.stack([right, true_up, -fwd], axis=1)
        f = 0.5 * height / np.tan(0.5 * np.radians(fov_y_deg))
        return cls(eye, rot, f, f, 0.5 * width, 0.5 * height, width, height, near, far)

    @classmethod
    def from_usd(cls, camera_prim, time=None, width: int = 960, height: int | None = None) -> Camera:
        """Camera from a ``UsdGeom.Camera`` (or its prim) at time code ``time`` (default: Default).

        World transform from ``ComputeLocalToWorldTransform`` (scale and shear removed),
        ``fx = fy = focalLength * width / horizontalAperture`` (square pixels, horizontal
        aperture fit), principal point shifted by the aperture offsets, ``near``/``far``
        from ``clippingRange``. ``height`` defaults to ``width * vAperture / hAperture``.
        Orthographic cameras raise ``UserError``.
        """
        from pxr import Gf, UsdGeom

        cam = UsdGeom.Camera(camera_prim)
        prim = cam.GetPrim()
        if not prim or not prim.IsA(UsdGeom.Camera):
            raise UserError(f"{camera_prim}: not a UsdGeom.Camera prim")
        tc = as_time(time)
        gcam = cam.GetCamera(tc)
        path = str(prim.GetPath())
        if gcam.projection != Gf.Camera.Perspective:
            raise UserError(f"{path}: 'projection' is orthographic; only perspective cameras are supported")
        f = float(gcam.focalLength)
        ha = float(gcam.horizontalAperture)
        va = float(gcam.verticalAperture)
        if not (f > 0 and ha > 0 and va > 0):
            raise UserError(f"{path}: focalLength and apertures must be > 0 (focalLength={f}, "
                            f"horizontalAperture={ha}, verticalAperture={va})")
        width = int(width)
        if height is None:
            height = max(1, int(round(width * va / ha)))
        m = np.array(gcam.transform, dtype=np.float64)  # row-vector convention: p' = [p, 1] @ m
        lin = m[:3, :3].T
        u, _, vt = np.linalg.svd(lin)
        rot = u @ vt  # nearest orthogonal matrix: drops scale / shear
        if np.linalg.det(rot) < 0:
            raise UserError(f"{path}: camera transform is mirrored (negative determinant)")
        fpx = f * width / ha
        cx = 0.5 * width - float(gcam.horizontalApertureOffset) * fpx / f
        cy = 0.5 * height + float(gcam.verticalApertureOffset) * fpx / f
        clip = gcam.clippingRange
        near, far = float(clip.min), float(clip.max)
        return cls(m[3, :3], rot, fpx, fpx, cx, cy, width, int(height), near, far)

    # ------------------------------------------------------------ derived data
    def view_matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """(view_rot (3,3), view_t (3,)) mapping world points to view coordinates
        (x right, y down, z = depth > 0 in front): ``q = view_rot @ p + view_t``."""
        vr = _FLIP @ self.rotation.T
        return vr, -vr @ self.position

    def intrinsics(self) -> np.ndarray:
        """(4,) float64 ``fx, fy, cx, cy`` in pixels."""
        return np.array([self.fx, self.fy, self.cx, self.cy])

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """World points (N,3) -> pixel coordinates (N,2) (u, v) and view depth (N,)."""
        vr, vt = self.view_matrix()
        q = np.asarray(points, np.float64).reshape(-1, 3) @ vr.T + vt
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * q[:, 0] / q[:, 2] + self.cx, self.fy * q[:, 1] / q[:, 2] + self.cy], axis=1)
        return uv, q[:, 2]

    def pixel_directions(self) -> np.ndarray:
        """(H, W, 3) float64 unit world-space directions through the pixel centres."""
        jj = (np.arange(self.width) + 0.5 - self.cx) / self.fx
        ii = (np.arange(self.height) + 0.5 - self.cy) / self.fy
        y, x = np.meshgrid(ii, jj, indexing="ij")
        local = np.stack([x, -y, -np.ones_like(x)], axis=-1)  # camera frame: -Z forward, +Y up
        d = local @ self.rotation.T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def cube_face_cameras(position, size: int, near: float = 0.01, far: float = 1.0e6) -> list[Camera]:
    """Six 90-degree cameras at ``position`` for the OpenGL cube-map faces +X, -X, +Y, -Y, +Z, -Z.

    Each is ``size x size`` with ``fx = fy = cx = cy = size / 2``; its rotation has columns
    (right, -down, -forward) of :data:`CUBE_FACE_FRAMES` (determinant -1: mirrored, as the
    cube-map convention requires), so pixel (i, j) of face f looks along
    ``forward + u right + v down`` (module docstring).
    """
    size = int(size)
    if size < 1:
        raise UserError(f"cube face size must be >= 1, got {size}")
    h = 0.5 * size
    cams = []
    for fwd, right, down in CUBE_FACE_FRAMES:
        rot = np.stack([right, -down, -fwd], axis=1)
        cams.append(Camera(position, rot, h, h, h, h, size, size, near, far))
    return cams
