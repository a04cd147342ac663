"""Octahedral atlas: eq. 6, round trips, seams, poles, fold corners, wrap continuity."""

import numpy as np
import pytest

from numba_kernels import octahedral as oc
from numba_kernels.reference import octahedral as reference

SPECIAL = np.array([
    [0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],  # poles and equator axes
    [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0],  # equator diagonals (fold seam)
    [1, 0, -1], [0, 1, -1], [-1, 0, -1], [0, -1, -1], [1, 0, 1], [0, 1, 1],  # octant seams
    [1, 1, -1], [-1, -1, -1], [1e-12, 0, -1], [0, 1e-12, -1], [-1e-12, -1e-12, -1],  # near the fold corners
], float)


def test_encode_matches_equation_6_and_roundtrip():
    rng = np.random.default_rng(0)
    d = np.concatenate([SPECIAL, rng.normal(size=(2000, 3))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    uv = oc.encode(d)
    ref = np.array([reference.encode(x) for x in d])
    np.testing.assert_allclose(uv, ref, atol=1e-15)
    assert np.all(np.abs(uv) <= 1.0)
    np.testing.assert_allclose(oc.decode(uv), d, atol=1e-14)


def test_poles_and_corners():
    uv = oc.encode(np.array([[0, 0, 1.0], [0, 0, -1.0]]))
    np.testing.assert_array_equal(uv[0], [0, 0])
    assert np.abs(uv[1]).tolist() == [1.0, 1.0]
    for corner in ([1, 1], [1, -1], [-1, 1], [-1, -1]):
        np.testing.assert_allclose(oc.decode(np.array([corner], float))[0], [0, 0, -1], atol=1e-15)


def test_edge_points_mirror_across_edge_midpoint():
    # (1, v) and (1, -v) are the same direction: the fold identifies them
    v = np.linspace(-1, 1, 21)
    a = oc.decode(np.stack([np.ones_like(v), v], 1))
    b = oc.decode(np.stack([np.ones_like(v), -v], 1))
    np.testing.assert_allclose(a, b, atol=1e-15)
    a = oc.decode(np.stack([v, -np.ones_like(v)], 1))
    b = oc.decode(np.stack([-v, -np.ones_like(v)], 1))
    np.testing.assert_allclose(a, b, atol=1e-15)


@pytest.mark.parametrize("w", [8, 16, 64])
def test_wrapped_neighbours_are_angular_neighbours(w):
    """For every pixel, the fold-wrapped neighbour at +-1 in i or j is close on the sphere:
    a pixel beyond the edge continues the sphere (the wrap rule), corners included."""
    dirs = oc.pixel_directions(w)
    step = np.pi / w * 2.2  # generous bound on the angular pixel pitch
    ii, jj = np.meshgrid(np.arange(w), np.arange(w), indexing="ij")
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)):
        nb = oc.wrap(np.stack([(ii + di).ravel(), (jj + dj).ravel()], 1), w)
        assert np.all((nb >= 0) & (nb < w))
        ang = np.arccos(np.clip(np.sum(dirs.reshape(-1, 3) * dirs[nb[:, 0], nb[:, 1]], axis=1), -1, 1))
        assert ang.max() < step * (1.5 if di and dj else 1.0)


def test_wrap_rule_in_pixels():
    w = 8
    np.testing.assert_array_equal(oc.wrap(np.array([[8, 2], [-1, 2], [3, 8], [3, -1], [8, 8], [-1, -1]]), w),
                                  [[7, 5], [0, 5], [4, 7], [4, 0], [0, 0], [7, 7]])
    # a pixel beyond the edge decodes (through the continuous uv formula) to its wrapped pixel's direction
    dirs = oc.pixel_directions(w)
    for i, j in ((8, 2), (-1, 5), (3, 8), (6, -1)):
        u, v = (2 * i + 1) / w - 1, (2 * j + 1) / w - 1
        # map the out-of-square uv through the fold formula of the module doc
        u, v = reference.fold_uv(u, v)
        wi, wj = oc.wrap(np.array([[i, j]]), w)[0]
        np.testing.assert_allclose(oc.decode(np.array([[u, v]]))[0], dirs[wi, wj], atol=1e-14)


def test_lipschitz_bound_holds():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.normal(size=d.shape)
    t -= np.sum(t * d, axis=1, keepdims=True) * d
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    h = 1e-7
    uv0 = oc.encode(d)
    uv1 = oc.encode(d * np.cos(h) + t * np.sin(h))
    g = np.linalg.norm(uv1 - uv0, axis=1) / h
    g = g[g < 10]  # drop pairs straddling the fold (a jump in uv, continuous on the sphere)
    assert g.max() <= oc.OCT_LIPSCHITZ


@pytest.mark.parametrize("w", [1, 2, 8, 16])
def test_wrap_pixel_matches_the_uv_fold_reference(w):
    """Every pixel up to ``w`` outside the atlas, corners included, against the uv fold formula."""
    for i in range(-w, 2 * w):
        for j in range(-w, 2 * w):
            assert tuple(int(x) for x in oc.wrap_pixel(i, j, w)) == reference.wrap_pixel(i, j, w)
