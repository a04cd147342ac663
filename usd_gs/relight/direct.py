"""The direct term of the relighting: irradiance from each modelled light (UsdLux, ``usd_gs.usd.lux``).

For a receiver at ``x`` (metres, world) with unit normal ``n``, the unshadowed direct irradiance
of one light, per channel, in the linear units of ``usd_gs.usd.lux`` (radiance 1 = the linear
colour of a white Lambertian surface under a uniform environment of radiance 1):

- point (``treatAsPoint`` or radius 0): ``I max(0, n.l) / r^2`` with ``I`` the light's
  ``radiant_intensity()``, ``l`` the unit vector to the light, ``r`` the distance;
- sphere of radius R: the exact irradiance of a uniform spherical cap of angular radius
  ``asin(R / r)`` with the receiver's horizon clipping it (:func:`cap_irradiance`, Snyder's
  closed form as given in Lagarde & de Rousiers, "Moving Frostbite to PBR", 2014, eq. 18 and
  listing 7), times the sphere's radiance; ``r < R`` is taken as ``r = R``;
- distant: the same cap formula for the sun disc (angular radius ``angle / 2``) around the
  direction toward the light, scaled to ``sun_irradiance()`` at normal incidence (``angle = 0``:
  ``sun_irradiance() max(0, n.s)``);
- rect (``width`` x ``height`` in the light's local x, y; emits along its local -Z, one-sided)
  and disk (radius R, same axes): ``sum_s L A_s max(0, n.w_s) max(0, -z.(-w_s)) / r_s^2`` over
  :data:`AREA_SAMPLES` stratified samples (a 4 x 4 grid of cell centres, a 16-point
  sunflower disk), ``w_s`` the unit vector from ``x`` to sample ``s``;
- dome: not a direct term. A dome is the environment behind the probe render
  (``usd_gs.relight.avatar``): its light reaches a Gaussian through the probe, occluded by the
  scene as the probe sees it.

Everything is vectorised over receivers (float64, no loop over Gaussians; the point form in one
threaded pass, ``numba_kernels.point_irradiance``); lights are few.
"""

from __future__ import annotations

import math

import numpy as np

AREA_SAMPLES = 16


def cap_irradiance(cos_theta: np.ndarray, sin_sigma: float) -> np.ndarray:
    """Irradiance (per unit radiance) on a plane from a uniform spherical cap of angular radius
    ``sigma`` (``sin_sigma`` in (0, 1]) whose centre is at angle ``theta`` from the plane's normal
    (``cos_theta`` (N,)): ``pi sin^2(sigma) cos(theta)`` while the cap is above the horizon,
    Snyder's closed form where the horizon cuts it, 0 below (module docstring)."""
    ct = np.asarray(cos_theta, np.float64).reshape(-1)
    return _sphere(ct, np.full(ct.shape, float(sin_sigma)))


def _area_samples(light) -> tuple[np.ndarray, float]:
    """(S, 3) world sample points on a rect or disk light and the area each stands for."""
    ax = np.asarray(light.axes, np.float64)
    c = np.asarray(light.position, np.float64)
    k = int(round(math.sqrt(AREA_SAMPLES)))
    if light.form == "rect":
        u = (np.arange(k) + 0.5) / k - 0.5
        a, b = np.meshgrid(u * light.width, u * light.height, indexing="ij")
        pts = c + a.reshape(-1, 1) * ax[:, 0] + b.reshape(-1, 1) * ax[:, 1]
        return pts, light.width * light.height / (k * k)
    n = AREA_SAMPLES
    i = np.arange(n) + 0.5
    rad = light.radius * np.sqrt(i / n)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    pts = c + (rad * np.cos(phi))[:, None] * ax[:, 0] + (rad * np.sin(phi))[:, None] * ax[:, 1]
    return pts, math.pi * light.radius ** 2 / n


