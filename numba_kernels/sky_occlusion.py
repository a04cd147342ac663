"""The share of a receiver's sky that a stack of spheres hides (``usd_gs.shadows.sky_occlusion``).

A sphere of radius ``r`` whose centre lies at distance ``d`` in unit direction ``w`` from a
receiver with unit normal ``n`` hides the cosine-weighted share ``(r / d)^2 |n.w|`` of the
receiver's hemisphere (the form factor of a sphere wholly above the receiver's horizon; normals
two-sided); a receiver inside a sphere is wholly hidden. The spheres' shares are summed and
clipped to [0, 1]. Reference: ``numba_kernels.reference.sky_occlusion``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import threaded
from .thread_chunks import run_chunks


@njit(cache=True, **threaded(), fastmath=False)
def _hidden(i0, i1, centres, radii, x, nrm, out):
    for m in range(i0, i1):
        acc = 0.0
        for s in range(centres.shape[0]):
            vx, vy, vz = centres[s, 0] - x[m, 0], centres[s, 1] - x[m, 1], centres[s, 2] - x[m, 2]
            d2 = vx * vx + vy * vy + vz * vz
            r2 = radii[s] * radii[s]
            if d2 <= r2:
                acc = 1.0
                break
            cos = abs(vx * nrm[m, 0] + vy * nrm[m, 1] + vz * nrm[m, 2]) / math.sqrt(d2)
            acc += r2 / d2 * cos
        out[m] = min(max(acc, 0.0), 1.0)


def hidden_sky_share(centres, radii, positions, normals) -> np.ndarray:
    """(M,) float64 hidden share of each receiver (module docstring): spheres ``centres`` (S, 3),
    ``radii`` (S,); receivers ``positions`` (M, 3) with unit ``normals`` (M, 3)."""
    x = np.ascontiguousarray(positions, np.float64).reshape(-1, 3)
    out = np.zeros(x.shape[0])
    if x.shape[0] == 0 or len(radii) == 0:
        return out
    run_chunks(_hidden, x.shape[0], np.ascontiguousarray(centres, np.float64).reshape(-1, 3),
               np.ascontiguousarray(radii, np.float64).reshape(-1), x,
               np.ascontiguousarray(normals, np.float64).reshape(-1, 3), out, min_chunk=8192)
    return out
