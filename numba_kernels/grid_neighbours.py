"""Uniform-grid spatial hash for fixed-radius neighbourhood queries (numba).

Points are binned into cubic cells of edge ``cell_size`` whose integer coordinates are
``floor((p - origin) / cell_size)`` (``origin`` = the first point). Cells are
hashed into a power-of-two table of ``>= M`` buckets with the classic
``(ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)`` hash, and the point indices are
counting-sorted by bucket (serial, so the layout is deterministic). Each point also keeps its
integer cell so that a query accepts only points of the cell it is visiting: hash collisions
never produce duplicates or wrong candidates, they only cost time.

A query at ``q`` with radius ``r`` visits the ``(2n+1)^3`` cells with ``n = ceil(r / cell_size)``
around ``q``'s cell and keeps point ``j`` when ``inner^2 <= |p_j - q|^2 <= r^2`` (float64
squared distances, summed x, y, z in that order). Choose ``cell_size`` close to the usual
query radius (27 cells visited) for neighbour lists; for counts and sums a fraction of it
(r / 3: 343 cells) pays off, because cells wholly inside the shell (box test with a rounding
margin) are added as pre-summed blocks without visiting their points. Cell coordinates are
clamped to [-2^20, 2^20 - 1] around the origin (the clamp is monotone, so far points stay
exact, they only share overfull edge cells). Units are those of the points; any axis
convention works.

All kernels are pure functions on numpy arrays; queries run in parallel over query points.
Query and point coordinates must be finite (callers check; non-finite values give an empty
neighbourhood, never a crash or NaN).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .jit_options import prange_only, threaded
from .thread_chunks import run_chunks

_P1 = np.int64(73856093)
_P2 = np.int64(19349663)
_P3 = np.int64(83492791)
_COORD_LIMIT = 2.0 ** 20  # cell coordinates are clamped to [-2^20, 2^20 - 1] and packed into one int64
_BIAS = np.int64(2 ** 20)


class HashGrid(NamedTuple):
    """Result of :func:`build_grid`. All arrays are contiguous.

    points: (M, 3) float64 indexed points, permuted into bucket order (``points[t]`` is
        input point ``order[t]``), so that a bucket's points are contiguous in memory.
    origin: (3,) float64; cell_size: float (same units as the points).
    mask: int, table size minus one (table size is a power of two).
    cell_keys: (M,) int64 packed integer cell ``(ix, iy, iz)`` of each point, in bucket order like
        ``points`` (coordinates clamped to [-2^20, 2^20 - 1], 21 bits each).
    bucket_start: (mask + 2,) int64; bucket b holds sorted slots ``bucket_start[b]:bucket_start[b+1]``.
    order: (M,) int64 input index of each sorted slot (ascending inside a bucket).
    pure: (mask + 1,) uint8, 1 where a bucket is non-empty and holds a single cell (no collision).
    """

    points: np.ndarray
    origin: np.ndarray
    cell_size: float
    mask: int
    cell_keys: np.ndarray
    bucket_start: np.ndarray
    order: np.ndarray
    pure: np.ndarray


@njit(inline="always")
def _cell_coord(v, o, inv_cell):
    # Clamping is monotone and never increases |a - b|, so queries stay exact for far-away
    # points (they merely share an overfull edge cell).
    c = np.floor((v - o) * inv_cell)
    if not c >= -_COORD_LIMIT:  # also catches NaN
        c = -_COORD_LIMIT
    elif c > _COORD_LIMIT - 1.0:
        c = _COORD_LIMIT - 1.0
    return np.int64(c)


@njit(inline="always")
def _pack(ix, iy, iz):
    return ((ix + _BIAS) << 42) | ((iy + _BIAS) << 21) | (iz + _BIAS)


@njit(inline="always")
def _hash(ix, iy, iz, mask):
    return ((ix * _P1) ^ (iy * _P2) ^ (iz * _P3)) & mask


@njit(inline="always")
def _cell_of(qx, qy, qz, origin, inv_cell):
    """Integer cell (clamped) of the point (qx, qy, qz)."""
    return (_cell_coord(qx, origin[0], inv_cell), _cell_coord(qy, origin[1], inv_cell),
            _cell_coord(qz, origin[2], inv_cell))


@njit(inline="always")
def _block_cell(cx, cy, cz, n, c, mask):
    """Cell ``c`` of the ``(2n+1)^3`` block around cell (cx, cy, cz), in x, then y, then z order:
    (bucket, packed key, ix, iy, iz); bucket -1 when the cell is outside the clamped range."""
    m = 2 * n + 1
    ix = cx - n + c // (m * m)
    iy = cy - n + (c // m) % m
    iz = cz - n + c % m
    if not (-_BIAS <= ix < _BIAS and -_BIAS <= iy < _BIAS and -_BIAS <= iz < _BIAS):
        return np.int64(-1), np.int64(0), ix, iy, iz
    return _hash(ix, iy, iz, mask), _pack(ix, iy, iz), ix, iy, iz


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _cell_keys(points, origin, inv_cell, mask, cells, keys):
    for i in prange(points.shape[0]):
        ix, iy, iz = _cell_of(points[i, 0], points[i, 1], points[i, 2], origin, inv_cell)
        cells[i] = _pack(ix, iy, iz)
        keys[i] = _hash(ix, iy, iz, mask)


@njit(cache=True, fastmath=False)
def _counting_sort(keys, n_buckets, points, cells):
    """Serial counting sort by bucket; also scatters points and packed cells into bucket order."""
    m = keys.shape[0]
    start = np.zeros(n_buckets + 1, dtype=np.int64)
    for i in range(m):
        start[keys[i] + 1] += 1
    for b in range(n_buckets):
        start[b + 1] += start[b]
    cursor = start[:-1].copy()
    order = np.empty(m, dtype=np.int64)
    spoints = np.empty((m, 3), dtype=np.float64)
    scells = np.empty(m, dtype=np.int64)
    for i in range(m):
        t = cursor[keys[i]]
        cursor[keys[i]] = t + 1
        order[t] = i
        spoints[t, 0] = points[i, 0]
        spoints[t, 1] = points[i, 1]
        spoints[t, 2] = points[i, 2]
        scells[t] = cells[i]
    pure = np.zeros(n_buckets, dtype=np.uint8)
    for b in range(n_buckets):
        if start[b + 1] > start[b]:
            p = 1
            for t in range(start[b] + 1, start[b + 1]):
                if scells[t] != scells[start[b]]:
                    p = 0
                    break
            pure[b] = p
    return start, order, spoints, scells, pure


def build_grid(points: np.ndarray, cell_size: float, origin=None, min_buckets: int = 0) -> HashGrid:
    """Index ``points`` (M, 3) (any float dtype, finite) into a spatial hash of cell edge ``cell_size`` > 0.

    origin: (3,) corner of cell (0, 0, 0) (default: the first point). The table has the smallest
    power-of-two number of buckets >= max(M, ``min_buckets``).
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    cell_size = float(cell_size)
    if not (cell_size > 0.0 and np.isfinite(cell_size)):
        raise ValueError(f"cell_size must be a positive finite number, got {cell_size}")
    m = pts.shape[0]
    n_buckets = 1
    while n_buckets < max(m, int(min_buckets)):
        n_buckets *= 2
    mask = n_buckets - 1
    if origin is None:
        # any origin works (cells may be negative); the first point is free, unlike a strided min()
        origin = pts[0].copy() if m else np.zeros(3)
    else:
        origin = np.array(origin, dtype=np.float64).reshape(3)
    origin = np.where(np.isfinite(origin), origin, 0.0)
    cells = np.empty(m, dtype=np.int64)
    keys = np.empty(m, dtype=np.int64)
    _cell_keys(pts, origin, 1.0 / cell_size, np.int64(mask), cells, keys)
    start, order, spoints, scells, pure = _counting_sort(keys, n_buckets, pts, cells)
    return HashGrid(spoints, origin, cell_size, mask, scells, start, order, pure)


