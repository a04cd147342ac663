"""Reference of :mod:`numba_kernels.beam` in numpy, from its module docstring."""

from __future__ import annotations

import numpy as np


def beam_gap_depth(positions, rows, point: bool, a, u, r: float, dc: float = 0.0, sin_h: float = 0.0,
                   cos_h: float = 1.0):
    x = np.asarray(positions, np.float64).reshape(-1, 3)
    if rows is not None:
        x = x[np.asarray(rows, np.int64)]
    v = x - np.asarray(a, np.float64)
    along = v @ np.asarray(u, np.float64)
    vv = np.sum(v * v, axis=1)
    if not point:
        return np.sqrt(np.maximum(vv - along * along, 0.0)) - r, along + r
    dist = np.sqrt(vv)
    perp = np.sqrt(np.maximum(dist * dist - along * along, 0.0))
    gap = np.where(along * cos_h + perp * sin_h < 0.0, dist, perp * cos_h - along * sin_h)
    return gap, dist - (dc - r)


def offset_toward_point(points, light_position, bias: float):
    p = np.asarray(points, np.float64)
    toward = np.asarray(light_position, np.float64) - p
    return p + bias * (toward / np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-12))
