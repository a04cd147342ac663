"""Gaussians merged cell by cell: one Gaussian per occupied cell of a cubic grid, a level of detail
for renders in which a cell is at most a texel across (the probes' view of another moving prim).

Inputs (one set): ``positions`` (N, 3) float32 (any length unit; ``cell`` in the same),
``quaternions`` (N, 4) float32 (w, x, y, z; normalised here), ``scales`` (N, 3) float32 (sigma),
``opacities`` (N,) float32 in [0, 1], ``sh`` (N, K, 3) float32 (any basis: averaged as they are).

Cells: Gaussian ``i`` lies in cell ``floor((p_i - lo) / cell)`` per axis, ``lo`` the set's
per-axis minimum. Clusters are the occupied cells, in increasing order of the cell's linear index
``(ix * ny + iy) * nz + iz``; ``labels[i]`` is Gaussian ``i``'s cluster.

Per cluster, in float64, with weights ``w_i = alpha_i * A_i`` and ``A = (s1 s2 + s2 s3 + s1 s3) / 3``
(a proxy of a Gaussian's projected area, the mean over views up to a constant factor):

- centre ``mu = sum w_i p_i / W`` (``W = sum w_i``);
- covariance ``Sigma = sum w_i (Sigma_i + (p_i - mu)(p_i - mu)^T) / W``: the members' mixture's
  second moment about ``mu`` (``Sigma_i = R_i diag(s_i)^2 R_i^T``), summed about the cell's first
  member's centre so that far-from-origin positions lose no precision;
- opacity ``min(1, W / A(Sigma))``: the members' opacity-weighted area, spread over the merged
  Gaussian's (an opaque cell stays opaque, a sparse one keeps its coverage);
- SH ``sum w_i sh_i / W``;
- ``Sigma`` -> (quaternion (w >= 0), sigmas) by a cyclic Jacobi eigen-decomposition, sigmas
  ``sqrt(max(eigenvalue, tiny))``.

A cluster whose members are all transparent (``W == 0``) takes the members' plain means and
opacity 0. Inputs must be finite (the caller's sets are checked when read); no NaN or Inf
leaves the kernels. The reference is :mod:`numba_kernels.reference.gaussian_merge`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import read_only
from .quaternion import quat_to_rotation
from .thread_chunks import run_chunks

#: the cell grid is counted densely (one int64 per cell) up to this many cells or 8 per Gaussian,
#: else the cells are sorted (a sparse grid: a large prim, or a few stray Gaussians far away)
DENSE_CELLS = 1 << 16
_TINY = 1e-30


@njit(cache=True, error_model="numpy")  # serial: see jit_options.SERIAL_NOTE
def _bounds(pos):
    """(lo (3,), hi (3,)) float64 per-axis minimum and maximum of ``pos`` (N >= 1) (numpy's axis-0
    reductions of an (N, 3) array run strided, several times slower)."""
    lo = np.empty(3)
    hi = np.empty(3)
    for c in range(3):
        lo[c] = hi[c] = pos[0, c]
    for i in range(1, pos.shape[0]):
        for c in range(3):
            v = np.float64(pos[i, c])
            lo[c] = min(lo[c], v)
            hi[c] = max(hi[c], v)
    return lo, hi


@njit(cache=True, error_model="numpy")  # serial: see jit_options.SERIAL_NOTE
def _cell_index(pos, lo, inv_cell, nx, ny, nz, out):
    for i in range(pos.shape[0]):  # (clamped: the top face's rounding may land one cell beyond)
        ix = min(max(int(math.floor((pos[i, 0] - lo[0]) * inv_cell)), 0), nx - 1)
        iy = min(max(int(math.floor((pos[i, 1] - lo[1]) * inv_cell)), 0), ny - 1)
        iz = min(max(int(math.floor((pos[i, 2] - lo[2]) * inv_cell)), 0), nz - 1)
        out[i] = (ix * ny + iy) * nz + iz


@njit(cache=True, error_model="numpy")  # serial: see jit_options.SERIAL_NOTE
def _counting_groups(cells, ncells, order, labels):
    """Stable counting sort of ``cells`` (values < ``ncells``): ``order`` the Gaussians by cell,
    ``labels`` their cluster; returns the clusters' start offsets (M + 1,)."""
    count = np.zeros(ncells + 1, np.int64)
    for i in range(cells.shape[0]):
        count[cells[i] + 1] += 1
    m = 0
    for c in range(ncells):
        if count[c + 1] > 0:
            m += 1
        count[c + 1] += count[c]
    starts = np.empty(m + 1, np.int64)
    k = 0
    for c in range(ncells):
        if count[c + 1] > count[c]:
            starts[k] = count[c]
            k += 1
    starts[m] = cells.shape[0]
    fill = count[:ncells].copy()
    for i in range(cells.shape[0]):
        c = cells[i]
        order[fill[c]] = i
        fill[c] += 1
    for j in range(m):
        for q in range(starts[j], starts[j + 1]):
            labels[order[q]] = j
    return starts


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _area(s0, s1, s2):
    return (s0 * s1 + s1 * s2 + s0 * s2) / 3.0


