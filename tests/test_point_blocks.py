"""usd_gs.point_blocks: ball tests over a static point set decided block by block give
within_capsule's values; blocks from prim ranges only where they tile the rows."""

import numpy as np

from numba_kernels.capsule import within_capsule, within_capsule_scaled
from usd_gs.point_blocks import BLOCK, PointBlocks, block_starts


def test_block_starts_split_large_prims():
    starts = block_starts([(0, 10), (10, 10 + 2 * BLOCK + 5), (10 + 2 * BLOCK + 5, 10 + 2 * BLOCK + 6)])
    assert starts.tolist() == [0, 10, 10 + BLOCK, 10 + 2 * BLOCK, 10 + 2 * BLOCK + 5, 10 + 2 * BLOCK + 6]


def test_blocks_of_ranges_need_a_tiling_from_zero():
    assert PointBlocks.of_ranges({"/a": (0, 5), "/b": (5, 9)}).starts.tolist() == [0, 5, 9]
    assert PointBlocks.of_ranges({"/b": (5, 9), "/a": (0, 5), "/empty": (9, 9)}).starts.tolist() == [0, 5, 9]
    assert PointBlocks.of_ranges({"/a": (0, 5), "/b": (6, 9)}) is None  # a gap
    assert PointBlocks.of_ranges({"/a": (2, 5)}) is None  # not from 0
    assert PointBlocks.of_ranges({}) is None


def test_within_equals_the_per_point_test():
    rng = np.random.default_rng(7)
    bricks = [rng.normal(c, 0.3, (int(rng.integers(50, 4000)), 3)) for c in rng.uniform(-30, 30, (80, 3))]
    p = np.concatenate(bricks).astype(np.float32)
    ends = np.cumsum([len(b) for b in bricks])
    ranges = {f"/b{i}": (e - len(b), e) for i, (b, e) in enumerate(zip(bricks, ends, strict=True))}
    blocks = PointBlocks.of_ranges(ranges)
    for centre, radius in (((0.0, 0.0, 0.0), 15.0), ((10.0, -5.0, 3.0), 2.0), ((0.0, 0.0, 0.0), 100.0)):
        got = blocks.within(p, np.array(centre), radius)
        assert np.array_equal(got, within_capsule(p, np.array(centre), np.array(centre), radius))
    # positions of another length: the plain test
    assert np.array_equal(blocks.within(p[:100], np.zeros(3), 15.0), within_capsule(p[:100], np.zeros(3),
                                                                                     np.zeros(3), 15.0))


def test_capsule_with_reach_equals_the_per_point_test():
    rng = np.random.default_rng(8)
    bricks = [rng.normal(c, 0.3, (int(rng.integers(50, 4000)), 3)) for c in rng.uniform(-30, 30, (80, 3))]
    p = np.concatenate(bricks).astype(np.float32)
    scales = np.exp(rng.uniform(np.log(0.005), np.log(0.2), (len(p), 3))).astype(np.float32)
    ends = np.cumsum([len(b) for b in bricks])
    ranges = {f"/b{i}": (e - len(b), e) for i, (b, e) in enumerate(zip(bricks, ends, strict=True))}
    blocks = PointBlocks.of_ranges(ranges)
    light = np.array([0.0, 3.0, 0.0])
    for end, radius in (((5.0, 0.0, 2.0), 2.0), ((-20.0, -3.0, 10.0), 6.0), ((0.0, 3.0, 0.0), 40.0)):
        for factor in (3.0, 0.0):
            got = blocks.within_capsule_scaled(p, light, np.array(end), radius, scales, factor)
            assert np.array_equal(got, within_capsule_scaled(p, light, np.array(end), radius, scales, factor))
    assert np.array_equal(blocks.within_capsule_scaled(p[:100], light, light, 15.0, scales[:100], 3.0),
                          within_capsule_scaled(p[:100], light, light, 15.0, scales[:100], 3.0))
