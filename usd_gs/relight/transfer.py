"""Relighting Gaussians with an SH probe: SH transfer (paper 3.5) and ZH transfer (RGCA 3.2.1).

SH transfer: per Gaussian, ``s_c(n)`` of eq. 10 (closed form, ``numba_kernels.sh_transfer``)
with ``n`` the outward pseudo-normal (``numba_kernels.normals``), then every SH band is
scaled so that the colour becomes ``c'(dir) = gamma * s_c(n) * c(dir)`` (view dependence
kept; ``relight_sh_coefficients`` gives the exact coefficient-space form).

ZH transfer: diffuse colour ``gamma * albedo * sum_i L_i d_i`` from per-Gaussian ZH
coefficients (``numba_kernels.zh_transfer``); the result is written as degree-0 3DGS SH.
RGCA appearance is read from ``GaussianSet.extras`` under the keys ``zh_albedo`` (N, 3),
``zh_color`` (N, 3, 4, 3) and optional ``zh_mono`` (N, 3, 5) (layouts in
``numba_kernels.zh_transfer``).
"""

from __future__ import annotations

import numpy as np

from numba_kernels.normals import gaussian_normals
from numba_kernels.sh_real import threedgs_to_rh
from numba_kernels.sh_transfer import relight_sh_coefficients, transfer_scale_sh
from numba_kernels.zh_transfer import zh_diffuse_color
from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError, UserError, first_bad_index
from usd_gs.gaussians import GaussianSet
from usd_gs.relight.probe import SHProbe

DEFAULT_Q = 1.0
DEFAULT_T_MAX = 8.0
DEFAULT_EPS = 1e-6


def probe_rh(probe, probe_basis: str | None = None) -> np.ndarray:
    """(K, 3) RH coefficients from an ``SHProbe`` or an array with an explicit basis."""
    if isinstance(probe, SHProbe):
        return probe.rh()
    arr = np.asarray(probe, dtype=np.float64)
    if probe_basis == "rh":
        return arr
    if probe_basis == "3dgs":
        return threedgs_to_rh(arr)
    raise UserError("probe coefficients given as an array need probe_basis='3dgs' or 'rh'")


def relight_scale(normals: np.ndarray, probe, q: float = DEFAULT_Q, t_max: float = DEFAULT_T_MAX,
                  eps: float = DEFAULT_EPS, probe_basis: str | None = None,
                  blend: np.ndarray | None = None) -> np.ndarray:
    """The per-channel factor ``s(n)`` of eq. 10, (N, 3) float32, for unit outward normals
    (N, 3) (world) under ``probe`` (SHProbe, or (K2, 3) array with ``probe_basis``), or under
    P probes ((P, K2, 3) RH array, ``probe_basis='rh'``) blended per Gaussian with ``blend``
    (N, P) weights (``numba_kernels.sh_transfer.transfer_scale_sh``)."""
    nrm = np.asarray(normals, dtype=np.float32)
    if nrm.ndim != 2 or nrm.shape[1] != 3:
        raise UserError(f"relight: normals must have shape (N, 3), got {nrm.shape}")
    bad = ~np.isfinite(nrm)
    if bad.any():
        raise GaussianDataError(f"relight: 'normals' element {first_bad_index(bad)} is not finite")
    if blend is not None:
        if probe_basis != "rh":
            raise UserError("relight: blended probes are given as a (P, K, 3) RH array (probe_basis='rh')")
        return transfer_scale_sh(nrm, np.asarray(probe, np.float64), q, t_max, eps, blend)
    return transfer_scale_sh(nrm, probe_rh(probe, probe_basis), q, t_max, eps)


def relight_sh(sh: np.ndarray, normals: np.ndarray, probe, q: float = DEFAULT_Q, gamma: float = 1.0,
               t_max: float = DEFAULT_T_MAX, eps: float = DEFAULT_EPS, probe_basis: str | None = None):
    """Relit 3DGS SH coefficients and the per-channel factor.

    sh: (N, K, 3) 3DGS basis; normals: (N, 3) unit outward normals (world); probe: SHProbe,
    or (K2, 3) array with ``probe_basis``. Returns ``(sh_relit (N, K, 3) float32,
    scale (N, 3) float32)`` with ``scale = s(n)`` of eq. 10 (gamma not included) and
    ``0.5 + SH'(dir) = gamma * scale * (0.5 + SH(dir))`` for every direction.
    """
    sh = np.asarray(sh)
    if np.shape(normals) != (sh.shape[0], 3):
        raise UserError(f"relight: normals must have shape ({sh.shape[0]}, 3), got {np.shape(normals)}")
    scale = relight_scale(normals, probe, q, t_max, eps, probe_basis)
    return relight_sh_coefficients(sh, scale, gamma), scale


def relight_gaussians(gs: GaussianSet, probe, q: float = DEFAULT_Q, gamma: float = 1.0,
                      t_max: float = DEFAULT_T_MAX, eps: float = DEFAULT_EPS, normals: np.ndarray | None = None,
                      radius: float | None = None, probe_basis: str | None = None):
    """Relight a GaussianSet: returns ``(relit GaussianSet, scale (N, 3), normals (N, 3))``.

    Normals default to ``gaussian_normals`` (smallest axis, oriented outward; ``radius`` is
    its neighbourhood radius in scene units).
    """
    if normals is None:
        normals = gaussian_normals(gs.positions, gs.orientations, gs.scales, gs.opacities, radius=radius)
    sh_new, scale = relight_sh(gs.sh, normals, probe, q, gamma, t_max, eps, probe_basis)
    out = gs.with_label(gs.label)
    out.sh = sh_new
    return out, scale, np.asarray(normals, dtype=np.float32)


def zh_colors(gs: GaussianSet, probe, gamma: float = 1.0, probe_basis: str | None = None) -> np.ndarray:
    """Diffuse colour (N, 3) float32 from the RGCA ZH appearance in ``gs.extras``."""
    for key in ("zh_albedo", "zh_color"):
        if key not in gs.extras:
            raise UserError(f"{gs.label}: ZH relighting needs the per-Gaussian field '{key}'")
    return zh_diffuse_color(gs.orientations, gs.extras["zh_albedo"], gs.extras["zh_color"],
                            gs.extras.get("zh_mono"), probe_rh(probe, probe_basis), gamma)


def zh_relight_gaussians(gs: GaussianSet, probe, gamma: float = 1.0, probe_basis: str | None = None):
    """ZH-relit copy with degree-0 SH whose 3DGS colour equals the diffuse colour.

    Returns ``(GaussianSet, colours (N, 3))``; ``sh0 = (colour - 0.5) / C0``.
    """
    col = zh_colors(gs, probe, gamma, probe_basis)
    out = gs.with_label(gs.label)
    out.sh = ((col.astype(np.float64) - 0.5) / sh3dgs.C0)[:, None, :].astype(np.float32)
    return out, col
