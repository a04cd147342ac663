"""Spatial bricks: splitting a large Gaussian set into child prims of bounded size.

USD arrays are whole per time sample: shadowing ten Gaussians of a one-million-Gaussian
prim re-authors all of its arrays at that frame. Split into bricks (child prims of at
most ``max_count`` Gaussians each, spatially compact), only the bricks that a shadow
touches get time samples, so the output per frame grows with the shadowed receivers, not
with the scene's size.

Bricks come from a k-d split: a set larger than ``max_count`` is cut at the median of its
longest axis, recursively. Every brick holds between ``max_count / 2`` and ``max_count``
Gaussians (for sets larger than ``max_count``). Deterministic (stable sorts).
"""

from __future__ import annotations

import numpy as np

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet


def brick_indices(positions: np.ndarray, max_count: int) -> list[np.ndarray]:
    """Index arrays (int64, sorted) of the bricks of ``positions`` (N, 3), in a fixed order."""
    if max_count < 1:
        raise UserError(f"brick size must be >= 1, got {max_count}")
    n = positions.shape[0]
    pending = [np.arange(n, dtype=np.int64)]
    done = []
    while pending:
        idx = pending.pop()
        if idx.size <= max_count:
            done.append(idx)
            continue
        p = positions[idx]
        axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
        order = np.argsort(p[:, axis], kind="stable")
        half = idx.size // 2
        pending.append(np.sort(idx[order[half:]]))
        pending.append(np.sort(idx[order[:half]]))
    done.sort(key=lambda a: int(a[0]) if a.size else -1)
    return done


def write_bricked(stage, path: str, gaussians: GaussianSet, max_count: int, keep_raw: bool = True,
                  precision: str = "float", role: str | None = None) -> list[str]:
    """Write ``gaussians`` as an ``Xform`` at ``path`` with children ``Brick_0000`` ... (each a
    conformant Gaussian prim); apply ``role`` to every brick. Returns the brick paths."""
    from pxr import UsdGeom

    from usd_gs.usd.gaussian_prim import write_gaussian_prim
    from usd_gs.usd.schema import apply_role

    UsdGeom.Xform.Define(stage, path)
    paths = []
    for i, idx in enumerate(brick_indices(gaussians.positions, max_count)):
        child = f"{path}/Brick_{i:04d}"
        prim = write_gaussian_prim(stage, child, gaussians.subset(idx), keep_raw=keep_raw, precision=precision)
        if role:
            apply_role(prim, role)
        paths.append(child)
    return paths
