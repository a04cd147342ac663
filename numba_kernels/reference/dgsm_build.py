"""Reference of :mod:`numba_kernels.dgsm_build`'s tile binning: per tile, the occluders whose
pixel box covers it, found by a Python loop over occluders and the tiles of each box."""

from __future__ import annotations

import math

from .octahedral import wrap_pixel


def tile_lists(fx, fy, rp, is_glob, w: int, active, tile: int) -> list[list[int]]:
    """Per tile (row-major over the ``w // tile`` square), the ascending indices of the non-global
    occluders whose pixel box (centre ``(fx, fy)`` +- ``rp``) covers it, fold-wrapped; empty for
    tiles that are not ``active``."""
    wt = w // tile
    lists = [[] for _ in range(wt * wt)]
    for i in range(len(fx)):
        if is_glob[i]:
            continue
        tiles = set()
        for tx in range(math.floor((fx[i] - rp[i]) / tile), math.floor((fx[i] + rp[i]) / tile) + 1):
            for ty in range(math.floor((fy[i] - rp[i]) / tile), math.floor((fy[i] + rp[i]) / tile) + 1):
                a, b = wrap_pixel(tx, ty, wt)
                tiles.add(a * wt + b)
        for t in sorted(tiles):
            if active[t]:
                lists[t].append(i)
    return lists
