"""The sun lattice's lookup kernels (numba_kernels.lattice_lookup) against their numpy forms, bit
for bit: negative lattice coordinates, points on pixel and block edges, depths before the first
and past the last bin, corners whose columns are missing, and a hand-computed blend."""

import numpy as np

from numba_kernels.dgsm_directional import light_basis
from numba_kernels.lattice_lookup import (
    CORNERS,
    lattice_interpolate,
    lattice_interpolate_numpy,
    lattice_stencils,
    lattice_stencils_numpy,
)
from usd_gs.shadows.lattice_index import BLOCK, LatticeIndex


def _lattice(rng, basis, h, n):
    """Points spread over negative and positive lattice coordinates (some exactly on pixel edges,
    some before the first bin and past the last) and an index holding a random half of the pixels
    their stencils need."""
    pts = rng.uniform(-3.0, 3.0, (n, 3))
    # exactly on pixel edges (fx = i + 0 after the half-pixel shift) and on a block edge
    on_edge = (np.array([0.5, BLOCK + 0.5, -BLOCK + 0.5, -0.5]) * h)
    pts[: len(on_edge)] = on_edge[:, None] * basis[0] + on_edge[:, None] * basis[1]
    pts[10:20] += 50.0 * basis[2]  # past the last bin
    pts[20:30] -= 50.0 * basis[2]  # before the first
    index = LatticeIndex()
    fx = pts @ basis[0] / h - 0.5
    fy = pts @ basis[1] / h - 0.5
    need = np.unique(np.concatenate([np.stack([np.floor(fx) + di, np.floor(fy) + dj], 1)
                                     for di, dj in CORNERS]).astype(np.int64), axis=0)
    keep = need[rng.random(len(need)) < 0.5]
    index.insert(keep, rng.permutation(len(keep)).astype(np.int64))
    return pts, index


def test_stencils_and_blend_equal_the_numpy_forms_bit_for_bit():
    rng = np.random.default_rng(3)
    basis = light_basis(np.array([0.3, -0.8, -0.5]))
    h, tb, ds, K = 0.013, -2.5, 0.07, 48
    c = np.zeros(3)  # (the sun atlas's reference point)
    pts, index = _lattice(rng, basis, h, 20000)
    got = lattice_stencils(pts, c, basis, h, tb, ds, K, *index.arrays())
    want = lattice_stencils_numpy(pts, c, basis, h, tb, ds, K, index.lookup)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    ij0, w, k0, rows = got
    edge = np.minimum(w[:4, :2], 1.0 - w[:4, :2])  # the points put on pixel edges: a weight of 0 or 1
    assert (edge < 1e-12).all() and (w[:4, :2] == 0.0).any()
    assert (rows < 0).any() and (rows >= 0).any() and (ij0 < 0).any()
    assert k0.min() == 0 and k0.max() == K - 2 and w[:, 2].min() == 0.0 and w[:, 2].max() == 1.0
    # the blend, every corner present (missing ones given rows of their own)
    rows = rows.copy()
    miss = rows < 0
    rows[miss] = len(index.arrays()[2]) + np.arange(int(miss.sum()))
    store = rng.random((int(rows.max()) + 1, K)).astype(np.float32)
    got = lattice_interpolate(rows, store, k0, w)
    want = lattice_interpolate_numpy(rows, store, k0, w)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    # a reference point off the origin
    c2 = np.array([0.2, -0.1, 0.05])
    for a, b in zip(lattice_stencils(pts, c2, basis, h, tb, ds, K, *index.arrays()),
                    lattice_stencils_numpy(pts, c2, basis, h, tb, ds, K, index.lookup), strict=True):
        np.testing.assert_array_equal(a, b)


def test_blend_of_one_point_by_hand():
    """Weights (wx, wy, wk) = (0.25, 0.5, 0.75) over eight known voxels."""
    K = 4
    store = np.zeros((4, K), np.float32)
    for n in range(4):
        store[n, 1], store[n, 2] = 0.1 * (n + 1), 0.2 * (n + 1)
    rows = np.arange(4, dtype=np.int64).reshape(4, 1)
    w = np.array([[0.25, 0.5, 0.75]])
    t, spread = lattice_interpolate(rows, store, np.array([1], np.int64), w)
    wij = [0.75 * 0.5, 0.75 * 0.5, 0.25 * 0.5, 0.25 * 0.5]  # CORNERS: (0,0), (0,1), (1,0), (1,1)
    v1 = store[:, 1].astype(np.float64)
    v2 = store[:, 2].astype(np.float64)
    expect = sum(wij[n] * (0.25 * v1[n] + 0.75 * v2[n]) for n in range(4))
    assert abs(t[0] - expect) < 1e-15
    assert abs(spread[0] - (v2.max() - v1.min())) < 1e-15


def test_no_points():
    index = LatticeIndex()
    basis = light_basis(np.array([0.0, 0.0, -1.0]))
    ij0, w, k0, rows = lattice_stencils(np.zeros((0, 3)), np.zeros(3), basis, 0.1, 0.0, 0.1, 8,
                                        *index.arrays())
    assert ij0.shape == (0, 2) and rows.shape == (4, 0)
    t, spread = lattice_interpolate(rows, np.ones((0, 8), np.float32), k0, w)
    assert t.shape == (0,) and spread.shape == (0,)
