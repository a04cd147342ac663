"""LatticeIndex (the sun atlas's pixel -> row map) against a Python dict, with negative
coordinates, pixels on block edges, and a grid that grows in every direction."""

import numpy as np

from usd_gs.shadows.lattice_index import BLOCK, LatticeIndex


def test_lookups_equal_a_dict_as_the_index_grows():
    rng = np.random.default_rng(0)
    index, ref = LatticeIndex(), {}
    edges = np.array([[0, 0], [-1, -1], [BLOCK - 1, BLOCK], [-BLOCK, BLOCK - 1], [-BLOCK - 1, 0]], np.int64)
    batches = [edges, rng.integers(-300, 300, (500, 2)), rng.integers(-5000, -4000, (200, 2)),
               rng.integers(9000, 9500, (200, 2))]
    row = 0
    for batch in batches:
        probe = np.concatenate([batch, rng.integers(-10000, 10000, (300, 2))])
        want = np.array([ref.get((int(i), int(j)), -1) for i, j in probe])
        np.testing.assert_array_equal(index.lookup(probe), want)
        new = np.unique(batch, axis=0)
        new = new[[(int(i), int(j)) not in ref for i, j in new]]
        rows = np.arange(row, row + len(new))
        index.insert(new, rows)
        ref.update({(int(i), int(j)): int(r) for (i, j), r in zip(new, rows, strict=True)})
        row += len(new)
    every = np.array(list(ref), np.int64)
    np.testing.assert_array_equal(index.lookup(every), np.array(list(ref.values())))
    assert index.lookup(np.zeros((0, 2), np.int64)).shape == (0,)
