"""Copy float32 rows into a larger array and learn, in the same pass, whether every value is finite.

A shot's static scene is concatenated once into the shot buffer (``usd_gs.gaussians.GaussianSet.
concatenate`` with ``finite=``); its values must be proven finite before any use. Checking each
copied block again with numpy (a sum per block, then the copy) reads every value twice; here each
value is read once, written, and tested as it passes (``v - v == 0`` holds exactly for finite
``v``: an infinity or a NaN gives NaN). The loops have no branch, so they vectorise.

- :func:`copy_finite`: ``dst[:] = src`` (1-D, equal lengths), True when every value is finite;
- :func:`copy_finite_padded`: rows of ``k`` values into rows of ``kk >= k`` (the rest of each
  destination row set to 0): a lower SH degree into the shot buffer's width.

float32 only, C-contiguous; the values are copied bit for bit (a NaN's payload included).
Reference: ``numba_kernels.reference.copy_finite``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit_options import read_only


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _copy(src, dst):
    ok = True
    for i in range(src.shape[0]):
        v = src[i]
        dst[i] = v
        ok &= (v - v) == np.float32(0.0)
    return ok


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _copy_padded(src, dst, k, kk):
    ok = True
    for r in range(src.shape[0] // k):
        a, b = r * k, r * kk
        for j in range(k):
            v = src[a + j]
            dst[b + j] = v
            ok &= (v - v) == np.float32(0.0)
        for j in range(k, kk):
            dst[b + j] = np.float32(0.0)
    return ok


def _flat(x: np.ndarray, name: str) -> np.ndarray:
    if x.dtype != np.float32 or not x.flags.c_contiguous:
        raise ValueError(f"copy_finite: {name} must be C-contiguous float32, got {x.dtype} "
                         f"({'' if x.flags.c_contiguous else 'not '}contiguous)")
    return x.reshape(-1)


def copy_finite(src: np.ndarray, dst: np.ndarray) -> bool:
    """Copy ``src`` into ``dst`` (same number of elements, any shapes) and return whether every
    value is finite (module doc)."""
    s, d = _flat(src, "src"), _flat(dst, "dst")
    if s.size != d.size:
        raise ValueError(f"copy_finite: src has {s.size} values, dst {d.size}")
    if not d.flags.writeable:
        raise ValueError("copy_finite: dst is read-only")
    return bool(_copy(read_only(s), d))


def copy_finite_padded(src: np.ndarray, dst: np.ndarray, k: int, kk: int) -> bool:
    """Copy rows of ``k`` values of ``src`` into rows of ``kk >= k`` values of ``dst`` (the same row
    count; each row's last ``kk - k`` values set to 0) and return whether every value of ``src`` is
    finite (module doc)."""
    s, d = _flat(src, "src"), _flat(dst, "dst")
    k, kk = int(k), int(kk)
    if k < 1 or kk < k or s.size % k or d.size != (s.size // k) * kk:
        raise ValueError(f"copy_finite_padded: {s.size} values in rows of {k} do not fill {d.size} values "
                         f"in rows of {kk}")
    if not d.flags.writeable:
        raise ValueError("copy_finite_padded: dst is read-only")
    return bool(_copy_padded(read_only(s), d, k, kk))
