"""Reference of :mod:`numba_kernels.sh_output` (tests only): numpy's float16 cast and the display-change
bound as a plain numpy expression."""

from __future__ import annotations

import numpy as np


def half_bits(x: np.ndarray) -> np.ndarray:
    """``x`` (float32) as float16: numpy's cast."""
    return np.asarray(x, np.float32).astype(np.float16)


def row_display_changes(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) float64: ``max_c sum_k |a - b| sqrt((2 l_k + 1) / (4 pi))`` per row of (N, K, 3) arrays, the
    difference taken in float32."""
    d = np.abs(np.asarray(a, np.float32) - np.asarray(b, np.float32)).astype(np.float64)
    k = d.shape[1]
    ymax = np.sqrt((2.0 * np.floor(np.sqrt(np.arange(k))) + 1.0) / (4.0 * np.pi))
    return np.einsum("nkc,k->nc", d, ymax).max(axis=1, initial=0.0)
