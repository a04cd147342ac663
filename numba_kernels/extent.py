"""The axis-aligned box around Gaussians' ``n_sigma`` ellipsoids in one pass
(``usd_gs.gaussians.GaussianSet.extent``, whose numpy code is the reference: the same float64
operations in the same order, so the same bits; ``tests/test_gaussians_extent.py``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import read_only, threaded
from .thread_chunks import run_chunks

_FLOAT32_MAX = float(np.finfo(np.float32).max)


@njit(cache=True, fastmath=False, inline="always")
def _extent_rows(positions, orientations, scales, start, stop, n_sigma, big, out):
    """The box of rows ``start:stop`` into ``out`` (2, 3); False where some row's box is not finite."""
    lo0 = lo1 = lo2 = math.inf
    hi0 = hi1 = hi2 = -math.inf
    ok = True
    for i in range(start, stop):
        w = np.float64(orientations[i, 0])
        x = np.float64(orientations[i, 1])
        y = np.float64(orientations[i, 2])
        z = np.float64(orientations[i, 3])
        qn = math.sqrt(((w * w + x * x) + y * y) + z * z)
        if qn > 0.0:
            w, x, y, z = w / qn, x / qn, y / qn, z / qn
        else:  # zero (or NaN) quaternion: identity
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
        r00 = 1.0 - 2.0 * (y * y + z * z)
        r01 = 2.0 * (x * y - w * z)
        r02 = 2.0 * (x * z + w * y)
        r10 = 2.0 * (x * y + w * z)
        r11 = 1.0 - 2.0 * (x * x + z * z)
        r12 = 2.0 * (y * z - w * x)
        r20 = 2.0 * (x * z - w * y)
        r21 = 2.0 * (y * z + w * x)
        r22 = 1.0 - 2.0 * (x * x + y * y)
        s0 = np.float64(scales[i, 0])
        s1 = np.float64(scales[i, 1])
        s2 = np.float64(scales[i, 2])
        s0 = s0 * s0
        s1 = s1 * s1
        s2 = s2 * s2
        h0 = n_sigma * math.sqrt((r00 * r00 * s0 + r01 * r01 * s1) + r02 * r02 * s2)
        h1 = n_sigma * math.sqrt((r10 * r10 * s0 + r11 * r11 * s1) + r12 * r12 * s2)
        h2 = n_sigma * math.sqrt((r20 * r20 * s0 + r21 * r21 * s1) + r22 * r22 * s2)
        p0 = np.float64(positions[i, 0])
        p1 = np.float64(positions[i, 1])
        p2 = np.float64(positions[i, 2])
        a0, b0 = p0 - h0, p0 + h0
        a1, b1 = p1 - h1, p1 + h1
        a2, b2 = p2 - h2, p2 + h2
        if not (abs(a0) <= big and abs(b0) <= big and abs(a1) <= big and abs(b1) <= big
                and abs(a2) <= big and abs(b2) <= big):
            ok = False
            continue
        lo0, hi0 = min(lo0, a0), max(hi0, b0)
        lo1, hi1 = min(lo1, a1), max(hi1, b1)
        lo2, hi2 = min(lo2, a2), max(hi2, b2)
    out[0, 0], out[0, 1], out[0, 2] = lo0, lo1, lo2
    out[1, 0], out[1, 1], out[1, 2] = hi0, hi1, hi2
    return ok


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _extent_kernel(positions, orientations, scales, n_sigma, big, out):
    return _extent_rows(positions, orientations, scales, 0, positions.shape[0], n_sigma, big, out)


@njit(cache=True, **threaded(), fastmath=False)
def _block_extents(b0, b1, positions, orientations, scales, starts, n_sigma, big, out, ok):
    for b in range(b0, b1):
        ok[b] = _extent_rows(positions, orientations, scales, starts[b], starts[b + 1], n_sigma, big, out[b])


def gaussian_extent(positions: np.ndarray, orientations: np.ndarray, scales: np.ndarray,
                    n_sigma: float) -> np.ndarray | None:
    """(2, 3) float64 (min, max) corners of the box around every Gaussian's ``n_sigma`` ellipsoid,
    or None where some Gaussian's box is not finite in float32 (the caller names it).

    ``positions`` (N, 3), ``orientations`` (N, 4) (w, x, y, z), not necessarily unit (a zero
    quaternion counts as identity), ``scales`` (N, 3) linear sigma: float32, C-contiguous, N >= 1.
    Per axis i the half-width is ``n_sigma * sqrt(sum_j R_ij^2 s_j^2)``, float64.
    """
    out = np.empty((2, 3), np.float64)
    ok = _extent_kernel(read_only(positions), read_only(orientations), read_only(scales), float(n_sigma),
                        _FLOAT32_MAX, out)
    return out if ok else None


def block_extents(positions: np.ndarray, orientations: np.ndarray, scales: np.ndarray, starts,
                  n_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gaussian_extent` of each block of rows ``starts[b]:starts[b+1]`` (``starts`` (B+1,)
    increasing), the blocks in threads: ``(boxes (B, 2, 3) float64, ok (B,) bool)``, the same bits
    as :func:`gaussian_extent` on each block's rows; ``ok`` False where it would return None
    (that block's box is then undefined), and for an empty block (box +-inf)."""
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    nb = max(st.size - 1, 0)
    out = np.empty((nb, 2, 3), np.float64)
    ok = np.zeros(nb, np.bool_)
    run_chunks(_block_extents, nb, read_only(positions), read_only(orientations), read_only(scales), st,
               float(n_sigma), _FLOAT32_MAX, out, ok)
    ok &= np.diff(st) > 0
    return out, ok