@njit(cache=True, fastmath=False, error_model="numpy")
def _jacobi3(a, v):
    """Eigen-decomposition of the symmetric 3x3 ``a`` (float64, overwritten) by cyclic Jacobi
    sweeps: returns the eigenvalues; ``v`` (3, 3) receives the eigenvectors as columns, a proper
    rotation."""
    for p in range(3):
        for q in range(3):
            v[p, q] = 1.0 if p == q else 0.0
    for _sweep in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        scale = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if off <= 1e-22 * scale:  # (eigenvalues to about 1e-11 of the largest)
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):  # a <- a J (columns p, q)
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(3):  # a <- J^T a (rows p, q)
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    det = (v[0, 0] * (v[1, 1] * v[2, 2] - v[1, 2] * v[2, 1]) - v[0, 1] * (v[1, 0] * v[2, 2] - v[1, 2] * v[2, 0])
           + v[0, 2] * (v[1, 0] * v[2, 1] - v[1, 1] * v[2, 0]))
    if det < 0.0:
        for k in range(3):
            v[k, 0] = -v[k, 0]
    return a[0, 0], a[1, 1], a[2, 2]


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _rotation_to_quaternion(r):
    """Shepperd's method (as ``usd_gs.gaussians.matrix_to_quaternion``): (w, x, y, z), w >= 0, unit."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr >= r[0, 0] and tr >= r[1, 1] and tr >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + tr, 1e-300))
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 1e-300))
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 - r[0, 0] + r[1, 1] - r[2, 2], 1e-300))
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 - r[0, 0] - r[1, 1] + r[2, 2], 1e-300))
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


# nogil without the parallel pipeline of jit_options.threaded(): with it this kernel ran about 3x slower
@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _merge_clusters(c0, c1, order, starts, pos, quat, scales, opac, sh, out_pos, out_quat, out_scales, out_opac,
                    out_sh):
    k = sh.shape[1]
    acc_sh = np.empty((k, 3))
    cov = np.empty((3, 3))
    vec = np.empty((3, 3))
    for c in range(c0, c1):
        a, b = starts[c], starts[c + 1]
        r = order[a]
        ox, oy, oz = np.float64(pos[r, 0]), np.float64(pos[r, 1]), np.float64(pos[r, 2])
        wsum = 0.0
        m0 = m1 = m2 = 0.0
        s00 = s01 = s02 = s11 = s12 = s22 = 0.0
        acc_sh[:, :] = 0.0
        plain = True
        for q in range(a, b):
            i = order[q]
            sx, sy, sz = np.float64(scales[i, 0]), np.float64(scales[i, 1]), np.float64(scales[i, 2])
            w = np.float64(opac[i]) * _area(sx, sy, sz)
            if w > 0.0:
                plain = False
                break
        for q in range(a, b):
            i = order[q]
            sx, sy, sz = np.float64(scales[i, 0]), np.float64(scales[i, 1]), np.float64(scales[i, 2])
            w = 1.0 if plain else np.float64(opac[i]) * _area(sx, sy, sz)
            if w <= 0.0:
                continue
            dx, dy, dz = pos[i, 0] - ox, pos[i, 1] - oy, pos[i, 2] - oz
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(
                np.float64(quat[i, 0]), np.float64(quat[i, 1]), np.float64(quat[i, 2]), np.float64(quat[i, 3]))
            vx, vy, vz = sx * sx, sy * sy, sz * sz
            wsum += w
            m0 += w * dx
            m1 += w * dy
            m2 += w * dz
            # w (Sigma_i + d d^T), Sigma_i = R diag(v) R^T
            s00 += w * (r00 * r00 * vx + r01 * r01 * vy + r02 * r02 * vz + dx * dx)
            s01 += w * (r00 * r10 * vx + r01 * r11 * vy + r02 * r12 * vz + dx * dy)
            s02 += w * (r00 * r20 * vx + r01 * r21 * vy + r02 * r22 * vz + dx * dz)
            s11 += w * (r10 * r10 * vx + r11 * r11 * vy + r12 * r12 * vz + dy * dy)
            s12 += w * (r10 * r20 * vx + r11 * r21 * vy + r12 * r22 * vz + dy * dz)
            s22 += w * (r20 * r20 * vx + r21 * r21 * vy + r22 * r22 * vz + dz * dz)
            for j in range(k):
                for ch in range(3):
                    acc_sh[j, ch] += w * sh[i, j, ch]
        mx, my, mz = m0 / wsum, m1 / wsum, m2 / wsum
        # about the centre: E[d d^T] - m m^T
        cov[0, 0] = s00 / wsum - mx * mx
        cov[0, 1] = cov[1, 0] = s01 / wsum - mx * my
        cov[0, 2] = cov[2, 0] = s02 / wsum - mx * mz
        cov[1, 1] = s11 / wsum - my * my
        cov[1, 2] = cov[2, 1] = s12 / wsum - my * mz
        cov[2, 2] = s22 / wsum - mz * mz
        l0, l1, l2 = _jacobi3(cov, vec)
        sg0 = math.sqrt(max(l0, _TINY))
        sg1 = math.sqrt(max(l1, _TINY))
        sg2 = math.sqrt(max(l2, _TINY))
        w, x, y, z = _rotation_to_quaternion(vec)
        out_pos[c, 0], out_pos[c, 1], out_pos[c, 2] = ox + mx, oy + my, oz + mz
        out_quat[c, 0], out_quat[c, 1], out_quat[c, 2], out_quat[c, 3] = w, x, y, z
        out_scales[c, 0], out_scales[c, 1], out_scales[c, 2] = sg0, sg1, sg2
        out_opac[c] = 0.0 if plain else min(1.0, wsum / _area(sg0, sg1, sg2))
        for j in range(k):
            for ch in range(3):
                out_sh[c, j, ch] = acc_sh[j, ch] / wsum


def _float32(a) -> np.ndarray:
    return read_only(np.ascontiguousarray(a, np.float32))


def merge_cells(positions, quaternions, scales, opacities, sh, cell: float):
    """The set's Gaussians merged per cell of size ``cell`` (module docstring):
    ``(labels (N,) int64, positions (M, 3), quaternions (M, 4), scales (M, 3), opacities (M,),
    sh (M, K, 3))``, float32 arrays, clusters in cell order. ``cell`` > 0."""
    pos = _float32(positions)
    n = pos.shape[0]
    if not cell > 0.0 or not math.isfinite(cell):
        raise ValueError(f"cell must be a finite size > 0, got {cell}")
    sh = _float32(sh)
    k = sh.shape[1]
    if n == 0:
        return (np.zeros(0, np.int64), np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32),
                np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros((0, k, 3), np.float32))
    lo, hi = _bounds(pos)
    span = hi - lo
    dims = np.floor(span / cell).astype(np.int64) + 1
    cells = np.empty(n, np.int64)
    _cell_index(pos, lo, 1.0 / float(cell), int(dims[0]), int(dims[1]), int(dims[2]), cells)
    order = np.empty(n, np.int64)
    labels = np.empty(n, np.int64)
    ncells = int(dims[0]) * int(dims[1]) * int(dims[2])
    if ncells <= max(DENSE_CELLS, 8 * n):
        starts = _counting_groups(cells, ncells, order, labels)
    else:  # a sparse grid (a large, thin prim): sort instead of counting every cell
        order = np.argsort(cells, kind="stable")
        sc = cells[order]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(sc)) + 1, [n]]).astype(np.int64)
        labels[order] = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
    m = len(starts) - 1
    out = (np.empty((m, 3), np.float32), np.empty((m, 4), np.float32), np.empty((m, 3), np.float32),
           np.empty(m, np.float32), np.empty((m, k, 3), np.float32))
    run_chunks(_merge_clusters, m, order, starts, pos, _float32(quaternions), _float32(scales), _float32(opacities),
               sh, *out, min_chunk=256)
    return (labels, *out)
