"""Passes over the SH arrays the output layer is written from (``usd_gs.usd.output_author``).

- :func:`half_bits`: float32 -> IEEE 754 binary16 bit patterns, round to nearest, ties to even,
  as ``numpy.ndarray.astype(np.float16)`` gives them bit for bit: overflow (``|x| >= 65520``) to
  signed infinity, subnormal halves below ``2**-14``, signed zero below ``2**-25`` (``2**-25``
  itself is a tie and goes to the even zero), infinities kept, NaN kept as a NaN with the top ten
  bits of its payload (at least one bit set) and its sign.
- :func:`half_bits_where`: the same conversion for the rows a mask selects, the other rows copied
  from a given half array (the unaffected SH of a prim whose rows mostly did not move).
- :func:`half_segments_equal`: per flat segment of two float16 arrays, whether all its elements are
  equal (IEEE: ``-0 == +0``, a NaN equals nothing), stopping at the first difference.
- :func:`row_display_changes`: per row ``n`` of two SH sets (N, K, 3) in the 3DGS basis, the
  bound ``max_c sum_k |a[n, k, c] - b[n, k, c]| ymax_k`` of the largest display-colour change over
  all view directions, ``ymax_k = sqrt((2 l_k + 1) / (4 pi))`` (``max_d |Y_lm(d)|``), the difference
  taken in float32 as the arrays hold it and summed in float64. One pass, no temporaries.

The kernels are serial ``nogil`` loops that ``thread_chunks.run_chunks`` runs on row ranges in
threads, or (``threads=False``) whole in the calling thread (the results do not depend on it).
References: numpy's cast and the numpy form of the bound (``numba_kernels/reference/sh_output.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import read_only, threaded
from .thread_chunks import run_chunks

_MIN_CHUNK = 1 << 16  # elements (or rows) per range: a range costs a thread-pool round trip


@njit(cache=True, fastmath=False, inline="always")
def _half(f):
    """The binary16 bits (as int64) of the float32 with bits ``f`` (module docstring)."""
    sign = (f >> 16) & 0x8000
    a = f & 0x7FFFFFFF
    if a >= 0x7F800000:  # infinity or NaN
        if a == 0x7F800000:
            return sign | 0x7C00
        payload = (a & 0x7FFFFF) >> 13
        return sign | 0x7C00 | (payload if payload else 1)
    if a >= 0x477FF000:  # 65520 and above round to infinity (65520 is a tie; 65504 is odd)
        return sign | 0x7C00
    if a >= 0x38800000:  # a normal half: rebias the exponent (127 - 15 = 112) and round 13 bits away
        m = a - 0x38000000
        h = m >> 13
        rest = m & 0x1FFF
        if rest > 0x1000 or (rest == 0x1000 and (h & 1)):
            h += 1  # (a carry into the exponent is the right result, up to 65504)
        return sign | h
    if a >= 0x33000000:  # 2**-25 <= |x| < 2**-14: a subnormal half (or the smallest normal by rounding)
        shift = 126 - (a >> 23)  # 14..24: the half's significand is mant * 2**(e - 126)
        mant = (a & 0x7FFFFF) | 0x800000
        h = mant >> shift
        rest = mant & ((1 << shift) - 1)
        tie = 1 << (shift - 1)
        if rest > tie or (rest == tie and (h & 1)):
            h += 1
        return sign | h
    return sign  # below 2**-25 (or exactly: a tie, to the even zero)


@njit(cache=True, **threaded(), fastmath=False)
def _half_bits(i0_, i1_, src, dst):
    for i in range(i0_, i1_):
        dst[i] = _half(np.int64(src[i]))


@njit(cache=True, **threaded(), fastmath=False)
def _half_bits_where(i0_, i1_, rows, src, other, width, dst):
    """Rows ``i0_..i1_-1`` of width ``width``: converted from ``src`` where ``rows`` is True, else
    copied from ``other`` (all flat)."""
    for r in range(i0_, i1_):
        a = r * width
        if rows[r]:
            for i in range(a, a + width):
                dst[i] = _half(np.int64(src[i]))
        else:
            for i in range(a, a + width):
                dst[i] = other[i]


@njit(cache=True, fastmath=False, inline="always")
def _half_equal(x, y):
    """IEEE equality of two binary16 values given by their bits: -0 == +0, a NaN equals nothing."""
    if (x & 0x7C00) == 0x7C00 and (x & 0x3FF) != 0:
        return False
    if (y & 0x7C00) == 0x7C00 and (y & 0x3FF) != 0:
        return False
    return x == y or ((x | y) & 0x7FFF) == 0


@njit(cache=True, **threaded(), fastmath=False)
def _half_segments_equal(i0_, i1_, x, y, starts, ends, out):
    for s in range(i0_, i1_):
        same = True
        for i in range(starts[s], ends[s]):
            if not _half_equal(x[i], y[i]):
                same = False
                break
        out[s] = same


def half_segments_equal(x: np.ndarray, y: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                        threads: bool = True) -> np.ndarray:
    """(P,) bool: ``(x[a:b] == y[a:b]).all()`` for each flat segment ``a, b`` of ``starts``, ``ends``
    ((P,) ints) of the float16 arrays ``x``, ``y`` (same shape; IEEE equality: ``-0 == +0``, a NaN
    equals nothing; an empty segment is equal); stops at a segment's first difference."""
    x, y = np.ascontiguousarray(x), np.ascontiguousarray(y)
    if x.dtype != np.float16 or y.dtype != np.float16 or x.shape != y.shape:
        raise ValueError(f"half_segments_equal: two float16 arrays of one shape, got {x.dtype} {x.shape}, "
                         f"{y.dtype} {y.shape}")
    starts = np.ascontiguousarray(starts, np.int64)
    ends = np.ascontiguousarray(ends, np.int64)
    out = np.empty(starts.shape[0], np.bool_)
    run_chunks(_half_segments_equal, starts.shape[0], read_only(x.reshape(-1).view(np.uint16)),
               read_only(y.reshape(-1).view(np.uint16)), starts, ends, out, threads=threads)
    return out


