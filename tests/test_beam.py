"""numba_kernels.beam against its numpy reference and hand-checked cases."""

import numpy as np
import pytest

from numba_kernels.beam import beam_gap_depth, offset_toward_point
from numba_kernels.reference.beam import beam_gap_depth as reference
from numba_kernels.reference.beam import offset_toward_point as reference_offset

RNG = np.random.default_rng(11)


def _point_params(lp, c, r):
    dc = float(np.linalg.norm(c - lp))
    s = r / dc
    return lp, (c - lp) / dc, r, dc, s, float(np.sqrt(1.0 - s * s))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_point_and_directional_beams_equal_the_reference(dtype):
    x = RNG.uniform(-6, 6, (100_000, 3)).astype(dtype)
    rows = np.sort(RNG.choice(len(x), 30_000, replace=False))
    lp, c = np.array([0.5, 3.0, -0.4]), np.array([0.2, 1.0, 0.3])
    args = _point_params(lp, c, 0.8)
    d = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    for point, a in ((True, args), (False, (c, d, 0.8))):
        for r in (None, rows):
            gap, depth = beam_gap_depth(x, r, point, *a)
            rg, rd = reference(x, r, point, *a)
            np.testing.assert_allclose(gap, rg, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(depth, rd, rtol=1e-12, atol=1e-12)
            assert gap.shape == (len(x) if r is None else len(rows),)
    # the point beam has points inside, outside and behind the apex
    gap, depth = beam_gap_depth(x, None, True, *args)
    assert 0.01 < np.mean(gap <= 0) < 0.5 and np.any(depth < 0) and np.any(depth > 0)
    assert beam_gap_depth(x, np.zeros(0, np.int64), True, *args)[0].shape == (0,)


def test_hand_cases_of_a_point_light_cone():
    # light at the origin, sphere of radius 1 at distance 2 along +x: half-angle 30 degrees
    lp, u, r, dc, s, cs = _point_params(np.zeros(3), np.array([2.0, 0.0, 0.0]), 1.0)
    pts = np.array([[4.0, 0.0, 0.0],    # on the axis, beyond the sphere: gap -along sin = -2
                    [3.0, 3.0, 0.0],    # 45 degrees off the axis: outside the 30-degree cone
                    [-1.0, 0.0, 0.0],   # behind the apex: gap = distance 1
                    [1.0, 0.0, 0.0]])   # the sphere's near side: depth 0
    gap, depth = beam_gap_depth(pts, None, True, lp, u, r, dc, s, cs)
    np.testing.assert_allclose(gap[[0, 2]], [-2.0, 1.0], atol=1e-15)
    along, perp = 3.0, 3.0
    np.testing.assert_allclose(gap[1], perp * cs - along * s, rtol=1e-15)
    assert gap[1] > 0
    np.testing.assert_allclose(depth, [3.0, np.sqrt(18.0) - 1.0, 0.0, 0.0], atol=1e-15)


def test_offset_toward_a_point_light_equals_the_reference_bit_for_bit():
    pts = RNG.uniform(-3, 3, (50_000, 3))
    lp = np.array([0.4, 2.5, -1.0])
    pts[7] = lp  # at the light: the direction's length is clamped, the point stays
    want = reference_offset(pts, lp, 0.03)
    got = offset_toward_point(pts.copy(), lp, 0.03)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got[7], lp)
    moved = np.linalg.norm(got - pts, axis=1)
    np.testing.assert_allclose(np.delete(moved, 7), 0.03, rtol=1e-12)
    with pytest.raises(ValueError, match="float64"):
        offset_toward_point(pts.astype(np.float32), lp, 0.03)
