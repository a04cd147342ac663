"""The sky a moving caster hides from the receivers around it (its ambient occlusion on them).

An avatar standing on sunlit ground does not only block the sun: it also hides part of the sky
from the ground around it, most near its feet and in its own sun shadow. The DGSMs model the
sun; this module models the sky part with a cheap, closed-form proxy:

- the caster is a vertical stack of ``n`` spheres (:func:`sphere_proxy`): its opaque Gaussians
  (opacity >= ``min_opacity``) sliced into ``n`` slabs of equal height along ``up``; each slab is
  a sphere at the slab's opacity-weighted centroid whose cross-section equals the slab's side
  area (height x the mean of its two horizontal widths, each from the 2nd-98th percentile range
  of the centres along the slab's principal axes);
- a sphere of radius ``r`` whose centre lies at distance ``d`` in unit direction ``w`` from a
  receiver with unit normal ``n`` hides the cosine-weighted share ``(r / d)^2 max(n.w, 0)`` of the
  receiver's hemisphere (the form factor of a sphere wholly above the receiver's horizon; a
  sphere that reaches below it counts only by its centre's cosine, an approximation); the
  spheres' shares are summed and clipped to 1 (:func:`hidden_sky_share`). Receiver normals are
  taken two-sided (``|n.w|``), so the side of a flat Gaussian facing the caster counts.

The share removes ``sky_share * hidden / V`` of a receiver's light (linear), with ``sky_share``
the sky's part of a lit receiver's light and ``V`` a lit receiver's sky visibility (both from
the estimated sun and sky, or 1 - the direct fraction and 1 for authored lights):
:func:`sky_factor` turns it into the display-referred colour factor that multiplies the sun's
``1 - f + f T`` (``usd_gs.shadows.shading``). Lengths in scene units; positions world space.
"""

from __future__ import annotations

import numpy as np

from usd_gs.colorspace import srgb_encode
from usd_gs.gaussians import GaussianSet, quaternion_to_matrix


