"""Linear blend skinning of 3D Gaussians (positions, orientations, scales, SH), numba kernel.

Contract (every array C-contiguous; ``N`` Gaussians, ``K`` influences each, ``J`` joints):

- ``rest_pos`` (N, 3) float32 bind-pose centres; ``rest_quat`` (N, 4) float32 (w, x, y, z)
  (need not be unit: normalised); ``rest_scales`` (N, 3) float32 linear sigmas; ``sh`` (N, C, 3)
  float32 3DGS-basis coefficients (C = (d+1)^2, d in 0..3).
- ``joint_idx`` (N, K) int32 in [0, J); ``weights`` (N, K) float32 (used as given, not
  renormalised).
- ``skin`` (J, 4, 4) float64 skinning matrices in the COLUMN-vector convention (``p' = M @ [p, 1]``;
  the transpose of UsdSkel's ``Gf.Matrix4d``), the geomBindTransform already folded in.
- ``dirs`` (M, 3) float64 unit directions, band l owning ``dirs[l^2 - 1 : (l+1)^2 - 1]`` (2l+1 of
  them), and ``pinv`` (C, M) float64: rows ``l^2 .. (l+1)^2 - 1`` hold the inverse of the band-l
  basis at its directions in those columns; see ``usd_gs.usd.skel.sh_rotation_tables``.

Per Gaussian: ``A = sum_k w_k skin[j_k]`` (the blended affine). Position ``A[:3, :3] @ p + A[:3, 3]``
(float64 math). Rotation ``R`` = the orthogonal polar factor of ``A[:3, :3]`` (Newton iteration
with determinant scaling, converged to 1e-12), uniform scale ``s = det(A33)^(1/3)``.
When ``det(A33) <= 1e-12 * |A33|_F^3`` (degenerate or reflected blend) ``R`` and ``s`` come from
the matrix of the Gaussian's largest-weight influence instead (identity / 1 if that one is
degenerate too). Orientation ``quat(R) * q_rest`` (unit, w >= 0), scales ``s * rest_scales``,
SH band l: ``c' = D_l @ c`` with ``D_l = A_l^-1 @ Y_l(R^T dirs_l)``, exact per band (the new expansion at world
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
def _polar9(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """Orthogonal polar factor of a 3x3 (row-major scalars) by Newton's iteration
    ``X <- (g X + X^-T / g) / 2`` (``g = |det X|^(-1/3)`` on the first step, 1 after), until the
    update is below 1e-12 (at most 40 steps). Returns (det(A), r00..r22); det(A) = 0.0 flags a degenerate or
    reflected input (det <= 1e-12 |A|_F^3), the rotation is then the identity."""
    fro2 = (a00 * a00 + a01 * a01 + a02 * a02 + a10 * a10 + a11 * a11 + a12 * a12
            + a20 * a20 + a21 * a21 + a22 * a22)
    det = a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)
    fro = math.sqrt(fro2)
    if not (fro > 0.0) or not (det > 1e-12 * fro2 * fro):
        return 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    x00, x01, x02, x10, x11, x12, x20, x21, x22 = a00, a01, a02, a10, a11, a12, a20, a21, a22
    d = det
    for it in range(40):
        # cofactor matrix = det * inverse transpose
        c00 = x11 * x22 - x12 * x21
        c01 = x12 * x20 - x10 * x22
        c02 = x10 * x21 - x11 * x20
        c10 = x02 * x21 - x01 * x22
        c11 = x00 * x22 - x02 * x20
        c12 = x01 * x20 - x00 * x21
        c20 = x01 * x12 - x02 * x11
        c21 = x02 * x10 - x00 * x12
        c22 = x00 * x11 - x01 * x10
        # determinant scaling on the first step only (it removes the uniform scale; later steps
        # start near a rotation, where plain Newton converges quadratically)
        g = math.exp(-math.log(d) / 3.0) if it == 0 else 1.0
        h = 0.5 * g
        f = 0.5 / (g * d)
        n00, n01, n02 = h * x00 + f * c00, h * x01 + f * c01, h * x02 + f * c02
        n10, n11, n12 = h * x10 + f * c10, h * x11 + f * c11, h * x12 + f * c12
        n20, n21, n22 = h * x20 + f * c20, h * x21 + f * c21, h * x22 + f * c22
        ch = ((n00 - x00) ** 2 + (n01 - x01) ** 2 + (n02 - x02) ** 2 + (n10 - x10) ** 2 + (n11 - x11) ** 2
              + (n12 - x12) ** 2 + (n20 - x20) ** 2 + (n21 - x21) ** 2 + (n22 - x22) ** 2)
        x00, x01, x02, x10, x11, x12, x20, x21, x22 = n00, n01, n02, n10, n11, n12, n20, n21, n22
        if ch < 1e-24:
            break
        d = x00 * (x11 * x22 - x12 * x21) - x01 * (x10 * x22 - x12 * x20) + x02 * (x10 * x21 - x11 * x20)
        if not (d > 0.0):
            break
    return det, x00, x01, x02, x10, x11, x12, x20, x21, x22


@njit(cache=True, inline="always")
def _mat_to_quat9(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """Unit (w, x, y, z) of a rotation matrix (Shepperd's method), w >= 0."""
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


@njit(cache=True)
def _dq_affine(joint_idx, weights, i, best_j, dq, scl, pre, post, m, t, out):
    """Gaussian i's affine map (3x4, row-major scalars) under UsdSkel's dual-quaternion skinning:
    ``post @ [R_dq S | t_dq] @ pre`` with ``S = sum_k w_k scl[j_k]`` (the joints' stretch parts,
    blended linearly) and the blended dual quaternion (signs aligned with the largest-weight
    joint's, normalised, Pluecker-corrected; identity when its real part vanishes). ``m``, ``t``, ``out``:
    scratch (4, 4), (4, 4), (3, 4) float64."""
    pw, px, py, pz = dq[best_j, 0], dq[best_j, 1], dq[best_j, 2], dq[best_j, 3]
    rw = rx = ry = rz = 0.0
    dw = dx = dy = dz = 0.0
    s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
    for k in range(joint_idx.shape[1]):
        j = joint_idx[i, k]
        w = float(weights[i, k])
        if w == 0.0:
            continue
        s00 += w * scl[j, 0, 0]
        s01 += w * scl[j, 0, 1]
        s02 += w * scl[j, 0, 2]
        s10 += w * scl[j, 1, 0]
        s11 += w * scl[j, 1, 1]
        s12 += w * scl[j, 1, 2]
        s20 += w * scl[j, 2, 0]
        s21 += w * scl[j, 2, 1]
        s22 += w * scl[j, 2, 2]
        if dq[j, 0] * pw + dq[j, 1] * px + dq[j, 2] * py + dq[j, 3] * pz < 0.0:
            w = -w
        rw += w * dq[j, 0]
        rx += w * dq[j, 1]
        ry += w * dq[j, 2]
        rz += w * dq[j, 3]
        dw += w * dq[j, 4]
        dx += w * dq[j, 5]
        dy += w * dq[j, 6]
        dz += w * dq[j, 7]
    ln = math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    if ln < 1e-10:
        rw, rx, ry, rz, dw, dx, dy, dz = 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    else:
        rw, rx, ry, rz, dw, dx, dy, dz = rw / ln, rx / ln, ry / ln, rz / ln, dw / ln, dx / ln, dy / ln, dz / ln
        e = rw * dw + rx * dx + ry * dy + rz * dz
        dw, dx, dy, dz = dw - e * rw, dx - e * rx, dy - e * ry, dz - e * rz
    # translation 2 * vec(dual * conj(real))
    tx = 2.0 * (-dw * rx + dx * rw - dy * rz + dz * ry)
    ty = 2.0 * (-dw * ry + dy * rw - dz * rx + dx * rz)
    tz = 2.0 * (-dw * rz + dz * rw - dx * ry + dy * rx)
    q00, q01, q02 = 1.0 - 2.0 * (ry * ry + rz * rz), 2.0 * (rx * ry - rw * rz), 2.0 * (rx * rz + rw * ry)
    q10, q11, q12 = 2.0 * (rx * ry + rw * rz), 1.0 - 2.0 * (rx * rx + rz * rz), 2.0 * (ry * rz - rw * rx)
    q20, q21, q22 = 2.0 * (rx * rz - rw * ry), 2.0 * (ry * rz + rw * rx), 1.0 - 2.0 * (rx * rx + ry * ry)
    # m = [Q S | t] (3x4), then post @ m @ pre
    m[0, 0] = q00 * s00 + q01 * s10 + q02 * s20
    m[0, 1] = q00 * s01 + q01 * s11 + q02 * s21
    m[0, 2] = q00 * s02 + q01 * s12 + q02 * s22
    m[1, 0] = q10 * s00 + q11 * s10 + q12 * s20
    m[1, 1] = q10 * s01 + q11 * s11 + q12 * s21
    m[1, 2] = q10 * s02 + q11 * s12 + q12 * s22
    m[2, 0] = q20 * s00 + q21 * s10 + q22 * s20
    m[2, 1] = q20 * s01 + q21 * s11 + q22 * s21
    m[2, 2] = q20 * s02 + q21 * s12 + q22 * s22
    m[0, 3], m[1, 3], m[2, 3] = tx, ty, tz
    m[3, 0] = m[3, 1] = m[3, 2] = 0.0
    m[3, 3] = 1.0
    for u in range(4):
        for v in range(4):
            acc = 0.0
            for k in range(4):
                acc += m[u, k] * pre[k, v]
            t[u, v] = acc
    for u in range(3):
        for v in range(4):
            acc = 0.0
            for k in range(4):
                acc += post[u, k] * t[k, v]
            out[u, v] = acc
    return (out[0, 0], out[0, 1], out[0, 2], out[0, 3], out[1, 0], out[1, 1], out[1, 2], out[1, 3],
            out[2, 0], out[2, 1], out[2, 2], out[2, 3])


@njit(cache=True, **threaded())
def _skin_range(lo, hi, rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv,
                out_pos, out_quat, out_scales, out_sh, out_rot, mode, dq, scl, pre, post):
    n_inf = joint_idx.shape[1]
    n_coef = sh.shape[1]
    ybuf = np.empty(16)
    ymat = np.empty((7, 7))
    dmat = np.empty((7, 7))
    dq_m, dq_t, dq_out = np.empty((4, 4)), np.empty((4, 4)), np.empty((3, 4))
    for i in range(lo, hi):
        a00 = a01 = a02 = a03 = a10 = a11 = a12 = a13 = a20 = a21 = a22 = a23 = 0.0
        best_w = -1.0
        best_j = 0
        for k in range(n_inf):
            j = joint_idx[i, k]
            w = float(weights[i, k])
            if w > best_w:
                best_w = w
                best_j = j
            if w != 0.0:
                a00 += w * skin[j, 0, 0]
                a01 += w * skin[j, 0, 1]
                a02 += w * skin[j, 0, 2]
                a03 += w * skin[j, 0, 3]
                a10 += w * skin[j, 1, 0]
                a11 += w * skin[j, 1, 1]
                a12 += w * skin[j, 1, 2]
                a13 += w * skin[j, 1, 3]
                a20 += w * skin[j, 2, 0]
                a21 += w * skin[j, 2, 1]
                a22 += w * skin[j, 2, 2]
                a23 += w * skin[j, 2, 3]
        if mode == 1:
            a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23 = _dq_affine(
                joint_idx, weights, i, best_j, dq, scl, pre, post, dq_m, dq_t, dq_out)
        px, py, pz = float(rest_pos[i, 0]), float(rest_pos[i, 1]), float(rest_pos[i, 2])
        out_pos[i, 0] = a00 * px + a01 * py + a02 * pz + a03
        out_pos[i, 1] = a10 * px + a11 * py + a12 * pz + a13
        out_pos[i, 2] = a20 * px + a21 * py + a22 * pz + a23
        det, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _polar9(a00, a01, a02, a10, a11, a12, a20, a21, a22)
        if det <= 0.0:
            s0 = skin[best_j]
            det, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _polar9(
                s0[0, 0], s0[0, 1], s0[0, 2], s0[1, 0], s0[1, 1], s0[1, 2], s0[2, 0], s0[2, 1], s0[2, 2])
            if det <= 0.0:
                det = 1.0
        s = math.exp(math.log(det) / 3.0)
        out_scales[i, 0] = s * rest_scales[i, 0]
        out_scales[i, 1] = s * rest_scales[i, 1]
        out_scales[i, 2] = s * rest_scales[i, 2]
        out_rot[i, 0, 0], out_rot[i, 0, 1], out_rot[i, 0, 2] = r00, r01, r02
        out_rot[i, 1, 0], out_rot[i, 1, 1], out_rot[i, 1, 2] = r10, r11, r12
        out_rot[i, 2, 0], out_rot[i, 2, 1], out_rot[i, 2, 2] = r20, r21, r22
        rw, rx, ry, rz = _mat_to_quat9(r00, r01, r02, r10, r11, r12, r20, r21, r22)
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
            band = 1
            while (band + 1) * (band + 1) <= n_coef:
                b0 = band * band
                nb = 2 * band + 1
                o = b0 - 1  # this band's directions: dirs[o : o + nb]
                for d in range(nb):
                    # the band basis at R^T w
                    wx, wy, wz = dirs[o + d, 0], dirs[o + d, 1], dirs[o + d, 2]
                    _basis(r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz,
                           r02 * wx + r12 * wy + r22 * wz, ybuf)
                    for e in range(nb):
                        ymat[d, e] = ybuf[b0 + e]
                # band matrix D = A_l^-1 @ Y_l(R^T dirs_l): new = D @ old
                for u in range(nb):
                    for v in range(nb):
                        acc = 0.0
                        for d in range(nb):
                            acc += pinv[b0 + u, o + d] * ymat[d, v]
                        dmat[u, v] = acc
                for u in range(nb):
                    c0 = 0.0
                    c1 = 0.0
                    c2 = 0.0
                    for v in range(nb):
                        dv = dmat[u, v]
                        c0 += dv * sh[i, b0 + v, 0]
                        c1 += dv * sh[i, b0 + v, 1]
                        c2 += dv * sh[i, b0 + v, 2]
                    out_sh[i, b0 + u, 0] = c0
                    out_sh[i, b0 + u, 1] = c1
                    out_sh[i, b0 + u, 2] = c2
                band += 1


def skin_gaussians(rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv, dual=None):
    """Skin N Gaussians (module docstring). Returns ``(positions (N, 3), orientations (N, 4) wxyz,
    scales (N, 3), sh (N, C, 3), rotations (N, 3, 3))``, all float32 (rotations: the per-Gaussian
    polar rotation ``R``, column-vector convention).

    ``dual``: None for linear blend skinning with ``skin``; else ``(dq (J, 8), scl (J, 3, 3), pre (4, 4),
    post (4, 4))`` float64 for UsdSkel's dual-quaternion skinning (``skin`` unused): each joint's
    rigid part as a unit dual quaternion (real w, x, y, z, dual w, x, y, z), its stretch ``scl`` (the
    symmetric polar factor, applied first, blended linearly), ``pre`` the geomBindTransform and
    ``post`` skeleton space -> output space, column-vector. The Gaussian's affine map is then
    ``post @ [R S | t] @ pre``; orientation, scale and SH follow its 3x3 as in the linear case."""
    n = rest_pos.shape[0]
    c = sh.shape[1]
    out_pos = np.empty((n, 3), np.float32)
    out_quat = np.empty((n, 4), np.float32)
    out_scales = np.empty((n, 3), np.float32)
    out_sh = np.empty((n, c, 3), np.float32)
    out_rot = np.empty((n, 3, 3), np.float32)
    if dual is None:
        mode, dq, scl, pre, post = 0, np.zeros((1, 8)), np.zeros((1, 3, 3)), np.eye(4), np.eye(4)
    else:
        mode, (dq, scl, pre, post) = 1, (np.ascontiguousarray(a, np.float64) for a in dual)
    run_chunks(_skin_range, n, rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv,
               out_pos, out_quat, out_scales, out_sh, out_rot, mode, dq, scl, pre, post, min_chunk=2048)
    return out_pos, out_quat, out_scales, out_sh, out_rot
