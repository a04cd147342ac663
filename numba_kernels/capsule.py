"""Which points lie within a capsule: the set of points within ``radius + extra_i`` of the
segment from ``a`` to ``b`` (a ball when ``a == b``), for culling Gaussians (``extra_i`` their own
reach, e.g. a few of their sigmas) against the rays a shadow or visibility test casts.

Float64 arithmetic on float32 or float64 positions: the closest point of the segment is
``a + t u`` with ``u`` the unit direction and ``t = clip((p - a) . u, 0, |b - a|)``; a point is
inside when ``|p - a - t u|^2 <= (radius + extra)^2``. :func:`within_capsule_scaled` takes each
point's extra reach as ``factor`` times its largest scale, computed in the kernel in float32 (the
value of ``factor * scales.max(axis=1)`` on float32 scales) so that no per-point array is made.
Reference: ``numba_kernels.reference.capsule``.

:func:`within_ball_blocks` answers the ball test (``a == b``) for points stored in contiguous
blocks with bounding spheres (:func:`block_spheres`): a block wholly inside or outside the ball is
decided at once, the others point by point, the same values as :func:`within_capsule` (its own
reference; ``tests/test_capsule.py``). :func:`within_capsule_scaled_blocks` does the same for
:func:`within_capsule_scaled`, with each block's least and largest reach (:func:`block_reach`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import float_rows, threaded
from .thread_chunks import run_chunks


@njit(inline="always")
def _distance2(p, m, a, u, length):
    """Squared distance (float64) of point ``p[m]`` to the segment ``a + t u``, t in [0, length]."""
    vx = np.float64(p[m, 0]) - a[0]
    vy = np.float64(p[m, 1]) - a[1]
    vz = np.float64(p[m, 2]) - a[2]
    if length > 0.0:
        t = min(max(vx * u[0] + vy * u[1] + vz * u[2], 0.0), length)
        vx -= t * u[0]
        vy -= t * u[1]
        vz -= t * u[2]
    return vx * vx + vy * vy + vz * vz


@njit(inline="always")
def _block_side(dc, rb, radius, reach_lo, reach_hi):
    """1 when every point within ``rb`` of a centre ``dc`` from the segment lies within ``radius`` plus
    its own reach (at least ``reach_lo``), -1 when every one lies beyond ``radius`` plus its reach
    (at most ``reach_hi``), 0 when the block must be tested point by point; decided only by more
    than a relative 1e-9, far above the rounding of the per-point test (NaN reaches: 0)."""
    tol = 1e-9 * (abs(radius) + dc + rb + abs(reach_lo) + abs(reach_hi))
    if dc + rb < radius + reach_lo - tol:
        return 1
    if dc - rb > radius + reach_hi + tol:
        return -1
    return 0


@njit(cache=True, **threaded(), fastmath=False)
def _within(i0, i1, p, extra, a, u, length, radius, out):
    for m in range(i0, i1):
        r = radius + extra[m]
        out[m] = _distance2(p, m, a, u, length) <= r * r


@njit(cache=True, **threaded(), fastmath=False)
def _within_plain(i0, i1, p, a, u, length, radius, out):
    r2 = radius * radius  # (the value of _within's r * r with no extra: radius + 0.0 is radius)
    for m in range(i0, i1):
        out[m] = _distance2(p, m, a, u, length) <= r2


@njit(cache=True, **threaded(), fastmath=False)
def _within_scaled(i0, i1, p, scales, factor, a, u, length, radius, out):
    for m in range(i0, i1):
        r = radius + np.float64(factor * max(scales[m, 0], scales[m, 1], scales[m, 2]))
        out[m] = _distance2(p, m, a, u, length) <= r * r


def _segment(positions, a, b):
    """(contiguous float32/float64 positions (N, 3), a (3,) float64, unit axis, length)."""
    p = float_rows(positions)
    a64 = np.asarray(a, np.float64).reshape(3)
    axis = np.asarray(b, np.float64).reshape(3) - a64
    length = float(math.sqrt(float(axis @ axis)))
    u = axis / length if length > 0.0 else np.zeros(3)
    return p, a64, u, length


def within_capsule_scaled(positions, a, b, radius: float, scales, factor: float) -> np.ndarray:
    """``within_capsule(positions, a, b, radius, factor * scales.max(axis=1))`` for float32
    ``scales`` (N, 3) (module docstring), without the (N,) array of reaches."""
    p, a64, u, length = _segment(positions, a, b)
    n = p.shape[0]
    s = np.ascontiguousarray(scales, np.float32).reshape(n, 3)
    out = np.zeros(n, np.bool_)
    run_chunks(_within_scaled, n, p, s, np.float32(factor), a64, u, length, float(radius), out, min_chunk=65536)
    return out


def within_capsule(positions, a, b, radius: float, extra=None) -> np.ndarray:
    """(N,) bool: ``positions`` (N, 3) float32 or float64 within ``radius`` + ``extra`` (N,) (None:
    0) of the segment ``a``-``b`` (3,) (module docstring)."""
    p, a64, u, length = _segment(positions, a, b)
    n = p.shape[0]
    out = np.zeros(n, np.bool_)
    if extra is None:  # (no (N,) array of zeros to make and read)
        run_chunks(_within_plain, n, p, a64, u, length, float(radius), out, min_chunk=65536)
        return out
    ex = np.ascontiguousarray(extra, np.float64).reshape(n)
    run_chunks(_within, n, p, ex, a64, u, length, float(radius), out, min_chunk=65536)
    return out


@njit(cache=True, **threaded(), fastmath=False)
def _block_spheres(b0, b1, p, starts, centres, radii):
    for b in range(b0, b1):
        lo0 = lo1 = lo2 = math.inf
        hi0 = hi1 = hi2 = -math.inf
        for m in range(starts[b], starts[b + 1]):
            x, y, z = np.float64(p[m, 0]), np.float64(p[m, 1]), np.float64(p[m, 2])
            lo0, hi0 = min(lo0, x), max(hi0, x)
            lo1, hi1 = min(lo1, y), max(hi1, y)
            lo2, hi2 = min(lo2, z), max(hi2, z)
        if starts[b + 1] <= starts[b]:
            centres[b, 0] = centres[b, 1] = centres[b, 2] = 0.0
            radii[b] = -1.0  # empty: never straddles
            continue
        centres[b, 0], centres[b, 1], centres[b, 2] = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1), 0.5 * (lo2 + hi2)
        h0, h1, h2 = 0.5 * (hi0 - lo0), 0.5 * (hi1 - lo1), 0.5 * (hi2 - lo2)
        # half the box diagonal, rounded up: every point of the block lies within it of the centre
        radii[b] = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2) * (1.0 + 1e-12)


@njit(cache=True, **threaded(), fastmath=False)
def _within_ball_blocks(b0, b1, p, starts, centres, radii, a, radius, out):
    zero = np.zeros(3)
    r2 = radius * radius
    for b in range(b0, b1):
        s, e = starts[b], starts[b + 1]
        if e <= s:
            continue
        side = _block_side(math.sqrt(_distance2(centres, b, a, zero, 0.0)), radii[b], radius, 0.0, 0.0)
        if side != 0:
            out[s:e] = side > 0
        else:
            for m in range(s, e):
                out[m] = _distance2(p, m, a, zero, 0.0) <= r2


@njit(cache=True, **threaded(), fastmath=False)
def _block_reach(b0, b1, scales, factor, starts, lo, hi):
    for b in range(b0, b1):
        r_lo, r_hi = math.inf, -math.inf
        for m in range(starts[b], starts[b + 1]):
            r = np.float64(factor * max(scales[m, 0], scales[m, 1], scales[m, 2]))  # (_within_scaled's value)
            if not r == r:  # NaN: the block is never decided at once
                r_lo, r_hi = math.nan, math.nan
                break
            r_lo, r_hi = min(r_lo, r), max(r_hi, r)
        lo[b], hi[b] = r_lo, r_hi


@njit(cache=True, **threaded(), fastmath=False)
def _within_scaled_blocks(b0, b1, p, scales, factor, starts, centres, radii, reach_lo, reach_hi, a, u, length,
                          radius, out):
    for b in range(b0, b1):
        s, e = starts[b], starts[b + 1]
        if e <= s:
            continue
        side = _block_side(math.sqrt(_distance2(centres, b, a, u, length)), radii[b], radius, reach_lo[b],
                           reach_hi[b])
        if side != 0:
            out[s:e] = side > 0
        else:
            for m in range(s, e):
                r = radius + np.float64(factor * max(scales[m, 0], scales[m, 1], scales[m, 2]))
                out[m] = _distance2(p, m, a, u, length) <= r * r


def block_reach(scales, starts, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Per block (``starts`` as for :func:`block_spheres`) the least and largest reach ``factor *
    scales.max(axis=1)`` of its points (float32 ``scales`` (N, 3), the value
    :func:`within_capsule_scaled` uses): ``(lo (B,), hi (B,))`` float64; inf / -inf for an empty
    block, NaN for a block with a NaN reach."""
    s = np.ascontiguousarray(scales, np.float32).reshape(-1, 3)
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    nb = max(st.size - 1, 0)
    lo, hi = np.full(nb, np.inf), np.full(nb, -np.inf)
    run_chunks(_block_reach, nb, s, np.float32(factor), st, lo, hi, min_chunk=8)
    return lo, hi


