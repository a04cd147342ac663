"""numba_kernels.sh_output (the output layer's SH passes) and sh_transfer.shade_rows against numpy:
the float16 cast bit for bit on the hard cases, the display-change bound, masked conversion and
segment equality, and the fused shadowing of SH rows against the masked numpy form."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels import sh_output
from numba_kernels.reference import sh_output as ref
from numba_kernels.sh_transfer import shade_rows
from usd_gs.shadows.shading import attenuation_factor, scale_sh


def _hard_float32() -> np.ndarray:
    """float32 values where a float16 cast can go wrong: every half value, the midpoints between
    neighbouring halves (ties) and their float32 neighbours, the range ends, zeros, subnormal
    limits, infinities and NaNs with payloads; both signs."""
    h = np.arange(0x7C00, dtype=np.uint16).view(np.float16)  # every finite non-negative half
    lo = h.astype(np.float64)
    with np.errstate(over="ignore"):  # (past the largest half: infinity, whose midpoint is infinite too)
        hi = np.nextafter(h, np.float16(np.inf)).astype(np.float64)
    mid = ((lo + hi) / 2.0).astype(np.float32)  # exact in float32 (halves have 11 significant bits)
    special = np.array([0.0, 2.0**-25, 2.0**-24, 1.5 * 2.0**-25, 2.0**-14, 2.0**-15, 65504.0, 65519.996, 65520.0,
                        65536.0, 1e30, np.finfo(np.float32).max, np.finfo(np.float32).tiny, 1e-45], np.float32)
    bits = [np.array([0x7F800000, 0x7F800001, 0x7FC00000, 0x7F802000, 0x7FFFFFFF], np.uint32).view(np.float32)]
    x = np.concatenate([h.astype(np.float32), mid, np.nextafter(mid, np.float32(0)),
                        np.nextafter(mid, np.float32(np.inf)), special, *bits])
    return np.concatenate([x, -x])


@pytest.mark.parametrize("threads", [True, False])
def test_half_bits_equal_numpy_bit_for_bit(threads):
    rng = np.random.default_rng(0)
    x = np.concatenate([_hard_float32(), rng.integers(0, 2**32, 2_000_000, dtype=np.uint64).astype(np.uint32)
                        .view(np.float32)])
    with np.errstate(over="ignore", invalid="ignore"):
        want = ref.half_bits(x)
    got = sh_output.half_bits(x.reshape(-1, 2)[:, :], threads=threads)  # shape kept
    assert got.shape == (x.size // 2, 2) and got.dtype == np.float16
    assert np.array_equal(got.reshape(-1).view(np.uint16), want.view(np.uint16))


def test_half_bits_rejects_other_dtypes():
    with pytest.raises(TypeError, match="float32"):
        sh_output.half_bits(np.zeros(4))


def test_half_bits_where_converts_the_selected_rows_only():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(500, 9, 3)).astype(np.float32)
    other = rng.normal(size=(500, 9, 3)).astype(np.float16)
    rows = rng.random(500) < 0.4
    got = sh_output.half_bits_where(rows, x, other, threads=False)
    want = np.where(rows[:, None, None], x.astype(np.float16), other)
    assert np.array_equal(got.view(np.uint16), want.view(np.uint16))
    with pytest.raises(ValueError):
        sh_output.half_bits_where(rows[:-1], x, other)


def test_half_segments_equal_is_ieee_equality_per_segment():
    a = np.array([0.0, 1.0, 2.0, -0.0, np.nan, 3.0, 5.0], np.float16)
    b = np.array([-0.0, 1.0, 2.0, 0.0, np.nan, 3.0, 6.0], np.float16)
    starts = np.array([0, 1, 3, 4, 5, 5, 6])
    ends = np.array([1, 3, 4, 5, 6, 5, 7])  # [0], [1, 2], [3], [nan], [5], empty, [6]
    got = sh_output.half_segments_equal(a, b, starts, ends)
    want = [bool((a[s:e] == b[s:e]).all()) for s, e in zip(starts, ends, strict=True)]
    assert got.tolist() == want == [True, True, True, False, True, True, False]


def test_row_display_changes_match_the_numpy_bound():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(3000, 16, 3)).astype(np.float32)
    b = a + rng.normal(scale=1e-2, size=a.shape).astype(np.float32)
    b[::7] = a[::7]
    want = ref.row_display_changes(a, b)
    got = sh_output.row_display_changes(a, b)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert np.all(got[::7] == 0.0)
    rows = rng.random(3000) < 0.5
    masked = sh_output.row_display_changes(a, b.astype(np.float64), rows, threads=False)
    np.testing.assert_allclose(masked, np.where(rows, want, 0.0), rtol=1e-6)
    # one degree-0 coefficient off by d moves the colour by d Y_00 = d / sqrt(4 pi) at most
    c = np.zeros((1, 1, 3), np.float32)
    d = c.copy()
    d[0, 0, 1] = 0.5
    assert sh_output.row_display_changes(c, d)[0] == pytest.approx(0.5 / np.sqrt(4.0 * np.pi), rel=1e-7)


@pytest.mark.parametrize("f", [1.0, 0.8, 0.3])
def test_shade_rows_equal_the_masked_scale_bit_for_bit(f):
    rng = np.random.default_rng(3)
    n = 20000
    sh = rng.normal(size=(n, 9, 3)).astype(np.float32)
    t = rng.random(n).astype(np.float32)
    t[::5] = 1.0
    sky = rng.random(n).astype(np.float32)
    sky[::3] = 1.0
    lit = rng.random(n) < 0.6
    want = sh.copy()
    want[lit] = scale_sh(sh[lit], attenuation_factor(t[lit], f) * sky[lit][:, None])
    for threads in (True, False):
        got = shade_rows(sh, lit, t, sky, f, threads=threads)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
    with pytest.raises(ValueError):
        shade_rows(sh, lit[:-1], t, sky, f)
