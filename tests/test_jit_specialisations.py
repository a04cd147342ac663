"""Compile-time invariants: one numba specialisation per kernel for the inputs the main job passes,
and the parallel JIT warm-up (usd_gs.pipeline.jit_warmup) creates exactly one per rasteriser kernel."""

from __future__ import annotations

import numpy as np

from numba_kernels import rasterize, sh_real, sh_transfer
from numba_kernels.sh_transfer import relight_sh_coefficients


def test_relight_one_specialisation_for_readonly_and_writable_inputs():
    rng = np.random.default_rng(3)
    sh = rng.normal(size=(50, 16, 3)).astype(np.float32)
    scale = rng.uniform(0.5, 2.0, (50, 3)).astype(np.float32)
    ro = sh.copy()
    ro.flags.writeable = False
    a = relight_sh_coefficients(sh, scale, 1.5)
    b = relight_sh_coefficients(ro, scale, 1.5)
    np.testing.assert_array_equal(a, b)
    # reference: sh'_0 = (f (0.5 + C0 sh_0) - 0.5) / C0, sh'_k = f sh_k
    f = 1.5 * scale.astype(np.float64)
    c0 = sh_real.SH_C0
    np.testing.assert_allclose(a[:, 0], (f * (0.5 + c0 * sh[:, 0]) - 0.5) / c0, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(a[:, 1:], f[:, None, :] * sh[:, 1:], rtol=1e-6)
    assert len(sh_transfer._relight_kernel.signatures) == 1


def test_warm_up_compiles_one_specialisation_per_rasteriser_kernel():
    from usd_gs.pipeline import jit_warmup

    jit_warmup.warm_up()
    for kernel in (rasterize._cull, rasterize._write_entries, rasterize._bin_tiles, rasterize._blend):
        assert len(kernel.signatures) == 1, kernel
