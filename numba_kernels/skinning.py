"""Linear blend skinning of 3D Gaussians (positions, orientations, scales, SH), numba kernel.

Contract (every array C-contiguous; ``N`` Gaussians, ``K`` influences each, ``J`` joints):

- ``rest_pos`` (N, 3) float32 bind-pose centres; ``rest_quat`` (N, 4) float32 (w, x, y, z)
  (need not be unit: normalised); ``rest_scales`` (N, 3) float32 linear sigmas; ``sh`` (N, C, 3)
  float32 3DGS-basis coefficients (C = (d+1)^2, d in 0..3).
- ``joint_idx`` (N, K) int32 in [0, J); ``weights`` (N, K) float32 (used as given, not
  renormalised).
- ``skin`` (J, 4, 4) float64 skinning matrices in the COLUMN-vector convention (``p' = M @ [p, 1]``;
  the transpose of UsdSkel's ``Gf.Matrix4d``), the geomBindTransform already folded in.
- ``dirs`` (M, 3) float64 unit directions and ``pinv`` (C, M) float64: for each band l >= 1 the rows
  ``l^2 .. (l+1)^2 - 1`` of ``pinv`` hold the pseudo-inverse of the band-l basis evaluated at
  ``dirs`` (``numpy.linalg.pinv(Y_l(dirs))``); see ``usd_gs.usd.skel.sh_rotation_tables``.

Per Gaussian: ``A = sum_k w_k skin[j_k]`` (the blended affine). Position ``A[:3, :3] @ p + A[:3, 3]``
(float64 math). Rotation ``R`` = the orthogonal polar factor of ``A[:3, :3]`` (Newton iteration
with determinant scaling, converged to 1e-12 relative), uniform scale ``s = det(A33)^(1/3)``.
When ``det(A33) <= 1e-12 * |A33|_F^3`` (degenerate or reflected blend) ``R`` and ``s`` come from
the matrix of the Gaussian's largest-weight influence instead (identity / 1 if that one is
degenerate too). Orientation ``quat(R) * q_rest`` (unit, w >= 0), scales ``s * rest_scales``,
SH band l: ``c' = pinv_l @ (Y_l(R^T dirs) @ c)``, exact per band (the new expansion at world
direction w equals the old one at ``R^T w``, as ``usd_gs.sh3dgs.rotate_coefficients``).
Band 0 (DC) is copied. Outputs are float32, finite for finite inputs.

Threads: :func:`skin_gaussians` runs the serial ``nogil`` range kernel through
``numba_kernels.thread_chunks.run_chunks`` (each range writes disjoint rows).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from numba_kernels.jit_options import threaded
from numba_kernels.thread_chunks import run_chunks

_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
       1.445305721320277, -0.5900435899266435)


@njit(cache=True, inline="always")
def _basis(x, y, z, out):
    """3DGS real SH basis bands 1..3 at (x, y, z) into out[1..15] (out[0] = 1, unused)."""
    out[0] = 1.0
    out[1] = -_C1 * y
    out[2] = _C1 * z
    out[3] = -_C1 * x
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    out[4] = _C2[0] * xy
    out[5] = _C2[1] * yz
    out[6] = _C2[2] * (2.0 * zz - xx - yy)
    out[7] = _C2[3] * xz
    out[8] = _C2[4] * (xx - yy)
    out[9] = _C3[0] * y * (3.0 * xx - yy)
    out[10] = _C3[1] * xy * z
    out[11] = _C3[2] * y * (4.0 * zz - xx - yy)
    out[12] = _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
    out[13] = _C3[4] * x * (4.0 * zz - xx - yy)
    out[14] = _C3[5] * z * (xx - yy)
    out[15] = _C3[6] * x * (xx - 3.0 * yy)


@njit(cache=True, inline="always")
def _det3(a):
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@njit(cache=True)
def _polar(a, r):
    """Orthogonal polar factor of the 3x3 ``a`` into ``r``; returns det(a), or 0.0 (r untouched)
    when ``a`` is degenerate or reflected (det <= 1e-12 |a|_F^3)."""
    fro = 0.0
    for i in range(3):
        for j in range(3):
            fro += a[i, j] * a[i, j]
    fro = math.sqrt(fro)
    det = _det3(a)
    if not (fro > 0.0) or not (det > 1e-12 * fro * fro * fro):
        return 0.0
    x = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            x[i, j] = a[i, j]
    for _ in range(40):
        d = _det3(x)
        g = abs(d) ** (-1.0 / 3.0)
        # cofactor(x) = det(x) * inv(x)^T
        c00 = x[1, 1] * x[2, 2] - x[1, 2] * x[2, 1]
        c01 = x[1, 2] * x[2, 0] - x[1, 0] * x[2, 2]
        c02 = x[1, 0] * x[2, 1] - x[1, 1] * x[2, 0]
        c10 = x[0, 2] * x[2, 1] - x[0, 1] * x[2, 2]
        c11 = x[0, 0] * x[2, 2] - x[0, 2] * x[2, 0]
        c12 = x[0, 1] * x[2, 0] - x[0, 0] * x[2, 1]
        c20 = x[0, 1] * x[1, 2] - x[0, 2] * x[1, 1]
        c21 = x[0, 2] * x[1, 0] - x[0, 0] * x[1, 2]
        c22 = x[0, 0] * x[1, 1] - x[0, 1] * x[1, 0]
        f = 1.0 / (g * d)
        ch = 0.0
        for i in range(3):
            for j in range(3):
                if i == 0:
                    c = c00 if j == 0 else (c01 if j == 1 else c02)
                elif i == 1:
                    c = c10 if j == 0 else (c11 if j == 1 else c12)
                else:
                    c = c20 if j == 0 else (c21 if j == 1 else c22)
                nv = 0.5 * (g * x[i, j] + f * c)
                ch += (nv - x[i, j]) * (nv - x[i, j])
                r[i, j] = nv
        for i in range(3):
            for j in range(3):
                x[i, j] = r[i, j]
        if ch < 1e-24:
            break
    return det


@njit(cache=True, inline="always")
def _mat_to_quat(r):
    """Unit (w, x, y, z) of a rotation matrix (Shepperd's method), w >= 0."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2.0
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2.0
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2.0
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


@njit(cache=True, **threaded())
def _skin_range(lo, hi, rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv,
                out_pos, out_quat, out_scales, out_sh, out_rot):
    n_inf = joint_idx.shape[1]
    n_coef = sh.shape[1]
    m = dirs.shape[0]
    a = np.empty((3, 4))
    a33 = np.empty((3, 3))
    r = np.empty((3, 3))
    ybuf = np.empty(16)
    bmat = np.empty((m, 16))
    tmp = np.empty((m, 3))
    for i in range(lo, hi):
        for u in range(3):
            for v in range(4):
                a[u, v] = 0.0
        best_w = -1.0
        best_j = 0
        for k in range(n_inf):
            j = joint_idx[i, k]
            w = float(weights[i, k])
            if w > best_w:
                best_w = w
                best_j = j
            if w != 0.0:
                for u in range(3):
                    for v in range(4):
                        a[u, v] += w * skin[j, u, v]
        px, py, pz = float(rest_pos[i, 0]), float(rest_pos[i, 1]), float(rest_pos[i, 2])
        for u in range(3):
            out_pos[i, u] = a[u, 0] * px + a[u, 1] * py + a[u, 2] * pz + a[u, 3]
            for v in range(3):
                a33[u, v] = a[u, v]
        det = _polar(a33, r)
        if det <= 0.0:
            for u in range(3):
                for v in range(3):
                    a33[u, v] = skin[best_j, u, v]
            det = _polar(a33, r)
            if det <= 0.0:
                det = 1.0
                for u in range(3):
                    for v in range(3):
                        r[u, v] = 1.0 if u == v else 0.0
        s = det ** (1.0 / 3.0)
        for u in range(3):
            out_scales[i, u] = s * rest_scales[i, u]
            for v in range(3):
                out_rot[i, u, v] = r[u, v]
        rw, rx, ry, rz = _mat_to_quat(r)
        qw, qx, qy, qz = float(rest_quat[i, 0]), float(rest_quat[i, 1]), float(rest_quat[i, 2]), float(rest_quat[i, 3])
        qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        if qn > 0.0 and math.isfinite(qn):
            qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
        else:
            qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
        ow = rw * qw - rx * qx - ry * qy - rz * qz
        ox = rw * qx + rx * qw + ry * qz - rz * qy
        oy = rw * qy - rx * qz + ry * qw + rz * qx
        oz = rw * qz + rx * qy - ry * qx + rz * qw
        on = math.sqrt(ow * ow + ox * ox + oy * oy + oz * oz)
        if ow < 0.0:
            on = -on
        out_quat[i, 0] = ow / on
        out_quat[i, 1] = ox / on
        out_quat[i, 2] = oy / on
        out_quat[i, 3] = oz / on
        for c in range(3):
            out_sh[i, 0, c] = sh[i, 0, c]
        if n_coef > 1:
            for d in range(m):
                # R^T w
                dx = r[0, 0] * dirs[d, 0] + r[1, 0] * dirs[d, 1] + r[2, 0] * dirs[d, 2]
                dy = r[0, 1] * dirs[d, 0] + r[1, 1] * dirs[d, 1] + r[2, 1] * dirs[d, 2]
                dz = r[0, 2] * dirs[d, 0] + r[1, 2] * dirs[d, 1] + r[2, 2] * dirs[d, 2]
                _basis(dx, dy, dz, ybuf)
                for e in range(16):
                    bmat[d, e] = ybuf[e]
            band = 1
            while (band + 1) * (band + 1) <= n_coef:
                b0 = band * band
                b1 = (band + 1) * (band + 1)
                for d in range(m):
                    for c in range(3):
                        acc = 0.0
                        for e in range(b0, b1):
                            acc += bmat[d, e] * sh[i, e, c]
                        tmp[d, c] = acc
                for e in range(b0, b1):
                    for c in range(3):
                        acc = 0.0
                        for d in range(m):
                            acc += pinv[e, d] * tmp[d, c]
                        out_sh[i, e, c] = acc
                band += 1


def skin_gaussians(rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv):
    """Skin N Gaussians (module docstring). Returns ``(positions (N, 3), orientations (N, 4) wxyz,
    scales (N, 3), sh (N, C, 3), rotations (N, 3, 3))``, all float32 (rotations: the per-Gaussian
    polar rotation ``R``, column-vector convention)."""
    n = rest_pos.shape[0]
    c = sh.shape[1]
    out_pos = np.empty((n, 3), np.float32)
    out_quat = np.empty((n, 4), np.float32)
    out_scales = np.empty((n, 3), np.float32)
    out_sh = np.empty((n, c, 3), np.float32)
    out_rot = np.empty((n, 3, 3), np.float32)
    run_chunks(_skin_range, n, rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv,
               out_pos, out_quat, out_scales, out_sh, out_rot, min_chunk=2048)
    return out_pos, out_quat, out_scales, out_sh, out_rot
