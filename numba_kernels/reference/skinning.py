"""Slow, obviously-correct numpy reference of ``numba_kernels.skinning.skin_gaussians``.

Same contract as the kernel (see its module docstring); the polar rotation comes from an SVD
(``R = U V^T`` of ``A33 = U S V^T`` when det(A33) > 1e-12 |A33|_F^3), the SH bands from an
explicit per-Gaussian least-squares fit of the rotated expansion on the same directions.
"""

from __future__ import annotations

import numpy as np

_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
       1.445305721320277, -0.5900435899266435)


def basis(d: np.ndarray) -> np.ndarray:
    """(M, 16) 3DGS SH basis bands 0..3 (column 0 set to 1) at (M, 3) unit directions."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    xx, yy, zz = x * x, y * y, z * z
    return np.stack([np.ones_like(x), -_C1 * y, _C1 * z, -_C1 * x,
                     _C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * zz - xx - yy), _C2[3] * x * z, _C2[4] * (xx - yy),
                     _C3[0] * y * (3 * xx - yy), _C3[1] * x * y * z, _C3[2] * y * (4 * zz - xx - yy),
                     _C3[3] * z * (2 * zz - 3 * xx - 3 * yy), _C3[4] * x * (4 * zz - xx - yy), _C3[5] * z * (xx - yy),
                     _C3[6] * x * (xx - 3 * yy)], axis=1)


def _polar(a: np.ndarray):
    fro = np.linalg.norm(a)
    det = np.linalg.det(a)
    if not (fro > 0 and det > 1e-12 * fro ** 3):
        return None, 0.0
    u, _, vt = np.linalg.svd(a)
    return u @ vt, det


def _quat(r: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation via the eigenvector of the 4x4 symmetric matrix (Bar-Itzhack)."""
    k = np.array([[r[0, 0] - r[1, 1] - r[2, 2], r[1, 0] + r[0, 1], r[2, 0] + r[0, 2], r[2, 1] - r[1, 2]],
                  [r[1, 0] + r[0, 1], r[1, 1] - r[0, 0] - r[2, 2], r[2, 1] + r[1, 2], r[0, 2] - r[2, 0]],
                  [r[2, 0] + r[0, 2], r[2, 1] + r[1, 2], r[2, 2] - r[0, 0] - r[1, 1], r[1, 0] - r[0, 1]],
                  [r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1], r[0, 0] + r[1, 1] + r[2, 2]]]) / 3.0
    _, vec = np.linalg.eigh(k)
    x, y, z, w = vec[:, -1]
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def _qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _quat_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _dq_affine(idx, w, dual):
    """4x4 affine ``post @ [R S | t] @ pre`` of one Gaussian under dual-quaternion skinning."""
    dq, scl, pre, post = dual
    pivot = dq[idx[int(np.argmax(w))], :4]
    blend = np.zeros(8)
    stretch = np.zeros((3, 3))
    for j, wk in zip(idx, w, strict=True):
        if wk == 0:
            continue
        stretch += wk * scl[j]
        blend += (wk if np.dot(dq[j, :4], pivot) >= 0 else -wk) * dq[j]
    real, du = blend[:4], blend[4:]
    n = np.linalg.norm(real)
    if n < 1e-10:
        real, du = np.array([1.0, 0, 0, 0]), np.zeros(4)
    else:
        real, du = real / n, du / n
        du = du - np.dot(real, du) * real
    t = 2.0 * _qmul(du, real * [1, -1, -1, -1])[1:]
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(real) @ stretch
    m[:3, 3] = t
    return post @ m @ pre


def skin_gaussians(rest_pos, rest_quat, rest_scales, sh, joint_idx, weights, skin, dirs, pinv=None, dual=None):
    """Reference of the kernel (``pinv`` is ignored: each band is fitted by ``lstsq`` here)."""
    n, c = rest_pos.shape[0], sh.shape[1]
    out_pos = np.zeros((n, 3))
    out_quat = np.zeros((n, 4))
    out_scales = np.zeros((n, 3))
    out_sh = np.zeros((n, c, 3))
    out_rot = np.zeros((n, 3, 3))
    y_world = basis(np.asarray(dirs, np.float64))
    for i in range(n):
        w = weights[i].astype(np.float64)
        blend = np.einsum("k,kij->ij", w, skin[joint_idx[i]]) if dual is None else _dq_affine(joint_idx[i], w, dual)
        out_pos[i] = blend[:3, :3] @ rest_pos[i].astype(np.float64) + blend[:3, 3]
        r, det = _polar(blend[:3, :3])
        if r is None:
            r, det = _polar(skin[joint_idx[i][int(np.argmax(w))]][:3, :3])
            if r is None:
                r, det = np.eye(3), 1.0
        out_rot[i] = r
        out_scales[i] = det ** (1 / 3) * rest_scales[i]
        q = rest_quat[i].astype(np.float64)
        qn = np.linalg.norm(q)
        q = q / qn if qn > 0 else np.array([1.0, 0, 0, 0])
        o = _qmul(_quat(r), q)
        o /= np.linalg.norm(o)
        out_quat[i] = o if o[0] >= 0 else -o
        out_sh[i, 0] = sh[i, 0]
        y_rot = basis(np.asarray(dirs, np.float64) @ r)  # rows: (R^T w)^T = w^T R
        band = 1
        while (band + 1) ** 2 <= c:
            s = slice(band * band, (band + 1) ** 2)
            # new coefficients c' with Y_world c' = Y(R^T w) c
            out_sh[i, s] = np.linalg.lstsq(y_world[:, s], y_rot[:, s] @ sh[i, s].astype(np.float64), rcond=None)[0]
            band += 1
    f = np.float32
    return out_pos.astype(f), out_quat.astype(f), out_scales.astype(f), out_sh.astype(f), out_rot.astype(f)