def within_capsule_scaled_blocks(positions, starts, spheres, reach, a, b, radius: float, scales,
                                 factor: float) -> np.ndarray:
    """``within_capsule_scaled(positions, a, b, radius, scales, factor)`` bit for bit, with blocks
    of points (``starts`` and ``spheres`` as :func:`block_spheres` gives them, ``reach`` as
    :func:`block_reach` gives it for these ``scales`` and ``factor``) that lie wholly inside or
    outside every point's capsule decided at once: a block's points are tested one by one only
    where its sphere, widened by its least and largest reach, straddles the capsule's surface (by
    more than a relative 1e-9). Rows outside every block are False."""
    p, a64, u, length = _segment(positions, a, b)
    n = p.shape[0]
    s = np.ascontiguousarray(scales, np.float32).reshape(n, 3)
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    centres, radii = spheres
    out = np.zeros(n, np.bool_)
    run_chunks(_within_scaled_blocks, max(st.size - 1, 0), p, s, np.float32(factor), st,
               np.ascontiguousarray(centres, np.float64), np.ascontiguousarray(radii, np.float64),
               np.ascontiguousarray(reach[0], np.float64), np.ascontiguousarray(reach[1], np.float64), a64, u,
               length, float(radius), out, min_chunk=8)
    return out


