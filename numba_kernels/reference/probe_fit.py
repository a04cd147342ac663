"""Reference of :mod:`numba_kernels.probe_fit`: the normal equations of eq. 7 as dense numpy
products and the ridge fit as an augmented least-squares problem (``np.linalg.lstsq``)."""

from __future__ import annotations

import numpy as np

from .sh_real import real_sh_basis


def normal_equations(dirs, weights, values, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """``(B^T W B, B^T W Y)`` for the RH basis B (M, K) at ``dirs`` (M, 3), weights (M,), values (M, C)."""
    b = real_sh_basis(dirs, degree)
    w = np.asarray(weights, np.float64)[:, None]
    return (b * w).T @ b, (b * w).T @ np.asarray(values, np.float64)


def fit_sh_lstsq(dirs, weights, values, degree: int, lam: float) -> np.ndarray:
    """Eq. 7: ``argmin_A |W^1/2 (B A - Y)|^2 + lam |A|^2`` as ``[W^1/2 B; sqrt(lam) I] A = [W^1/2 Y; 0]``."""
    b = real_sh_basis(dirs, degree)
    sw = np.sqrt(np.asarray(weights, np.float64))[:, None]
    y = np.asarray(values, np.float64)
    aug = np.vstack([sw * b, np.sqrt(lam) * np.eye(b.shape[1])])
    rhs = np.vstack([sw * y, np.zeros((b.shape[1], y.shape[1]))])
    return np.linalg.lstsq(aug, rhs, rcond=None)[0]