@njit(cache=True, fastmath=False)
def neighbour_slots(points, origin, cell_size, mask, cell_keys, bucket_start, qx, qy, qz, radius, skip, buf):
    """Grid slots ``t`` (indices into ``HashGrid.points``, bucket order) of the points with
    ``|points[t] - q|^2 <= radius^2``, ``t != skip``, written to ``buf`` in visiting order (cells by
    x, then y, then z coordinate, ascending; a cell's points in slot order); returns how many
    (at most ``len(buf)``: further neighbours are ignored). Called from other kernels, one query
    point at a time (``skip``: the query's own slot, or -1); the array arguments are the
    :class:`HashGrid` fields. Visits the 27 cells around q's cell when ``radius <= cell_size``."""
    inv = 1.0 / cell_size
    r2 = radius * radius
    n = np.int64(1) if radius <= cell_size else np.int64(np.ceil(radius * inv))
    cx, cy, cz = _cell_of(qx, qy, qz, origin, inv)
    cnt = 0
    for c in range((2 * n + 1) ** 3):
        b, key, _, _, _ = _block_cell(cx, cy, cz, n, c, mask)
        if b < 0:
            continue
        for t in range(bucket_start[b], bucket_start[b + 1]):
            dx = points[t, 0] - qx
            dy = points[t, 1] - qy
            dz = points[t, 2] - qz
            # distance first (cheap, vectorisable); the exact cell check then drops points
            # reached twice through colliding hashes
            if dx * dx + dy * dy + dz * dz <= r2 and cell_keys[t] == key and t != skip:
                if cnt < buf.shape[0]:
                    buf[cnt] = t
                    cnt += 1
    return cnt


