"""numba_kernels.capsule against its numpy reference and hand-checked cases."""

import numpy as np

from numba_kernels.capsule import within_capsule, within_capsule_scaled
from numba_kernels.reference.capsule import within_capsule as reference
from numba_kernels.reference.capsule import within_capsule_scaled as reference_scaled


def test_kernel_equals_the_reference_away_from_the_boundary():
    rng = np.random.default_rng(2)
    p = rng.uniform(-5, 5, (200_000, 3)).astype(np.float32)
    extra = rng.uniform(0, 0.5, len(p))
    a, b = np.array([-1.0, 0.5, 2.0]), np.array([3.0, -1.0, 0.0])
    got, ref = within_capsule(p, a, b, 1.2, extra), reference(p, a, b, 1.2, extra)
    # the two can only differ where the squared distance is within rounding of the radius
    v = p.astype(np.float64) - a
    u = (b - a) / np.linalg.norm(b - a)
    t = np.clip(v @ u, 0, np.linalg.norm(b - a))
    d = np.linalg.norm(v - t[:, None] * u, axis=1)
    clear = np.abs(d - (1.2 + extra)) > 1e-9
    assert np.array_equal(got[clear], ref[clear]) and 0.02 < got.mean() < 0.5


def test_no_extra_is_a_zero_extra_and_the_reference():
    """``extra=None`` (its own kernel, no array of zeros): the values of an explicit zero reach, bit
    for bit, for a segment and a ball, float32 and float64 points, points on the boundary included."""
    rng = np.random.default_rng(5)
    p32 = rng.uniform(-3, 3, (100_000, 3)).astype(np.float32)
    p32[:4] = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, -2.0], [2.0, 0.0, 0.0]]  # at |p| = 1 or 2
    for p in (p32, p32.astype(np.float64)):
        for a, b, r in ((np.zeros(3), np.zeros(3), 2.0), (np.zeros(3), np.array([2.0, 1.0, -1.0]), 1.0)):
            got = within_capsule(p, a, b, r)
            assert np.array_equal(got, within_capsule(p, a, b, r, np.zeros(len(p))))
            assert np.array_equal(got, reference(p, a, b, r, np.zeros(len(p))))
            assert 0.05 < got.mean() < 0.8
    assert within_capsule(p32[:4], np.zeros(3), np.zeros(3), 2.0).tolist() == [True, True, True, True]
    assert within_capsule(p32[:4], np.zeros(3), np.zeros(3), 1.0).tolist() == [True, False, False, False]


def test_hand_cases_segment_ends_and_a_ball():
    a, b = np.zeros(3), np.array([10.0, 0.0, 0.0])
    pts = np.array([[5.0, 0.99, 0.0],   # beside the middle, inside
                    [5.0, 1.01, 0.0],   # just outside
                    [-0.9, 0.0, 0.3],   # behind a, within the end cap
                    [-1.1, 0.0, 0.0],   # behind a, outside the cap
                    [10.7, 0.7, 0.0],   # past b: distance 0.99 from b
                    [12.0, 0.0, 0.0]])  # past b, outside
    assert within_capsule(pts, a, b, 1.0).tolist() == [True, False, True, False, True, False]
    assert within_capsule(pts, a, b, 0.5, np.full(6, 0.5)).tolist() == [True, False, True, False, True, False]
    # a == b: a ball, float64 positions too
    ball = within_capsule(np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0]]), a, a, 1.0)
    assert ball.tolist() == [True, False]
    assert within_capsule(np.zeros((0, 3), np.float32), a, b, 1.0).shape == (0,)


def test_scaled_reach_is_the_largest_scale_times_the_factor():
    """The reach computed in the kernel (float32 factor x largest scale) gives the same answer as the
    (N,) reach array given to within_capsule, bit for bit, and the reference away from the boundary."""
    rng = np.random.default_rng(5)
    p = rng.uniform(-4, 4, (150_000, 3)).astype(np.float32)
    scales = rng.lognormal(-3.0, 1.0, (len(p), 3)).astype(np.float32)
    a, b = np.array([0.5, -2.0, 1.0]), np.array([-1.5, 2.5, 0.25])
    for factor in (8.0, 4.0, 3.3):
        got = within_capsule_scaled(p, a, b, 0.9, scales, factor)
        assert np.array_equal(got, within_capsule(p, a, b, 0.9, np.float32(factor) * scales.max(axis=1)))
        ref = reference_scaled(p, a, b, 0.9, scales, factor)
        v = p.astype(np.float64) - a
        u = (b - a) / np.linalg.norm(b - a)
        t = np.clip(v @ u, 0, np.linalg.norm(b - a))
        d = np.linalg.norm(v - t[:, None] * u, axis=1)
        clear = np.abs(d - (0.9 + factor * scales.max(axis=1).astype(np.float64))) > 1e-6
        assert np.array_equal(got[clear], ref[clear]) and 0.02 < got.mean() < 0.6
    # a point 1 m beside the segment is inside exactly when factor x its largest scale reaches it
    one = np.array([[0.0, 1.0, 0.0]], np.float32)
    s = np.array([[0.01, 0.2, 0.05]], np.float32)
    a, b = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    assert within_capsule_scaled(one, a, b, 0.5, s, 3.0).tolist() == [True]   # 0.5 + 0.6 >= 1
    assert within_capsule_scaled(one, a, b, 0.5, s, 2.0).tolist() == [False]  # 0.5 + 0.4 < 1
    assert within_capsule_scaled(np.zeros((0, 3), np.float32), a, b, 1.0, np.zeros((0, 3), np.float32),
                                 8.0).shape == (0,)