def _float32_bits(x: np.ndarray) -> np.ndarray:
    x = np.ascontiguousarray(x)
    if x.dtype != np.float32:
        raise TypeError(f"half conversion: expected float32, got {x.dtype}")
    return read_only(x.reshape(-1).view(np.uint32))


def half_bits(x: np.ndarray, threads: bool = True) -> np.ndarray:
    """``x`` (float32, any shape) as float16 of the same shape, bit for bit ``x.astype(np.float16)``
    (module docstring)."""
    src = _float32_bits(x)
    dst = np.empty(src.size, np.uint16)
    run_chunks(_half_bits, src.size, src, dst, threads=threads, min_chunk=_MIN_CHUNK)
    return dst.view(np.float16).reshape(np.shape(x))


def half_bits_where(rows: np.ndarray, x: np.ndarray, other: np.ndarray, threads: bool = True) -> np.ndarray:
    """float16 array shaped like ``x`` (float32, (N, ...)): row ``n`` is ``x[n].astype(np.float16)``
    where ``rows[n]`` (N,) bool, else ``other[n]`` (float16, shaped like ``x``)."""
    rows = np.ascontiguousarray(rows, np.bool_)
    src = _float32_bits(x)
    other = np.ascontiguousarray(other)
    if other.dtype != np.float16 or other.shape != np.shape(x) or rows.shape != (np.shape(x)[0],):
        raise ValueError(f"half_bits_where: rows {rows.shape}, x {np.shape(x)}, other {other.shape} {other.dtype}")
    n = rows.shape[0]
    width = src.size // n if n else 0
    dst = np.empty(src.size, np.uint16)
    run_chunks(_half_bits_where, n, rows, src, read_only(other.reshape(-1).view(np.uint16)), width, dst,
               threads=threads, min_chunk=max(1, _MIN_CHUNK // max(width, 1)))
    return dst.view(np.float16).reshape(np.shape(x))


@njit(cache=True, **threaded(), fastmath=False)
def _row_display_changes(i0_, i1_, a, b, ymax, rows, out):
    k = a.shape[1]
    every = rows.shape[0] == 0
    for n in range(i0_, i1_):
        best = 0.0
        if not (every or rows[n]):
            out[n] = 0.0
            continue
        for c in range(3):
            s = 0.0
            for j in range(k):
                s += abs(np.float64(a[n, j, c] - b[n, j, c])) * ymax[j]
            if s > best:
                best = s
        out[n] = best


def display_bounds(k: int) -> np.ndarray:
    """(k,) float64 ``max_d |Y_k(d)| = sqrt((2 l + 1) / (4 pi))`` of the first ``k`` SH coefficients
    (coefficient ``i`` is in band ``l = floor(sqrt(i))``; any ``k``, not only a whole degree's)."""
    bands = np.floor(np.sqrt(np.arange(k)))
    return np.sqrt((2.0 * bands + 1.0) / (4.0 * math.pi))


def row_display_changes(a: np.ndarray, b: np.ndarray, rows: np.ndarray | None = None,
                        threads: bool = True) -> np.ndarray:
    """(N,) float32: the display-change bound of each row of ``a``, ``b`` ((N, K, 3), converted to
    float32 when they are not; module docstring); ``rows`` (N,) bool: only those rows, 0 for the
    others (rows known to be equal)."""
    a = read_only(np.ascontiguousarray(a, np.float32))
    b = read_only(np.ascontiguousarray(b, np.float32))
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"row_display_changes: two (N, K, 3) arrays, got {a.shape} and {b.shape}")
    rows = np.zeros(0, np.bool_) if rows is None else np.ascontiguousarray(rows, np.bool_)
    if rows.size and rows.shape != (a.shape[0],):
        raise ValueError(f"row_display_changes: rows must be ({a.shape[0]},), got {rows.shape}")
    out = np.empty(a.shape[0], np.float32)
    run_chunks(_row_display_changes, a.shape[0], a, b, display_bounds(a.shape[1]), rows, out, threads=threads,
               min_chunk=max(1, _MIN_CHUNK // max(a.shape[1] * 3, 1)))
    return out
