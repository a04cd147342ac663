"""Ball tests over a large static point set, decided block by block.

A shot's static scene is many prims (a captured scene's bricks); a test such as "which centres lie
within r of this point" over every one of its Gaussians costs a pass over millions of rows, yet
most prims lie wholly inside or wholly outside the ball. :class:`PointBlocks` keeps each prim's rows
(split into runs of at most :data:`BLOCK`) as a block with the bounding sphere of its centres
(``numba_kernels.capsule.block_spheres``, computed on first use) and answers
:meth:`PointBlocks.within` with ``numba_kernels.capsule.within_ball_blocks``: the same booleans as
``within_capsule`` on every row, testing row by row only the blocks the ball's boundary crosses
(and :meth:`PointBlocks.within_capsule_scaled` likewise for a capsule with each point's own reach).
"""

from __future__ import annotations

import threading

import numpy as np

from numba_kernels.capsule import (
    block_reach,
    block_scale_bound,
    block_spheres,
    within_ball_blocks,
    within_capsule,
    within_capsule_scaled,
    within_capsule_scaled_blocks,
)

#: a block holds at most this many rows (a larger prim is split: a capture's points are near each
#: other in storage order more often than not; where they are not, a block is merely tested row by row)
BLOCK = 65536


def block_starts(bounds) -> np.ndarray:
    """(B+1,) int64 block starts from prims' row ``bounds`` (``[(start, end)]``, contiguous from 0
    in increasing order): each prim one block, split into runs of at most :data:`BLOCK` rows."""
    cuts = [0]
    for a, b in bounds:
        cuts.extend(range(int(a) + BLOCK, int(b), BLOCK))
        cuts.append(int(b))
    return np.unique(np.asarray(cuts, np.int64))


def within_ball(blocks: PointBlocks | None, positions: np.ndarray, centre, radius: float) -> np.ndarray:
    """(N,) bool ``within_capsule(positions, centre, centre, radius)``: block by block with ``blocks``
    (:meth:`PointBlocks.within`), row by row without."""
    if blocks is None:
        return within_capsule(positions, centre, centre, radius)
    return blocks.within(positions, centre, radius)


def within_reach(blocks: PointBlocks | None, positions: np.ndarray, a, b, radius: float, scales: np.ndarray,
                 factor: float) -> np.ndarray:
    """(N,) bool ``within_capsule_scaled(positions, a, b, radius, scales, factor)``: block by block with
    ``blocks`` (:meth:`PointBlocks.within_capsule_scaled`), row by row without."""
    if blocks is None:
        return within_capsule_scaled(positions, a, b, radius, scales, factor)
    return blocks.within_capsule_scaled(positions, a, b, radius, scales, factor)


class PointBlocks:
    """The rows ``0 .. starts[-1]`` of a point set in blocks (``starts`` from :func:`block_starts`);
    the positions are passed to each call (the same values every time: the spheres are computed
    from the first call's). Thread-safe."""

    def __init__(self, starts):
        self.starts = np.asarray(starts, np.int64)
        self._spheres = None
        self._reach: dict = {}  # factor -> block_reach of the scales the first call gave
        self._scale_bound = None  # block_scale_bound of the scales the first cull_bounds call gave
        self._memo: tuple | None = None  # (key, owner, value): memo()'s last value
        self._lock = threading.Lock()

    def _spheres_of(self, positions: np.ndarray):
        with self._lock:
            if self._spheres is None:
                self._spheres = block_spheres(positions, self.starts)
            return self._spheres

    def memo(self, key, owner, compute):
        """``compute()``, or the value the last call computed where it had the same hashable ``key``
        and the same ``owner`` (the object the value is derived from, e.g. the point set): a value
        that consecutive callers derive from these same rows, such as the light estimate's region
        of interest that its two estimates ask for. Only the last value is kept (an estimate per
        frame does not pile up a copy per frame); it is shared: callers must not modify it."""
        with self._lock:
            hit = self._memo
        if hit is not None and hit[0] == key and hit[1] is owner:
            return hit[2]
        value = compute()
        with self._lock:
            self._memo = (key, owner, value)
        return value

    @classmethod
    def of_ranges(cls, ranges) -> PointBlocks | None:
        """Blocks over prims' ``ranges`` (``{path: (start, end)}``), or None where they do not tile
        the rows from 0 without gaps."""
        bounds = sorted((int(a), int(b)) for a, b in ranges.values() if b > a)
        if not bounds or bounds[0][0] != 0 or any(b[1] != c[0] for b, c in zip(bounds, bounds[1:], strict=False)):
            return None
        return cls(block_starts(bounds))

    def within(self, positions: np.ndarray, centre, radius: float) -> np.ndarray:
        """(N,) bool: ``within_capsule(positions, centre, centre, radius)``, the same values, block
        by block; every row when ``positions`` does not have ``starts[-1]`` rows."""
        if len(positions) != self.starts[-1]:
            return within_capsule(positions, centre, centre, radius)
        return within_ball_blocks(positions, self.starts, self._spheres_of(positions), centre, radius)

    def within_capsule_scaled(self, positions: np.ndarray, a, b, radius: float, scales: np.ndarray,
                              factor: float) -> np.ndarray:
        """(N,) bool: ``within_capsule_scaled(positions, a, b, radius, scales, factor)``, the same
        values, block by block (``scales``: the same values every call, as the positions); every row
        when ``positions`` does not have ``starts[-1]`` rows."""
        if len(positions) != self.starts[-1]:
            return within_capsule_scaled(positions, a, b, radius, scales, factor)
        spheres = self._spheres_of(positions)
        with self._lock:
            reach = self._reach.get(float(factor))
        if reach is None:
            reach = block_reach(scales, self.starts, factor)
            with self._lock:
                self._reach[float(factor)] = reach
        return within_capsule_scaled_blocks(positions, self.starts, spheres, reach, a, b, radius, scales, factor)

    def cull_bounds(self, positions: np.ndarray, scales: np.ndarray) -> tuple | None:
        """The blocks as the rasteriser's ``blocks`` argument (``numba_kernels.rasterize.rasterize``):
        ``(starts, centres, radii, largest |scale|)``, computed once (the same positions and scales
        every call); None when ``positions`` does not have ``starts[-1]`` rows."""
        if len(positions) < self.starts[-1]:
            return None
        spheres = self._spheres_of(positions[:self.starts[-1]])
        with self._lock:
            if self._scale_bound is None:
                self._scale_bound = block_scale_bound(scales[:self.starts[-1]], self.starts)
            bound = self._scale_bound
        return self.starts, spheres[0], spheres[1], bound