@njit(cache=True, fastmath=False)
def _visit(points, origin, inv_cell, cell_size, mask, coords, start, order, pure, qx, qy, qz, r2, in2,
           values, bsum, out_idx, mode):
    """Visit the neighbours of (qx, qy, qz); mode 0: count, 1: write input indices, 2: sum values.

    ``values`` are per point in bucket order. Returns (count, sum). In mode 1 indices are
    written to ``out_idx`` from position 0. Modes 0 and 2 take a cell whole (``bsum[b]``:
    sum of the bucket's values, bucket count from ``start``) when its box, widened by a
    rounding margin, lies entirely inside the shell and its bucket holds no other cell; cells
    entirely outside are skipped; the rest are scanned point by point. Counts are therefore
    exact; sums equal brute force up to summation order.
    """
    n = np.int64(np.ceil(np.sqrt(r2) * inv_cell))
    cx, cy, cz = _cell_of(qx, qy, qz, origin, inv_cell)
    count = np.int64(0)
    total = 0.0
    if not (np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz)):
        return count, total
    for c in range((2 * n + 1) ** 3):
        b, key, ix, iy, iz = _block_cell(cx, cy, cz, n, c, mask)
        if b < 0 or start[b + 1] == start[b]:
            continue
        if mode != 1 and ix > -_BIAS and iy > -_BIAS and iz > -_BIAS and \
                ix < _BIAS - 1 and iy < _BIAS - 1 and iz < _BIAS - 1:
            # min / max squared distance from q to the cell box widened by a margin that
            # covers floor() rounding of the cell assignment
            mind2 = 0.0
            maxd2 = 0.0
            for ax in range(3):
                qa = qx if ax == 0 else (qy if ax == 1 else qz)
                ia = ix if ax == 0 else (iy if ax == 1 else iz)
                lo = origin[ax] + ia * cell_size
                hi = lo + cell_size
                tol = 1e-6 * cell_size + 1e-14 * (abs(lo) + abs(hi) + abs(qa))
                lo -= tol
                hi += tol
                dlo = qa - lo
                dhi = hi - qa
                if dlo < 0.0:
                    mind2 += dlo * dlo
                elif dhi < 0.0:
                    mind2 += dhi * dhi
                far = max(abs(dlo), abs(dhi))
                maxd2 += far * far
            if mind2 > r2 or maxd2 < in2:
                continue  # entirely outside the shell
            if pure[b] == 1 and coords[start[b]] == key and maxd2 <= r2 and mind2 >= in2:
                count += start[b + 1] - start[b]
                if mode == 2:
                    total += bsum[b]
                continue
        for t in range(start[b], start[b + 1]):
            if coords[t] != key:
                continue
            dx = points[t, 0] - qx
            dy = points[t, 1] - qy
            dz = points[t, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= r2 and d2 >= in2:
                if mode == 1:
                    out_idx[count] = order[t]
                elif mode == 2:
                    total += values[t]
                count += 1
    return count, total


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _bucket_sums(values, start):
    nb = start.shape[0] - 1
    out = np.zeros(nb)
    for b in prange(nb):
        acc = 0.0
        for t in range(start[b], start[b + 1]):
            acc += values[t]
        out[b] = acc
    return out


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def _query_kernel(points, origin, cell_size, mask, coords, start, order, pure, queries, qorder, radius, inner,
                  values, bsum, mode):
    """mode 0: counts; 2: sums and counts. Returns (counts (Q,) int64, sums (Q,) float64)."""
    q = queries.shape[0]
    counts = np.zeros(q, dtype=np.int64)
    sums = np.zeros(q, dtype=np.float64)
    inv = 1.0 / cell_size
    r2 = radius * radius
    in2 = inner * inner
    seg = np.empty(0, dtype=np.int64)
    for ii in prange(q):
        i = qorder[ii]
        c, s = _visit(points, origin, inv, cell_size, mask, coords, start, order, pure,
                      queries[i, 0], queries[i, 1], queries[i, 2], r2, in2, values, bsum, seg, mode)
        counts[i] = c
        sums[i] = s
    return counts, sums


@njit(parallel=prange_only(), cache=True, fastmath=False)
def _list_kernel(points, origin, cell_size, mask, coords, start, order, pure, queries, qorder, radius, inner,
                 offsets):
    """Neighbour lists (mode 1 of ``_visit``): fills and returns ``out`` (offsets[Q],) int64,
    sorted per query. A separate kernel so that count/sum users never compile the sort."""
    q = queries.shape[0]
    out = np.empty(offsets[q], dtype=np.int64)
    inv = 1.0 / cell_size
    r2 = radius * radius
    in2 = inner * inner
    nov = np.zeros(0)
    for ii in prange(q):
        i = qorder[ii]
        seg = out[offsets[i]:offsets[i + 1]]
        _visit(points, origin, inv, cell_size, mask, coords, start, order, pure,
               queries[i, 0], queries[i, 1], queries[i, 2], r2, in2, nov, nov, seg, 1)
        seg.sort()
    return out


def _queries(grid, queries):
    """Queries as (Q, 3) float64 plus a visiting order sorted by bucket (memory locality)."""
    q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
    cells = np.empty(q.shape[0], dtype=np.int64)
    keys = np.empty(q.shape[0], dtype=np.int64)
    _cell_keys(q, grid.origin, 1.0 / grid.cell_size, np.int64(grid.mask), cells, keys)
    return q, np.argsort(keys, kind="stable")


def _check_radii(radius, inner):
    radius, inner = float(radius), float(inner)
    if not (radius >= 0.0 and np.isfinite(radius)) or not (0.0 <= inner <= radius):
        raise ValueError(f"need 0 <= inner ({inner}) <= radius ({radius}) < inf")
    return radius, inner


def _run(grid, queries, radius, inner, mode, values=None, offsets=None):
    g = grid
    q, qorder = _queries(g, queries)
    args = (g.points, g.origin, g.cell_size, np.int64(g.mask), g.cell_keys, g.bucket_start, g.order, g.pure, q,
            qorder, radius, inner)
    if mode == 1:
        return None, None, _list_kernel(*args, offsets)
    vals = np.zeros(0) if values is None else values.values
    bsum = np.zeros(0) if values is None else values.bucket_sums
    counts, sums = _query_kernel(*args, vals, bsum, mode)
    return counts, sums, None


def radius_count(grid: HashGrid, queries: np.ndarray, radius: float, inner: float = 0.0) -> np.ndarray:
    """Number of indexed points with ``inner <= |p - q| <= radius`` for each query (Q, 3). Returns (Q,) int64."""
    radius, inner = _check_radii(radius, inner)
    return _run(grid, queries, radius, inner, 0)[0]


class GridValues(NamedTuple):
    """Per-point values prepared for :func:`radius_sum`: ``values`` (M,) float64 in bucket order
    and ``bucket_sums`` (mask + 1,) float64. Build once with :func:`grid_values` to reuse them."""

    values: np.ndarray
    bucket_sums: np.ndarray


def grid_values(grid: HashGrid, values: np.ndarray) -> GridValues:
    """Reorder ``values`` (M,) (one per indexed point, input order) for repeated :func:`radius_sum` calls."""
    vals = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    if vals.shape[0] != grid.points.shape[0]:
        raise ValueError(f"values has {vals.shape[0]} entries, the grid has {grid.points.shape[0]} points")
    sorted_vals = np.ascontiguousarray(vals[grid.order])
    return GridValues(sorted_vals, _bucket_sums(sorted_vals, grid.bucket_start))


def radius_sum(grid: HashGrid, queries: np.ndarray, radius: float, values,
               inner: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Sum of ``values`` and count over the points with ``inner <= |p - q| <= radius``.

    ``values``: (M,) array in input order, or a :class:`GridValues` from :func:`grid_values`.
    Returns ``(sums (Q,) float64, counts (Q,) int64)``. Deterministic run to run; equal to a
    brute-force sum up to float64 summation order (whole cells are added as pre-summed blocks).
    """
    radius, inner = _check_radii(radius, inner)
    gv = values if isinstance(values, GridValues) else grid_values(grid, values)
    counts, sums, _ = _run(grid, queries, radius, inner, 2, values=gv)
    return sums, counts


def radius_neighbours(grid: HashGrid, queries: np.ndarray, radius: float,
                      inner: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """All neighbours with ``inner <= |p - q| <= radius`` as CSR.

    Returns ``(offsets (Q+1,) int64, indices (offsets[-1],) int64)``; the neighbours of query
    i are ``indices[offsets[i]:offsets[i+1]]`` sorted ascending.
    """
    radius, inner = _check_radii(radius, inner)
    counts = _run(grid, queries, radius, inner, 0)[0]
    offsets = np.zeros(counts.shape[0] + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, _run(grid, queries, radius, inner, 1, offsets=offsets)[2]


def nearest(points: np.ndarray, queries: np.ndarray, radius: float | None = None) -> np.ndarray:
    """(Q,) int64 index of the nearest of ``points`` (M >= 1, finite) to each query (finite), by
    float64 squared distance; ties go to the lower index. Searches a hash grid within ``radius``
    (default: the points' bounding-box diagonal over sqrt(M), about their spacing on a surface)
    and doubles the radius for the queries with no point inside until every query has one."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        raise ValueError("nearest: no points")
    out = np.full(q.shape[0], -1, np.int64)
    if radius is None:
        diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        radius = diag / np.sqrt(pts.shape[0])
    r = max(float(radius), 1e-9)
    todo = np.arange(q.shape[0])
    while todo.size:
        grid = build_grid(pts, r)
        offsets, idx = radius_neighbours(grid, q[todo], r)
        run_chunks(_nearest_of_lists, todo.size, offsets, idx, pts, q, todo, out, min_chunk=4096)
        todo = todo[out[todo] < 0]
        r *= 2.0
    return out


@njit(**threaded(), cache=True, fastmath=False)
def _nearest_of_lists(i0, i1, offsets, idx, pts, q, todo, out):
    """``out[todo[i]]`` for ``i`` in ``i0..i1-1`` (run in threads by ``thread_chunks.run_chunks``): the
    entry of neighbour list i (``idx[offsets[i]:offsets[i+1]]``, ascending) nearest to query
    ``q[todo[i]]`` by float64 squared distance, the first (lowest index) of equal ones; lists that
    are empty leave ``out`` as it is."""
    for i in range(i0, i1):
        k = todo[i]
        best = -1
        best_d2 = np.inf
        for t in range(offsets[i], offsets[i + 1]):
            j = idx[t]
            dx = pts[j, 0] - q[k, 0]
            dy = pts[j, 1] - q[k, 1]
            dz = pts[j, 2] - q[k, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best_d2:
                best_d2 = d2
                best = j
        if best >= 0:
            out[k] = best
