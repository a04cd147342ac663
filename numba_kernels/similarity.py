"""A similarity transform of Gaussians' positions, orientations and scales in one threaded pass.

``GaussianSet.transformed`` applies a USD transform ``p' = s Q p + t`` (``Q`` orthogonal, ``s > 0``)
to every Gaussian a time-sampled or moved prim holds, at every frame it is read. In numpy that is
a dozen float64 temporaries per set; here each Gaussian is read once and written once:

- position: ``lin @ p + t`` in float64 (``lin = s Q``), rounded to float32;
- orientation: the quaternion (w, x, y, z) normalised in float64 (a zero quaternion becomes the
  identity), its y and z negated when ``Q`` is a reflection (the first local axis flipped:
  ``usd_gs.gaussians.GaussianSet.transformed``), then the Hamilton product ``rq * q`` with the
  proper rotation's unit quaternion ``rq``, rounded to float32;
- scales: times ``s`` in float64, rounded to float32.

Orientations and scales are bit for bit the numpy formulas' (the same float64 operations in the
same order: ``numba_kernels/reference/similarity.py``); a position may differ from numpy's
matrix product in the last bit of its float64 value (BLAS may fuse or reorder the 3-term dot
product), which rounds to the same float32 but in rare ties. Inputs are finite (the readers check
them); the outputs then are too.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import read_only, threaded
from .thread_chunks import run_chunks

_MIN_CHUNK = 16384


@njit(cache=True, **threaded(), fastmath=False, error_model="numpy")
def _similarity_range(i0, i1, pos, quat, scales, lin, t, s, rq, flip, out_pos, out_quat, out_scales):
    aw, ax, ay, az = rq[0], rq[1], rq[2], rq[3]
    for i in range(i0, i1):
        px, py, pz = np.float64(pos[i, 0]), np.float64(pos[i, 1]), np.float64(pos[i, 2])
        for k in range(3):
            out_pos[i, k] = np.float32(((px * lin[k, 0] + py * lin[k, 1]) + pz * lin[k, 2]) + t[k])
        bw, bx = np.float64(quat[i, 0]), np.float64(quat[i, 1])
        by, bz = np.float64(quat[i, 2]), np.float64(quat[i, 3])
        n = math.sqrt(((bw * bw + bx * bx) + by * by) + bz * bz)
        if n > 0.0:
            bw, bx, by, bz = bw / n, bx / n, by / n, bz / n
        else:
            bw, bx, by, bz = 1.0, 0.0, 0.0, 0.0
        if flip:
            by, bz = -by, -bz
        out_quat[i, 0] = np.float32(aw * bw - ax * bx - ay * by - az * bz)
        out_quat[i, 1] = np.float32(aw * bx + ax * bw + ay * bz - az * by)
        out_quat[i, 2] = np.float32(aw * by - ax * bz + ay * bw + az * bx)
        out_quat[i, 3] = np.float32(aw * bz + ax * by - ay * bx + az * bw)
        for k in range(3):
            out_scales[i, k] = np.float32(np.float64(scales[i, k]) * s)


def similarity_transform(positions: np.ndarray, orientations: np.ndarray, scales: np.ndarray, lin: np.ndarray,
                         t: np.ndarray, s: float, rq: np.ndarray, flip: bool):
    """``(positions, orientations, scales)`` float32 ((N, 3), (N, 4) w-first, (N, 3)) of the Gaussians
    ``positions``, ``orientations``, ``scales`` (float32) under ``p' = lin @ p + t`` (``lin`` (3, 3)
    = ``s Q``, column-vector convention; ``t`` (3,)), their orientations turned by the unit
    quaternion ``rq`` (4,) of ``Q``'s proper rotation (``flip``: ``Q`` is a reflection, module
    docstring), their scales times ``s``."""
    n = positions.shape[0]
    out_pos = np.empty((n, 3), np.float32)
    out_quat = np.empty((n, 4), np.float32)
    out_scales = np.empty((n, 3), np.float32)
    args = [read_only(np.ascontiguousarray(a, np.float32)) for a in (positions, orientations, scales)]
    run_chunks(_similarity_range, n, *args, np.ascontiguousarray(lin, np.float64),
               np.ascontiguousarray(t, np.float64).reshape(3), float(s), np.ascontiguousarray(rq, np.float64),
               bool(flip), out_pos, out_quat, out_scales, min_chunk=_MIN_CHUNK)
    return out_pos, out_quat, out_scales
