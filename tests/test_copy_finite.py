"""``numba_kernels.copy_finite``: a copy that learns in the same pass whether every value is finite,
against its numpy reference (``numba_kernels.reference.copy_finite``), bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels import copy_finite as kernel
from numba_kernels.reference import copy_finite as reference


def _values(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (rng.normal(0.0, 1.0, n) * np.exp(rng.uniform(-30, 30, n))).astype(np.float32)


@pytest.mark.parametrize("n", [0, 1, 7, 16, 33, 1000, 4099])
def test_copy_and_verdict_match_the_reference_wherever_a_bad_value_sits(n):
    src = _values(n, n)
    dst, want = np.full(n, 7.0, np.float32), np.full(n, 7.0, np.float32)
    assert kernel.copy_finite(src, dst) is reference.copy_finite(src, want) is True
    assert np.array_equal(dst.view(np.uint32), want.view(np.uint32))
    for at in {0, n // 2, n - 1} if n else set():  # the first, a middle and the last lane
        for bad in (np.nan, np.inf, -np.inf):
            s = src.copy()
            s[at] = bad
            d, w = np.zeros(n, np.float32), np.zeros(n, np.float32)
            assert kernel.copy_finite(s, d) is reference.copy_finite(s, w) is False
            assert np.array_equal(d.view(np.uint32), w.view(np.uint32))


def test_extremes_are_finite_and_nan_payloads_are_copied_as_they_are():
    big = np.finfo(np.float32).max
    tiny = np.finfo(np.float32).smallest_subnormal
    src = np.array([big, -big, tiny, -tiny, 0.0, -0.0], np.float32)
    dst = np.empty_like(src)
    assert kernel.copy_finite(src, dst) is True  # (v - v is 0 for the largest values too)
    assert np.array_equal(dst.view(np.uint32), src.view(np.uint32))  # -0.0 stays -0.0
    odd = np.array([0x7FC00123, 0xFFC00001, 0x3F800000], np.uint32).view(np.float32)  # two NaN payloads, 1.0
    out = np.empty_like(odd)
    assert kernel.copy_finite(odd, out) is False
    assert np.array_equal(out.view(np.uint32), odd.view(np.uint32))


@pytest.mark.parametrize("k, kk", [(3, 3), (3, 12), (12, 48), (27, 48)])
def test_padded_rows_match_the_reference(k, kk):
    rows = 50
    src = _values(rows * k, k + kk).reshape(rows, k)
    dst, want = np.full((rows, kk), 5.0, np.float32), np.full((rows, kk), 5.0, np.float32)
    assert kernel.copy_finite_padded(src, dst, k, kk) is reference.copy_finite_padded(src, want, k, kk) is True
    assert np.array_equal(dst, want) and np.all(dst[:, k:] == 0.0)
    src[rows - 1, k - 1] = np.nan
    assert kernel.copy_finite_padded(src, dst, k, kk) is False
    assert np.isnan(dst[rows - 1, k - 1]) and np.all(dst[:, k:] == 0.0)


def test_bad_arguments_are_refused():
    a = np.zeros(6, np.float32)
    with pytest.raises(ValueError, match="values"):
        kernel.copy_finite(a, np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="float32"):
        kernel.copy_finite(a.astype(np.float64), np.zeros(6, np.float32))
    with pytest.raises(ValueError, match="contiguous"):
        kernel.copy_finite(np.zeros(12, np.float32)[::2], a)
    ro = np.zeros(6, np.float32)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="read-only"):
        kernel.copy_finite(a, ro)
    with pytest.raises(ValueError, match="rows"):
        kernel.copy_finite_padded(a, np.zeros(7, np.float32), 3, 4)
    with pytest.raises(ValueError, match="rows"):
        kernel.copy_finite_padded(a, np.zeros(6, np.float32), 3, 2)
