"""The spatial-hash radius queries against brute-force distance matrices."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels.grid_neighbours import build_grid, radius_count, radius_neighbours, radius_sum
from numba_kernels.reference.grid_neighbours import within as _brute


@pytest.mark.parametrize("cell, radius, inner", [(0.2, 0.2, 0.0), (0.2, 0.25, 0.05), (0.05, 0.17, 0.0),
                                                 (0.5, 0.1, 0.02), (0.3, 0.0, 0.0), (0.1, 0.3, 0.1)])
def test_matches_brute_force(cell, radius, inner):
    rng = np.random.default_rng(1)
    points = np.concatenate([rng.uniform(-1, 1, (1500, 3)), rng.normal(0.3, 0.02, (300, 3))])
    points[:50] = points[50:100]  # exact duplicates
    queries = np.concatenate([rng.uniform(-1.3, 1.3, (200, 3)), points[:40]])  # also outside the box, on points
    g = build_grid(points, cell)
    mask = _brute(points, queries, radius, inner)
    off, idx = radius_neighbours(g, queries, radius, inner)
    assert off[-1] == mask.sum()
    for i in range(queries.shape[0]):
        np.testing.assert_array_equal(idx[off[i]:off[i + 1]], np.flatnonzero(mask[i]))
    np.testing.assert_array_equal(radius_count(g, queries, radius, inner), mask.sum(1))
    vals = rng.normal(size=points.shape[0])
    sums, counts = radius_sum(g, queries, radius, vals, inner)
    np.testing.assert_array_equal(counts, mask.sum(1))
    np.testing.assert_allclose(sums, (mask * vals).sum(1), rtol=1e-12, atol=1e-12)


def test_far_points_and_clamped_cells():
    """Points far beyond the +-2^20 cell range share clamped edge cells but are still found exactly."""
    rng = np.random.default_rng(2)
    points = np.concatenate([rng.uniform(0, 1, (200, 3)), 1e9 + rng.uniform(0, 0.01, (20, 3)),
                             -1e9 + rng.uniform(0, 0.01, (20, 3))])
    queries = np.concatenate([points[:5], points[200:205], points[220:225]])
    g = build_grid(points, 0.01)
    off, idx = radius_neighbours(g, queries, 0.02)
    mask = _brute(points, queries, 0.02)
    for i in range(queries.shape[0]):
        np.testing.assert_array_equal(idx[off[i]:off[i + 1]], np.flatnonzero(mask[i]))
    assert all(off[i + 1] - off[i] >= 1 for i in range(queries.shape[0]))


def test_empty_and_nonfinite_queries():
    g = build_grid(np.zeros((0, 3)), 0.1)
    off, idx = radius_neighbours(g, np.zeros((3, 3)), 1.0)
    np.testing.assert_array_equal(off, [0, 0, 0, 0])
    assert idx.size == 0
    g = build_grid(np.zeros((4, 3)), 0.1)
    counts = radius_count(g, np.array([[0.0, 0, 0], [np.nan, 0, 0], [np.inf, 0, 0]]), 0.5)
    np.testing.assert_array_equal(counts, [4, 0, 0])
    with pytest.raises(ValueError):
        build_grid(np.zeros((4, 3)), 0.0)
    with pytest.raises(ValueError):
        radius_count(g, np.zeros((1, 3)), 0.1, inner=0.2)


def test_deterministic_sums():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 1, (5000, 3))
    vals = rng.normal(size=5000)
    g = build_grid(points, 0.1)
    a = radius_sum(g, points[:500], 0.1, vals)
    b = radius_sum(build_grid(points, 0.1), points[:500], 0.1, vals)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@pytest.mark.parametrize("radius", [None, 1e-4, 5.0])
def test_nearest_matches_the_dense_reference(radius):
    from numba_kernels import grid_neighbours
    from numba_kernels.reference import grid_neighbours as ref

    rng = np.random.default_rng(7)
    pts = rng.normal(size=(300, 3))
    pts[:50] = pts[0]  # duplicates: the tie goes to the lower index
    queries = np.concatenate([rng.normal(size=(500, 3)) * 2.0, pts[:60], [[40.0, 0.0, 0.0]]])
    got = grid_neighbours.nearest(pts, queries, radius)
    np.testing.assert_array_equal(got, ref.nearest(pts, queries))
