"""Reference of :mod:`numba_kernels.cubemap`'s face mapping, from its module docstring: face
``2a + (d_a < 0)`` for the major axis ``a`` (first maximum), ``(s, t) = (d_b, d_c) / |d_a|`` with
``(b, c) = ((a+1) % 3, (a+2) % 3)``; decoding sets ``d_a = +-1, d_b = s, d_c = t`` and normalises."""

from __future__ import annotations

import numpy as np


def encode(d) -> tuple[int, float, float]:
    """Direction (3,) -> (face, s, t)."""
    d = np.asarray(d, np.float64)
    a = int(np.argmax(np.abs(d)))
    return 2 * a + int(d[a] < 0), d[(a + 1) % 3] / abs(d[a]), d[(a + 2) % 3] / abs(d[a])


def decode(f: int, s: float, t: float) -> np.ndarray:
    """(face, s, t) -> unit direction (3,)."""
    a = f // 2
    v = np.zeros(3)
    v[a] = 1.0 if f % 2 == 0 else -1.0
    v[(a + 1) % 3] = s
    v[(a + 2) % 3] = t
    return v / np.linalg.norm(v)