def sphere_proxy(g: GaussianSet, up: np.ndarray, n: int = 8, min_opacity: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """``(centres (k, 3), radii (k,))`` float64, k <= n: the caster ``g`` as a stack of spheres
    (module docstring). Empty arrays when no Gaussian reaches ``min_opacity``."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    keep = g.opacities >= min_opacity
    if keep.sum() < 8:
        return np.zeros((0, 3)), np.zeros(0)
    p = g.positions[keep].astype(np.float64)
    w = g.opacities[keep].astype(np.float64)
    h = p @ up
    lo, hi = np.percentile(h, [1.0, 99.0])
    if not hi > lo:
        return np.zeros((0, 3)), np.zeros(0)
    edges = np.linspace(lo, hi, n + 1)
    slab = np.clip(np.searchsorted(edges, h, side="right") - 1, 0, n - 1)
    dh = (hi - lo) / n
    centres, radii = [], []
    for k in range(n):
        sel = slab == k
        if sel.sum() < 4:
            continue
        q = p[sel]
        c = np.average(q, axis=0, weights=w[sel])
        flat = (q - c) - np.outer((q - c) @ up, up)  # horizontal offsets
        _, vecs = np.linalg.eigh(flat.T @ flat)
        axes = vecs[:, 1:]  # the two largest: the horizontal principal axes
        proj = flat @ axes
        widths = np.percentile(proj, 98.0, axis=0) - np.percentile(proj, 2.0, axis=0)
        area = dh * float(np.mean(widths))
        centres.append(c)
        radii.append(np.sqrt(max(area, 0.0) / np.pi))
    return np.array(centres).reshape(-1, 3), np.array(radii)


def reach(radii: np.ndarray, min_share: float) -> float:
    """Distance beyond which the proxy hides less than ``min_share`` of any receiver's sky:
    ``sqrt(sum r^2 / min_share)`` (every sphere at its nearest, cosine 1)."""
    return float(np.sqrt(np.sum(np.asarray(radii, np.float64) ** 2) / max(min_share, 1e-12)))


def hidden_sky_share(centres: np.ndarray, radii: np.ndarray, positions: np.ndarray,
                     normals: np.ndarray) -> np.ndarray:
    """(M,) float64 in [0, 1]: the cosine-weighted share of each receiver's hemisphere the
    spheres hide (module docstring; ``numba_kernels.sky_occlusion``); ``positions`` (M, 3), unit
    ``normals`` (M, 3) two-sided. A receiver inside a sphere is wholly hidden."""
    from numba_kernels.sky_occlusion import hidden_sky_share as kernel

    return kernel(centres, radii, positions, normals)


def receiver_normals(g: GaussianSet, idx: np.ndarray) -> np.ndarray:
    """(len(idx), 3) unit normals of receivers ``idx``: each Gaussian's smallest axis (sign
    arbitrary: :func:`hidden_sky_share` is two-sided)."""
    q = g.orientations[idx]
    s = g.scales[idx]
    r = quaternion_to_matrix(q)
    k = np.argmin(s, axis=1)
    return r[np.arange(len(idx)), :, k]


def sky_factor(hidden: np.ndarray, sun_t: np.ndarray, direct_share: float, sky_visibility: float,
               lit_luminance: float) -> np.ndarray:
    """(M,) display-referred colour factor of the sky a caster hides (module docstring), to
    multiply the sun's shadow factor: ``Y'(L (D T + S (1 - h / V))) / Y'(L (D T + S))`` with ``Y'``
    the sRGB encoding of a grey of linear luminance, ``L`` the lit receivers' linear luminance
    (``lit_luminance``), ``D`` the sun's share of a lit receiver's light (``direct_share``),
    ``S = 1 - D``, ``T`` the receiver's sun transmittance ``sun_t`` and ``h`` the hidden share
    (``hidden``), ``V`` = ``sky_visibility`` (clipped so that at most the whole sky is removed)."""
    d = float(np.clip(direct_share, 0.0, 1.0))
    s = 1.0 - d
    v = max(float(sky_visibility), 1e-3)
    lum = max(float(lit_luminance), 1e-6)
    t = np.clip(np.asarray(sun_t, np.float64), 0.0, 1.0)
    before = lum * (d * t + s)
    after = lum * (d * t + s * (1.0 - np.clip(np.asarray(hidden, np.float64) / v, 0.0, 1.0)))
    num = srgb_encode(after)
    den = srgb_encode(before)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def min_hidden_share(params: tuple[float, float, float], tolerance: float) -> float:
    """The smallest hidden share whose :func:`sky_factor` on an unshadowed receiver departs from 1
    by ``tolerance`` or more (bisection; 1 when even the whole sky does not)."""
    d, v, lum = params
    if 1.0 - float(sky_factor(np.array([v]), np.ones(1), d, v, lum)[0]) < tolerance:
        return 1.0
    lo, hi = 0.0, float(v)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if 1.0 - float(sky_factor(np.array([mid]), np.ones(1), d, v, lum)[0]) >= tolerance:
            hi = mid
        else:
            lo = mid
    return hi


def static_sky_factors(casters: list[GaussianSet], receivers, prim_spheres: dict, up: np.ndarray,
                       params: tuple[float, float, float], tolerance: float,
                       sun_t=None, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The sky ``casters`` (this frame's moving casters, world space) hide from the static
    ``receivers`` (``usd_gs.shadows.shot.Receivers``) around them, sparse: ``(idx (K,) int64
    receiver indices, factor (K,) float32 < 1)`` (:func:`sky_factor`), every other receiver 1.
    ``prim_spheres``: each receiver prim's bounding sphere (``prim_spheres`` of the shadow pass,
    for prim-level culling); ``params``: ``(D, V, L)``; receivers whose hidden share stays below
    :func:`min_hidden_share` of ``tolerance`` are left out; ``sun_t``: ``(idx, T)`` of the
    receivers some light's shadow reaches (their sun transmittance, 1 elsewhere); ``normals``: (N, 3)
    of every receiver if known (:func:`receiver_normals`; static receivers: compute them once per
    shot), else computed for the receivers in reach."""
    return sky_factors_from_shares(hidden_sky_shares(casters, receivers, prim_spheres, up, params, tolerance, normals),
                                   params, sun_t)


