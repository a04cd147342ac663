"""Brute-force float64 reference for :mod:`numba_kernels.rasterize` (tests and benchmarks).

Same image formation as the fast rasteriser (see its module docstring): same EWA
projection with the guard-band clamp and dilation, same 3-sigma support, alpha clamp and
thresholds, same order (``float32`` view depth, ties by lower Gaussian index) and early
termination. What it does NOT do: tiles, bounding boxes, frustum culling, compaction.
Every pixel is composited over every Gaussian in front of the near plane (and not past the
far plane), in float64, vectorised over (pixel, Gaussian) with numpy; the sequential
front-to-back loop is rewritten exactly with a cumulative product (transmittance only
decreases, so "stopped before k" is ``prod_{j<=k}(1 - alpha_j) < 1e-4``).

Memory is O(pixels x Gaussians) per chunk of pixel rows: meant for a few hundred Gaussians
and small images.
"""

from __future__ import annotations

import numpy as np

from .sh_real import threedgs_color

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
SUPPORT_Q = 9.0


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (N,3) by unit quaternions q (N,4) (w,x,y,z): v + 2w (u x v) + 2 u x (u x v)."""
    w = q[:, :1]
    u = q[:, 1:]
    uv = np.cross(u, v)
    return v + 2.0 * w * uv + 2.0 * np.cross(u, uv)


def covariances_3d(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(N,3,3) float64 ``R diag(s^2) R^T``; quaternions (w,x,y,z) are normalised (zero -> identity)."""
    q = np.asarray(quats, np.float64)
    n = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    s = np.abs(np.asarray(scales, np.float64))
    # columns of R are the rotated basis vectors
    cols = [_rotate(q, np.broadcast_to(e, (q.shape[0], 3))) for e in np.eye(3)]
    r = np.stack(cols, axis=2)
    return np.einsum("nij,nj,nkj->nik", r, s * s, r)


def project(positions, quats, scales, view_rot, view_t, intr, width, height, dilation=0.3, guard=1.3):
    """EWA projection of every Gaussian (no culling).

    Returns mean2d (N,2) pixels, cov2d (N,2,2) incl. dilation, z (N,) view depth.
    """
    p = np.asarray(positions, np.float64) @ np.asarray(view_rot, np.float64).T + np.asarray(view_t, np.float64)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fx, fy, cx, cy = (float(v) for v in intr)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.stack([fx * x / z + cx, fy * y / z + cy], axis=1)
        lo_x, hi_x = (0.0 - cx) / fx, (width - cx) / fx
        lo_y, hi_y = (0.0 - cy) / fy, (height - cy) / fy
        cxm, hxm = 0.5 * (lo_x + hi_x), 0.5 * (hi_x - lo_x)
        cym, hym = 0.5 * (lo_y + hi_y), 0.5 * (hi_y - lo_y)
        tx = np.clip(x / z, cxm - guard * hxm, cxm + guard * hxm)
        ty = np.clip(y / z, cym - guard * hym, cym + guard * hym)
        jac = np.zeros((len(z), 2, 3))
        jac[:, 0, 0] = fx / z
        jac[:, 0, 2] = -fx * tx / z
        jac[:, 1, 1] = fy / z
        jac[:, 1, 2] = -fy * ty / z
    m = jac @ np.asarray(view_rot, np.float64)
    cov = m @ covariances_3d(quats, scales) @ np.transpose(m, (0, 2, 1))
    cov = cov + dilation * np.eye(2)
    return mean, cov, z


def rasterize(positions, quats, scales, opacities, sh, view_rot, view_t, intr, nearfar, cam_pos,
              width, height, include=None, dilation=0.3, guard=1.3, rows_per_chunk=16, antialiased=False):
    """Brute-force render of one camera (same arguments as ``rasterize.rasterize`` for K=1).

    Returns (color (H,W,3) premultiplied, transmittance (H,W), depth_sum (H,W)), float64.
    """
    view_rot = np.asarray(view_rot, np.float64).reshape(3, 3)
    view_t = np.asarray(view_t, np.float64).reshape(3)
    intr = np.asarray(intr, np.float64).reshape(4)
    near, far = (float(v) for v in np.asarray(nearfar).reshape(2))
    cam_pos = np.asarray(cam_pos, np.float64).reshape(3)
    n = np.asarray(positions).shape[0]
    mean, cov, z = project(positions, quats, scales, view_rot, view_t, intr, width, height, dilation, guard)
    keep = (z > near) & (z <= far)
    if include is not None:
        keep &= np.asarray(include, bool)
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    keep &= det > 0
    idx = np.flatnonzero(keep)
    # order: float32 depth, then Gaussian index
    idx = idx[np.lexsort((idx, z[idx].astype(np.float32)))]
    mean, cov, z = mean[idx], cov[idx], z[idx]
    conic = np.linalg.inv(cov)
    op = np.clip(np.asarray(opacities, np.float64)[idx], 0.0, 1.0)
    if antialiased:  # keep each splat's integral: opacity * sqrt(det(cov - dilation I) / det(cov))
        det0 = (cov[:, 0, 0] - dilation) * (cov[:, 1, 1] - dilation) - cov[:, 0, 1] ** 2
        op = op * np.sqrt(np.maximum(det0, 0.0) / (cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2))
    dirs = np.asarray(positions, np.float64)[idx] - cam_pos
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-300)
    col = np.maximum(0.0, threedgs_color(np.asarray(sh)[idx], dirs)) if len(idx) else np.zeros((0, 3))

    color = np.zeros((height, width, 3))
    trans = np.ones((height, width))
    dsum = np.zeros((height, width))
    if len(idx) == 0 or n == 0:
        return color, trans, dsum
    jj = np.arange(width) + 0.5
    for r0 in range(0, height, rows_per_chunk):
        r1 = min(height, r0 + rows_per_chunk)
        ii = np.arange(r0, r1) + 0.5
        py, px = np.meshgrid(ii, jj, indexing="ij")
        d = np.stack([px.ravel(), py.ravel()], axis=1)[:, None, :] - mean[None, :, :]  # (P, G, 2)
        q = np.einsum("pgi,gij,pgj->pg", d, conic, d)
        alpha = np.minimum(ALPHA_MAX, op[None, :] * np.exp(-0.5 * q))
        alpha = np.where((q <= SUPPORT_Q) & (alpha >= ALPHA_MIN), alpha, 0.0)
        test_t = np.cumprod(1.0 - alpha, axis=1)
        blended = test_t >= T_MIN
        t_before = np.concatenate([np.ones((d.shape[0], 1)), test_t[:, :-1]], axis=1)
        w = np.where(blended, alpha * t_before, 0.0)
        t_final = np.where(blended, test_t, np.inf).min(axis=1)
        t_final = np.where(np.isfinite(t_final), t_final, 1.0)
        sl = (slice(r0, r1), slice(None))
        color[sl] = (w @ col).reshape(r1 - r0, width, 3)
        trans[sl] = t_final.reshape(r1 - r0, width)
        dsum[sl] = (w @ z).reshape(r1 - r0, width)
    return color, trans, dsum