def block_spheres(positions, starts) -> tuple[np.ndarray, np.ndarray]:
    """Bounding spheres of contiguous blocks of points: ``positions`` (N, 3), ``starts`` (B+1,)
    int64 increasing block bounds (block b is rows ``starts[b]:starts[b+1]``). Returns ``(centres
    (B, 3), radii (B,))`` float64: the centre of each block's box and half its diagonal (-1 for an
    empty block), an upper bound on every point's distance to the centre."""
    p = float_rows(positions)
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    nb = max(st.size - 1, 0)
    centres, radii = np.zeros((nb, 3)), np.full(nb, -1.0)
    run_chunks(_block_spheres, nb, p, st, centres, radii, min_chunk=8)
    return centres, radii


@njit(cache=True, **threaded(), fastmath=False)
def _block_scale_bound(b0, b1, scales, starts, out):
    for b in range(b0, b1):
        # three running maxima and a NaN flag, without an early exit (the loop vectorises)
        m0 = m1 = m2 = np.float32(0.0)
        nan = False
        for m in range(starts[b], starts[b + 1]):
            s0, s1, s2 = abs(scales[m, 0]), abs(scales[m, 1]), abs(scales[m, 2])
            nan |= (s0 != s0) | (s1 != s1) | (s2 != s2)
            m0 = s0 if s0 > m0 else m0
            m1 = s1 if s1 > m1 else m1
            m2 = s2 if s2 > m2 else m2
        out[b] = math.nan if nan else max(np.float64(m0), max(np.float64(m1), np.float64(m2)))


def block_scale_bound(scales, starts) -> np.ndarray:
    """(B,) float64 largest ``|scale|`` of each block of rows (``starts`` as for :func:`block_spheres`;
    0 for an empty block, NaN for a block with a NaN scale), the rasteriser's cull bound
    (``numba_kernels.rasterize``: its blocks' ``smax``)."""
    s = np.ascontiguousarray(scales, np.float32).reshape(-1, 3)
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    out = np.zeros(max(st.size - 1, 0))
    run_chunks(_block_scale_bound, out.size, s, st, out, min_chunk=8)
    return out


def within_ball_blocks(positions, starts, spheres, centre, radius: float) -> np.ndarray:
    """``within_capsule(positions, centre, centre, radius)`` bit for bit, with blocks of points
    (``starts``, ``spheres`` as :func:`block_spheres` gives them) that lie wholly inside or outside
    the ball decided at once: a block's own test is made only where its sphere straddles the
    ball's boundary (by more than a relative 1e-9, far above the rounding of the per-point test).
    Rows outside every block (before ``starts[0]`` or from ``starts[-1]`` on) are False."""
    p, a64 = float_rows(positions), np.asarray(centre, np.float64).reshape(3)
    st = np.ascontiguousarray(starts, np.int64).reshape(-1)
    centres, radii = spheres
    out = np.zeros(p.shape[0], np.bool_)
    run_chunks(_within_ball_blocks, max(st.size - 1, 0), p, st, np.ascontiguousarray(centres, np.float64),
               np.ascontiguousarray(radii, np.float64), a64, float(radius), out, min_chunk=8)
    return out