def hidden_sky_shares(casters: list[GaussianSet], receivers, prim_spheres: dict, up: np.ndarray,
                      params: tuple[float, float, float], tolerance: float,
                      normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The first half of :func:`static_sky_factors` (same arguments, no ``sun_t``; it needs no
    shadow map): ``(idx (K,) int64 sorted receiver indices, h (K,) float64)``, the share of each
    receiver's sky the casters hide, for the receivers where it reaches :func:`min_hidden_share`
    (:func:`caster_hidden_parts` of each caster, :func:`combine_hidden_parts`)."""
    h_min = min_hidden_share(params, tolerance)
    if receivers.gaussians.count == 0 or h_min >= 1.0:
        return np.zeros(0, np.int64), np.zeros(0, np.float32)
    parts = [part for c in casters for part in caster_hidden_parts(c, receivers, prim_spheres, up, h_min, normals)]
    return combine_hidden_parts(parts, h_min)


def caster_hidden_parts(caster: GaussianSet, receivers, prim_spheres: dict, up: np.ndarray, h_min: float,
                        normals: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """One caster's ``(receiver indices, hidden share)`` per receiver prim within its reach of
    ``h_min`` (arguments as :func:`hidden_sky_shares`): what :func:`combine_hidden_parts` adds up."""
    g = receivers.gaussians
    centres, radii = sphere_proxy(caster, up)
    if radii.size == 0:
        return []
    r_far = reach(radii, h_min)
    mid = centres.mean(axis=0)
    span = float(np.max(np.linalg.norm(centres - mid, axis=1) + radii))
    parts = []
    for path, (a, b) in receivers.ranges.items():
        sc, sr = prim_spheres.get(path, (None, None))
        if sc is None or np.linalg.norm(np.asarray(sc) - mid) > sr + span + r_far:
            continue
        x = g.positions[a:b].astype(np.float64)
        v = x - mid
        near = np.flatnonzero(np.einsum("ij,ij->i", v, v) <= (span + r_far) ** 2)
        if near.size == 0:
            continue
        idx = a + near
        parts.append((idx, hidden_sky_share(centres, radii, x[near],
                                            normals[idx] if normals is not None else receiver_normals(g, idx))))
    return parts


def combine_hidden_parts(parts: list, h_min: float) -> tuple[np.ndarray, np.ndarray]:
    """``(idx, h)`` of :func:`hidden_sky_shares` from its casters' :func:`caster_hidden_parts`, in
    order (the casters' shares add, clipped at 1; only ``h >= h_min`` kept)."""
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.float32)
    idx, inv = np.unique(np.concatenate([i for i, _ in parts]), return_inverse=True)  # sorted
    h = np.minimum(np.bincount(inv, weights=np.concatenate([h for _, h in parts]), minlength=idx.size), 1.0)
    keep = h >= h_min
    return idx[keep], h[keep]


def sky_factors_from_shares(shares: tuple[np.ndarray, np.ndarray], params: tuple[float, float, float],
                            sun_t=None) -> tuple[np.ndarray, np.ndarray]:
    """The second half of :func:`static_sky_factors`: ``(idx, factor float32)`` from
    :func:`hidden_sky_shares` ``(idx, h)`` and the receivers' sun transmittance ``sun_t``."""
    idx, h = shares
    if idx.size == 0:
        return idx, np.zeros(0, np.float32)
    t = np.ones(idx.size)
    if sun_t is not None and len(sun_t[0]):
        pos = np.searchsorted(sun_t[0], idx)
        hit = (pos < len(sun_t[0])) & (sun_t[0][np.minimum(pos, len(sun_t[0]) - 1)] == idx)
        t[hit] = np.asarray(sun_t[1], np.float64)[pos[hit]]
    d, v, lum = params
    return idx, sky_factor(h, t, d, v, lum).astype(np.float32)