def test_ball_blocks_equal_the_per_point_test_bit_for_bit():
    """within_ball_blocks decides whole blocks inside or outside the ball and tests only the
    straddling ones point by point: the same booleans as within_capsule, for blocks wholly inside,
    wholly outside, straddling, empty and one block spread over everything, and for points placed
    exactly on the boundary (where a wrong block decision would show)."""
    from numba_kernels.capsule import block_spheres, within_ball_blocks

    rng = np.random.default_rng(11)
    centres = rng.uniform(-20, 20, (60, 3))
    clusters = [c + rng.normal(0, 0.4, (int(rng.integers(1, 3000)), 3)) for c in centres]
    scattered = rng.uniform(-25, 25, (5000, 3))  # one block whose sphere holds everything
    centre = np.array([1.5, -2.0, 0.5])
    on_edge = centre + 7.0 * np.array([[1.0, 0, 0], [0, -1.0, 0], [0.6, 0.8, 0]])  # |p - c| == 7 in float64
    parts = [*clusters, np.zeros((0, 3)), scattered, on_edge]
    p = np.concatenate(parts).astype(np.float32)
    starts = np.concatenate([[0], np.cumsum([len(x) for x in parts])]).astype(np.int64)
    spheres = block_spheres(p, starts)
    assert spheres[1][len(clusters)] == -1.0  # the empty block
    for b in range(len(parts)):
        rows = p[starts[b]:starts[b + 1]].astype(np.float64)
        if len(rows):
            assert np.linalg.norm(rows - spheres[0][b], axis=1).max() <= spheres[1][b]
    decided = 0
    for radius in (0.5, 7.0, 7.0 * (1 + 1e-7), 12.0, 40.0):
        got = within_ball_blocks(p, starts, spheres, centre, radius)
        assert np.array_equal(got, within_capsule(p, centre, centre, radius))
        dc = np.linalg.norm(spheres[0] - centre, axis=1)
        decided += int(np.sum((dc + spheres[1] < radius) | (dc - spheres[1] > radius)))
    assert decided > 100  # most blocks were decided whole
    # rows outside the blocks are False
    assert not within_ball_blocks(p, starts[:2], spheres, centre, 1e3)[starts[1]:].any()


def test_scaled_blocks_equal_the_per_point_test_bit_for_bit():
    """within_capsule_scaled_blocks decides blocks wholly inside or outside every point's capsule at
    once and tests the others point by point: the same booleans as within_capsule_scaled, for
    blocks inside, outside and straddling, an empty block, a ball (a == b) and a NaN scale."""
    from numba_kernels.capsule import block_reach, block_spheres, within_capsule_scaled_blocks

    rng = np.random.default_rng(4)
    centres = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [3.0, 1.5, 0.0], [0.5, 0.2, 0.1], [-20.0, 5.0, 3.0]])
    sizes = [500, 700, 600, 0, 400]
    p = np.concatenate([c + rng.normal(0, 0.6, (n, 3)) for c, n in zip(centres, sizes, strict=True)]).astype(np.float32)
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.3), (len(p), 3))).astype(np.float32)
    scales[1234] = np.nan  # (block 2: never decided at once)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    spheres = block_spheres(p, starts)
    reach = block_reach(scales, starts, 3.0)
    assert np.isnan(reach[0][2]) and reach[0][3] == np.inf
    ref_hi = 3.0 * scales[:500].astype(np.float32).max(axis=1)
    assert reach[1][0] == np.float64(ref_hi.max()) and reach[0][0] == np.float64(ref_hi.min())
    decided = set()
    for a, b, radius in (([-1.0, 0.0, 0.0], [5.0, 0.0, 0.0], 1.5), ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 2.0),
                         ([0.0, -4.0, 0.0], [40.0, 4.0, 0.0], 0.8), ([-25.0, 5.0, 3.0], [31.0, 0.0, 0.0], 3.0)):
        got = within_capsule_scaled_blocks(p, starts, spheres, reach, np.array(a), np.array(b), radius, scales, 3.0)
        want = within_capsule_scaled(p, np.array(a), np.array(b), radius, scales, 3.0)
        assert np.array_equal(got, want)
        decided |= {(bool(want[s:e].all()), bool(want[s:e].any())) for s, e in zip(starts[:-1], starts[1:],
                                                                                      strict=True) if e > s}
    assert {(True, True), (False, False), (False, True)} <= decided  # blocks inside, outside and straddling
