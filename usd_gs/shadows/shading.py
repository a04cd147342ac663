"""Per-Gaussian shading arithmetic of the main job: combining lights, attenuating SH.

Colour convention (shared/DESIGN.md): a Gaussian's colour is ``c(dir) = 0.5 + SH(dir)``
(3DGS basis). Shadowing scales the direct part of the colour:

    c'(dir) = c(dir) * (1 - f + f * T)

with ``T`` the light-weighted transmittance and ``f`` the direct fraction
(``--direct-fraction``, default 1: the captured colour is treated as all direct light).
In coefficient space this is :func:`numba_kernels.sh_transfer.relight_sh_coefficients`
with a grey per-Gaussian factor.

Lights are combined by their share of the direct light at each receiver: point light ``l``
with intensity ``I_l`` (times colour luminance) at distance ``r`` contributes
``w_l = I_l / r^2`` (a directional light ``I_l``), normalised over lights. The combined
transmittance is ``T = sum_l w_l T_l``: the fraction of direct light that still arrives
(one light fully blocked and an equal one open gives 0.5, as it should).
"""

from __future__ import annotations

import numpy as np

#: transmittance at or above this counts as unshadowed (snapped to exactly 1)
UNSHADOWED = 1.0 - 1e-5


def light_shares(lights, positions: np.ndarray) -> np.ndarray:
    """(L, N) float64 weights summing to 1 over lights for each receiver position (N, 3)."""
    n = positions.shape[0]
    if not lights:
        return np.zeros((0, n))
    w = np.empty((len(lights), n))
    p = positions.astype(np.float64)
    for i, light in enumerate(lights):
        strength = max(light.luminous_weight, 0.0)
        if light.kind == "directional":
            w[i] = strength
        else:
            d2 = np.sum((p - light.position) ** 2, axis=1)
            w[i] = strength / np.maximum(d2, 1e-6)
    total = w.sum(axis=0)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), 1.0 / len(lights))


def combine_lights(per_light: list[np.ndarray], shares: np.ndarray) -> np.ndarray:
    """(N,) float32 ``sum_l shares[l] * T_l``, snapped to 1 where >= :data:`UNSHADOWED`."""
    if not per_light:
        return np.ones(shares.shape[1], np.float32)
    t = np.zeros(shares.shape[1])
    for s, tl in zip(shares, per_light, strict=True):
        t += s * tl
    t = np.clip(t, 0.0, 1.0)
    t[t >= UNSHADOWED] = 1.0
    return t.astype(np.float32)


def attenuation_factor(transmittance: np.ndarray, direct_fraction: float) -> np.ndarray:
    """(N, 3) float32 colour factor ``1 - f + f T`` (grey)."""
    f = float(direct_fraction)
    k = (1.0 - f) + f * np.asarray(transmittance, np.float64)
    return np.repeat(k[:, None], 3, axis=1).astype(np.float32)


def shade_sh_rows(sh: np.ndarray, lit: np.ndarray, transmittance: np.ndarray, sky: np.ndarray,
                  direct_fraction: float, threads: bool = True) -> np.ndarray:
    """(N, K, 3) float32: the rows of ``sh`` where ``lit`` (N,) bool shadowed by
    ``attenuation_factor(transmittance, direct_fraction) * sky`` (``sky`` (N,) the share of the sky still
    seen), the others as they are: ``scale_sh`` of the lit rows, bit for bit, in one pass
    (``numba_kernels.sh_transfer.shade_rows``; ``threads`` False: in the calling thread)."""
    from numba_kernels.sh_transfer import shade_rows

    return shade_rows(sh, lit, transmittance, sky, direct_fraction, threads)


def scale_sh(sh: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """SH coefficients whose colour is ``factor * c(dir)`` (see module docstring)."""
    from numba_kernels.sh_transfer import relight_sh_coefficients

    return relight_sh_coefficients(sh, factor, 1.0)