def direct_irradiance(light, positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 3) float64 unshadowed direct irradiance of ``light`` (a ``usd_gs.usd.lux.ShotLight``) at
    ``positions`` (N, 3) metres about unit ``normals`` (N, 3) (module docstring); zeros for a dome."""
    form = light.form
    count = np.asarray(positions).reshape(-1, 3).shape[0]
    if form == "dome" or count == 0:
        return np.zeros((count, 3))
    area = form in ("rect", "disk")
    sphere = form == "sphere" and light.radius > 0
    if form != "distant" and not area and not sphere:  # a point (a sphere of radius 0): one threaded pass
        from numba_kernels.point_irradiance import point_irradiance

        return point_irradiance(positions, normals, light.position, light.radiant_intensity())
    x = np.asarray(positions, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    if form == "distant":
        s = -np.asarray(light.direction, np.float64)
        s = s / np.linalg.norm(s)
        cos = n @ s
        e = np.asarray(light.sun_irradiance(), np.float64)
        half = math.radians(light.angle) / 2.0
        if half <= 0:
            return np.maximum(cos, 0.0)[:, None] * e[None, :]
        normal = math.pi * math.sin(half) ** 2  # the disc's irradiance at normal incidence per unit radiance
        return (cap_irradiance(cos, math.sin(half)) / normal)[:, None] * e[None, :]
    if area:
        pts, da = _area_samples(light)
        z = np.asarray(light.axes, np.float64)[:, 2]
        lrad = np.asarray(light.radiance(), np.float64)
        acc = np.zeros(x.shape[0])
        for p in pts:  # AREA_SAMPLES samples, each vectorised over receivers
            w = p - x
            r2 = np.maximum(np.einsum("ij,ij->i", w, w), 1e-12)
            r = np.sqrt(r2)
            cos_r = np.maximum(np.einsum("ij,ij->i", n, w) / r, 0.0)
            cos_e = np.maximum((w @ z) / r, 0.0)  # emits along -Z: receivers where w . z > 0
            acc += cos_r * cos_e / r2
        return (acc * da)[:, None] * lrad[None, :]
    d = np.asarray(light.position, np.float64) - x  # sphere
    r2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    r = np.sqrt(r2)
    cos = np.einsum("ij,ij->i", n, d) / r
    sin_sigma = light.radius / np.maximum(r, light.radius)
    return _sphere(cos, sin_sigma)[:, None] * np.asarray(light.radiance(), np.float64)[None, :]


def _sphere(cos: np.ndarray, sin_sigma: np.ndarray) -> np.ndarray:
    """:func:`cap_irradiance` with a per-receiver ``sin_sigma`` (N,) in (0, 1]."""
    ct = np.clip(cos, -1.0, 1.0)
    s2 = np.minimum(sin_sigma, 1.0) ** 2
    out = np.pi * s2 * np.maximum(ct, 0.0)
    part = (ct * ct <= s2) & (s2 < 1.0)
    if part.any():
        c, q = ct[part], s2[part]
        st = np.sqrt(np.maximum(1.0 - c * c, 1e-300))
        xx = np.sqrt(1.0 / q - 1.0)
        y = np.clip(-xx * c / st, -1.0, 1.0)
        sty = st * np.sqrt(np.maximum(1.0 - y * y, 0.0))
        out[part] = np.maximum((c * np.arccos(y) - xx * sty) * q + np.arctan(sty / xx), 0.0)
    full = s2 >= 1.0
    if full.any():
        out[full] = np.pi * 0.5 * (1.0 + ct[full])
    return out


def light_direction(light, point) -> np.ndarray:
    """(3,) unit direction from ``point`` (3,) toward ``light`` (toward the sun for a distant one)."""
    if light.kind == "directional":
        s = -np.asarray(light.direction, np.float64)
    else:
        s = np.asarray(light.position, np.float64) - np.asarray(point, np.float64)
    return s / max(float(np.linalg.norm(s)), 1e-12)


def direct_factors(lights, positions: np.ndarray, normals: np.ndarray, visibility=None,
                   irradiance=None) -> np.ndarray:
    """(N, 3) float64 ``sum_l E_l(x, n) V_l(x)``: every light's direct irradiance times its
    visibility (``visibility``: list of (N,) arrays in [0, 1] per light, or None entries / None
    for 1). ``irradiance``: each light's :func:`direct_irradiance` at these positions and normals
    where the caller has it (a list, None entries / None: computed here)."""
    x = np.asarray(positions, np.float64)
    out = np.zeros((x.shape[0], 3))
    for i, lt in enumerate(lights):
        if lt.kind == "dome":
            continue
        e = irradiance[i] if irradiance is not None and irradiance[i] is not None else direct_irradiance(lt, x, normals)
        v = None if visibility is None else visibility[i]
        out += e if v is None else e * np.clip(np.asarray(v, np.float64), 0.0, 1.0)[:, None]
    return out


def self_shadow_samples(positions: np.ndarray, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``(sel, nearest)`` for sampling a prim's self-shadowing at a subset of its Gaussians: ``sel``
    every k-th index (k = ceil(N / n_samples)), ``nearest`` (N,) the position in ``sel`` of each
    Gaussian's nearest sample (itself when k = 1). Positions (N, 3) metres."""
    pos = np.asarray(positions, np.float64)
    n = pos.shape[0]
    step = max(1, -(-n // max(int(n_samples), 1)))
    sel = np.arange(0, n, step)
    if step == 1:
        return sel, np.arange(n)
    from numba_kernels.grid_neighbours import nearest

    return sel, nearest(pos[sel], pos)
