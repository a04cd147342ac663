"""A growable map from integer lattice pixels ``(i, j)`` to row numbers, for the shot-long lattice
of :class:`usd_gs.shadows.static_scene.StaticSceneSunAtlas`.

The lattice is unbounded (a pitch of millimetres on a plane the receivers wander over), so the
map is two-level: a dense grid of ``BLOCK`` x ``BLOCK``-pixel blocks over the range of blocks
seen so far (grown when a pixel falls outside it), and a pool of dense ``BLOCK`` x ``BLOCK`` row
tables, one per block that holds a pixel. A lookup is two gathers, whatever the number of pixels
stored (a sorted-key search over hundreds of thousands of lookups per frame cost tens of
milliseconds): :meth:`lookup` in numpy, and the sun atlas's per-frame lookups in a kernel that
reads the same arrays (:meth:`arrays`, ``numba_kernels.lattice_lookup``). Memory: 4 bytes per grid
block plus ``8 * BLOCK**2`` bytes per used block.
"""

from __future__ import annotations

import numpy as np

#: pixels per block side (a power of two)
BLOCK = 64
_SHIFT = BLOCK.bit_length() - 1


class LatticeIndex:
    """Rows of lattice pixels; -1 where a pixel has none."""

    def __init__(self):
        self._lo = np.zeros(2, np.int64)  # block coordinates of grid cell (0, 0)
        self._grid = np.full((0, 0), -1, np.int32)  # block -> slot in the pool
        self._pool = np.full((0, BLOCK, BLOCK), -1, np.int64)
        self._slots = 0

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(lo (2,) int64, grid (B0, B1) int32, pool (S, BLOCK, BLOCK) int64)``: the map as
        ``numba_kernels.lattice_lookup.lattice_stencils`` reads it (block coordinates of grid cell
        (0, 0), block -> pool slot or -1, slot -> rows or -1). Valid until the next :meth:`insert`."""
        return self._lo, self._grid, self._pool

    def lookup(self, ij: np.ndarray) -> np.ndarray:
        """(M,) int64 rows of the pixels ``ij`` (M, 2) int64; -1 for pixels not inserted."""
        out = np.full(ij.shape[0], -1, np.int64)
        if self._slots == 0 or ij.shape[0] == 0:
            return out
        b = (ij >> _SHIFT) - self._lo
        inside = np.flatnonzero((b[:, 0] >= 0) & (b[:, 0] < self._grid.shape[0])
                                & (b[:, 1] >= 0) & (b[:, 1] < self._grid.shape[1]))
        slot = self._grid[b[inside, 0], b[inside, 1]]
        used = slot >= 0
        at = inside[used]
        local = ij[at] & (BLOCK - 1)
        out[at] = self._pool[slot[used], local[:, 0], local[:, 1]]
        return out

    def insert(self, ij: np.ndarray, rows: np.ndarray) -> None:
        """Map the pixels ``ij`` (M, 2) int64 (distinct, not inserted yet) to ``rows`` (M,)."""
        if ij.shape[0] == 0:
            return
        blocks = ij >> _SHIFT
        self._cover(blocks.min(axis=0), blocks.max(axis=0))
        b = blocks - self._lo
        slot = self._grid[b[:, 0], b[:, 1]]
        fresh = np.unique(b[slot < 0], axis=0)
        if fresh.shape[0]:
            need = self._slots + fresh.shape[0]
            if need > self._pool.shape[0]:
                grown = np.full((max(2 * self._pool.shape[0], need, 16), BLOCK, BLOCK), -1, np.int64)
                grown[: self._slots] = self._pool[: self._slots]
                self._pool = grown
            self._grid[fresh[:, 0], fresh[:, 1]] = np.arange(self._slots, need, dtype=np.int32)
            self._slots = need
            slot = self._grid[b[:, 0], b[:, 1]]
        local = ij & (BLOCK - 1)
        self._pool[slot, local[:, 0], local[:, 1]] = rows

    def _cover(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Grow the block grid so that it holds the blocks ``lo`` .. ``hi`` (inclusive)."""
        if self._grid.size == 0:
            self._lo = lo.astype(np.int64)
            self._grid = np.full(tuple(int(v) for v in hi - lo + 1), -1, np.int32)
            return
        old_hi = self._lo + np.array(self._grid.shape) - 1
        new_lo, new_hi = np.minimum(self._lo, lo), np.maximum(old_hi, hi)
        if np.array_equal(new_lo, self._lo) and np.array_equal(new_hi, old_hi):
            return
        grid = np.full(tuple(int(v) for v in new_hi - new_lo + 1), -1, np.int32)
        o = self._lo - new_lo
        grid[o[0]: o[0] + self._grid.shape[0], o[1]: o[1] + self._grid.shape[1]] = self._grid
        self._lo, self._grid = new_lo, grid
