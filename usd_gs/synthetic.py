"""Random but realistic Gaussian sets for tests and benchmarks.

``random_gaussians(n, degree, seed)`` draws, with ``numpy.random.default_rng(seed)``:

- positions uniform in the 10 m box [-5, 5]^3 (metres),
- log-scales ~ N(-4, 1) (sigma about 1.8 cm, from 0.7 mm to 0.5 m at 3 sd),
- opacity logits ~ N(0, 2),
- orientations uniform on the unit-quaternion sphere, (w, x, y, z),
- SH in the 3DGS basis: DC ~ N(0, 1), higher bands ~ N(0, 0.1).

The raw ``log_scales`` / ``logit_opacities`` are kept and the linear ``scales`` /
``opacities`` derived from them exactly as :func:`usd_gs.io.ply.read_ply` does, so a set
written with ``write_ply`` reads back equal.
"""

from __future__ import annotations

import numpy as np

from usd_gs import sh3dgs
from usd_gs.gaussians import GaussianSet, opacities_from_logit, scales_from_log


def random_gaussians(n: int, degree: int = 3, seed: int = 0) -> GaussianSet:
    """``n`` random Gaussians with SH ``degree`` (0..3), reproducible from ``seed``."""
    if not 0 <= degree <= sh3dgs.MAX_DEGREE:
        raise ValueError(f"SH degree must be 0..{sh3dgs.MAX_DEGREE}, got {degree}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    f32 = np.float32
    positions = rng.uniform(-5.0, 5.0, size=(n, 3)).astype(f32)
    log_scales = (rng.standard_normal((n, 3), dtype=f32) - f32(4.0)).astype(f32)
    logits = (rng.standard_normal(n, dtype=f32) * f32(2.0)).astype(f32)
    q = rng.standard_normal((n, 4))
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 1e-12, q / np.where(norm > 1e-12, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    k = sh3dgs.num_coeffs(degree)
    sh = np.empty((n, k, 3), dtype=f32)
    sh[:, 0, :] = rng.standard_normal((n, 3), dtype=f32)
    if k > 1:
        sh[:, 1:, :] = rng.standard_normal((n, k - 1, 3), dtype=f32) * f32(0.1)
    return GaussianSet(positions, q.astype(f32), scales_from_log(log_scales), opacities_from_logit(logits), sh,
                       log_scales=log_scales, logit_opacities=logits,
                       label=f"random_gaussians(n={n}, degree={degree}, seed={seed})")
