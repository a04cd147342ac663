"""Unshadowed irradiance of a point light on oriented receivers, in one threaded pass.

For a receiver at ``x`` with unit normal ``n`` and a point light at ``p`` of radiant intensity
``I`` (3,): ``d = p - x``, ``r2 = max(d . d, 1e-12)``, ``r = sqrt(r2)``, ``cos = (n . d) / r`` and
the irradiance per channel ``c`` is ``(max(cos, 0) / r2) * I[c]`` (``usd_gs.relight.direct``,
form "point"). Float64 arithmetic on float32 or float64 inputs, each sum of three products taken
left to right. Reference: ``numba_kernels.reference.point_irradiance`` (equal to rounding: numpy's
``einsum`` may add three products in another order).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit_options import float_rows, threaded
from .thread_chunks import run_chunks


@njit(cache=True, **threaded(), fastmath=False)
def _irradiance_rows(i0, i1, x, n, p, intensity, out):
    for m in range(i0, i1):
        dx = p[0] - np.float64(x[m, 0])
        dy = p[1] - np.float64(x[m, 1])
        dz = p[2] - np.float64(x[m, 2])
        r2 = max(dx * dx + dy * dy + dz * dz, 1e-12)
        r = math.sqrt(r2)
        cos = (np.float64(n[m, 0]) * dx + np.float64(n[m, 1]) * dy + np.float64(n[m, 2]) * dz) / r
        f = max(cos, 0.0) / r2
        out[m, 0] = f * intensity[0]
        out[m, 1] = f * intensity[1]
        out[m, 2] = f * intensity[2]


def point_irradiance(positions, normals, light_position, intensity) -> np.ndarray:
    """(N, 3) float64 irradiance (module docstring) of a point light at ``light_position`` (3,) with
    radiant intensity ``intensity`` (3,) on receivers at ``positions`` (N, 3) with unit ``normals``
    (N, 3); positions and normals float32 or float64."""
    x = float_rows(positions)
    nrm = float_rows(normals)
    if nrm.shape != x.shape:
        raise ValueError(f"point_irradiance: normals {nrm.shape} do not match positions {x.shape}")
    out = np.empty((x.shape[0], 3))
    run_chunks(_irradiance_rows, x.shape[0], x, nrm, np.asarray(light_position, np.float64).reshape(3),
               np.asarray(intensity, np.float64).reshape(3), out, min_chunk=16384)
    return out
