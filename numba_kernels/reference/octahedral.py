"""Reference of :mod:`numba_kernels.octahedral`: eq. 6 written directly, and the fold-wrap of
pixels beyond the edge through the continuous uv fold formula of the module docstring."""

from __future__ import annotations

import math

import numpy as np


def encode(d) -> np.ndarray:
    """Eq. 6 for one unit direction (3,) (``sgn(0) = +1``): (2,) uv in [-1, 1]^2."""
    q = np.asarray(d, np.float64) / np.abs(d).sum()
    if q[2] >= 0:
        return np.array([q[0], q[1]])
    sx = 1.0 if q[0] >= 0 else -1.0
    sy = 1.0 if q[1] >= 0 else -1.0
    return np.array([sx * (1 - abs(q[1])), sy * (1 - abs(q[0]))])


def fold_uv(u: float, v: float) -> tuple[float, float]:
    """The point of [-1, 1]^2 that uv (less than 2 outside) continues on the sphere: ``u > 1``:
    ``(2 - u, -v)``, ``v > 1``: ``(-u, 2 - v)``, and the mirrored rules below -1, until inside."""
    while abs(u) > 1 or abs(v) > 1:
        if u > 1:
            u, v = 2 - u, -v
        elif u < -1:
            u, v = -2 - u, -v
        elif v > 1:
            u, v = -u, 2 - v
        else:
            u, v = -u, -2 - v
    return u, v


def wrap_pixel(i: int, j: int, w: int) -> tuple[int, int]:
    """The pixel of a ``w`` x ``w`` atlas that pixel (i, j) (less than ``w`` outside) continues
    on the sphere: its centre's uv folded back into the square (:func:`fold_uv`), then the pixel
    holding it."""
    u, v = fold_uv((2 * i + 1) / w - 1, (2 * j + 1) / w - 1)
    return math.floor((u + 1) * w / 2), math.floor((v + 1) * w / 2)
