"""A minimal open scene with known sun and sky, baked with exact visibility (pure numpy).

Y-up, metres. A square ground ``[-g, g]^2`` at y = 0 and axis-aligned boxes (a statue-sized
caster by default, 0.8 x 1.8 x 0.6 m at the origin) covered with flat Gaussians on jittered
grids (local z = the surface normal, opacity 0.97). Nothing above: no sky Gaussians.

Baked colour of a surface point with normal n and linear albedo rho (the 3DGS DC colour,
sRGB-encoded, clipped to [0, 1]):

    L = rho / pi * (E_sun max(0, n.s) T_sun + L_sky * int_{up hemisphere} max(0, n.w) V(w) dw)

with ``T_sun`` the share of ``sun_samples`` directions inside the sun's disc (angular diameter
``sun_angle_deg``) that no box blocks, ``V`` the exact ray-box visibility, the sky integral
by ``sky_samples`` cosine-weighted directions over the normal's hemisphere restricted to
directions above the horizon. ``E_sun`` is the sun's irradiance at normal incidence and
``L_sky`` the uniform sky radiance (horizontal irradiance of the unoccluded sky ``E_sky =
pi L_sky``); ``ratio = E_sun / E_sky``. ``overcast=True`` sets E_sun = 0. ``exposure`` scales
L so the lit ground's display colour stays below 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usd_gs.gaussians import GaussianSet, matrix_to_quaternion

SH_C0 = 0.28209479177387814


@dataclass
class SunScene:
    """The scene (``gaussians``), its truth: ``sun`` (3,) unit towards the sun, ``ratio``
    E_sun / E_sky, ``e_sun``, ``l_sky``, per-Gaussian ``albedo`` (N, 3), ``normal`` (N, 3),
    ``part`` (N,) 0 ground 1 box, the linear radiance ``radiance`` (N, 3) before exposure and
    clipping, the ``boxes`` ((lo, hi) pairs) and ``exposure``."""

    gaussians: GaussianSet
    sun: np.ndarray
    ratio: float
    e_sun: float
    l_sky: float
    albedo: np.ndarray
    normal: np.ndarray
    part: np.ndarray
    radiance: np.ndarray
    boxes: list = field(default_factory=list)
    exposure: float = 1.0


def srgb_encode(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _frame(n: np.ndarray) -> np.ndarray:
    h = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(h, n)
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(n, a), n], axis=1)  # columns: tangent, bitangent, normal


def _rect(origin, eu, ev, normal, spacing, rng):
    o, eu, ev = (np.asarray(v, np.float64) for v in (origin, eu, ev))
    nu = max(int(np.ceil(np.linalg.norm(eu) / spacing)), 1)
    nv = max(int(np.ceil(np.linalg.norm(ev) / spacing)), 1)
    u, v = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv, indexing="ij")
    u = u.ravel() + rng.uniform(-0.3, 0.3, u.size) / nu
    v = v.ravel() + rng.uniform(-0.3, 0.3, v.size) / nv
    pts = o + u[:, None] * eu + v[:, None] * ev
    return pts, np.broadcast_to(np.asarray(normal, np.float64), pts.shape)


def _box_faces(lo, hi):
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    d = hi - lo
    ex, ey, ez = np.array([d[0], 0, 0]), np.array([0, d[1], 0]), np.array([0, 0, d[2]])
    return [(lo, ex, ez, (0, -1, 0)), (lo + ey, ex, ez, (0, 1, 0)), (lo, ex, ey, (0, 0, -1)),
            (lo + ez, ex, ey, (0, 0, 1)), (lo, ez, ey, (-1, 0, 0)), (lo + ex, ez, ey, (1, 0, 0))]


def ray_box_hit(p: np.ndarray, d: np.ndarray, lo, hi) -> np.ndarray:
    """(N,) bool: the rays ``p + t d`` (t > 0; p (N, 3), d (N, 3) or (3,)) hit the box."""
    d = np.broadcast_to(np.asarray(d, np.float64), p.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1 = (np.asarray(lo) - p) * inv
    t2 = (np.asarray(hi) - p) * inv
    tmin = np.max(np.minimum(t1, t2), axis=1)
    tmax = np.min(np.maximum(t1, t2), axis=1)
    return (tmax >= np.maximum(tmin, 1e-6))


def visible(p, d, boxes) -> np.ndarray:
    out = np.ones(p.shape[0], bool)
    for lo, hi in boxes:
        out &= ~ray_box_hit(p, d, lo, hi)
    return out


def disc_directions(s: np.ndarray, angle_deg: float, n: int, rng) -> np.ndarray:
    """(n, 3) directions uniform over the disc of angular diameter ``angle_deg`` around ``s``."""
    if n <= 1 or angle_deg <= 0:
        return s[None]
    f = _frame(s)
    r = np.radians(angle_deg) / 2 * np.sqrt((np.arange(n) + 0.5) / n)
    phi = np.pi * (3 - np.sqrt(5)) * np.arange(n)
    d = s + np.tan(r)[:, None] * (np.cos(phi)[:, None] * f[:, 0] + np.sin(phi)[:, None] * f[:, 1])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def make_sun_scene(sun_elevation_deg: float = 45.0, sun_azimuth_deg: float = 30.0, ratio: float = 3.0,
                   overcast: bool = False, ground_half: float = 3.0, spacing: float = 0.05,
                   boxes=None, sun_angle_deg: float = 0.53, sun_samples: int = 8, sky_samples: int = 128,
                   seed: int = 0, exposure: float | None = None) -> SunScene:
    """Generate the scene (module docstring). Sun direction: elevation above the ground,
    azimuth from +X towards -Z (``usd_gs.relight.sun_estimation.elevation_azimuth``)."""
    rng = np.random.default_rng(seed)
    el, az = np.radians(sun_elevation_deg), np.radians(sun_azimuth_deg)
    s = np.array([np.cos(el) * np.cos(az), np.sin(el), -np.cos(el) * np.sin(az)])
    boxes = [((-0.4, 0.0, -0.3), (0.4, 1.8, 0.3))] if boxes is None else boxes
    g = ground_half
    pts_l, nrm_l, part_l = [], [], []
    p, n = _rect((-g, 0, -g), (2 * g, 0, 0), (0, 0, 2 * g), (0, 1, 0), spacing, rng)
    inside = np.zeros(len(p), bool)
    for lo, hi in boxes:
        inside |= np.all((p[:, [0, 2]] > np.asarray(lo)[[0, 2]]) & (p[:, [0, 2]] < np.asarray(hi)[[0, 2]]), axis=1)
    pts_l.append(p[~inside])
    nrm_l.append(n[~inside])
    part_l.append(np.zeros((~inside).sum(), np.int8))
    for lo, hi in boxes:
        for o, eu, ev, nr in _box_faces(lo, hi):
            if nr[1] < 0 and np.asarray(lo)[1] <= 1e-9:
                continue  # bottom face on the ground
            p, n = _rect(o, eu, ev, nr, spacing * 0.8, rng)
            pts_l.append(p)
            nrm_l.append(n)
            part_l.append(np.ones(len(p), np.int8))
    pts = np.concatenate(pts_l)
    nrm = np.concatenate(nrm_l)
    part = np.concatenate(part_l)
    m = len(pts)
    # albedo: tiles on the ground (0.5 m squares, +-8 %) with per-Gaussian noise; a grey statue
    tile = np.floor(pts[:, 0] / 0.5) * 7.0 + np.floor(pts[:, 2] / 0.5) * 13.0
    tone = 1.0 + 0.08 * np.sin(tile * 1.7)
    alb = np.where(part[:, None] == 0, np.array([0.55, 0.5, 0.45]) * tone[:, None], np.array([0.6, 0.6, 0.62]))
    alb = np.clip(alb * (1 + 0.04 * rng.standard_normal((m, 1))), 0.02, 0.98)
    e_sky = np.pi  # L_sky = 1
    e_sun = 0.0 if overcast else ratio * e_sky
    lift = pts + 1e-4 * nrm
    # sun
    sun_t = np.zeros(m)
    if e_sun > 0:
        dd = disc_directions(s, sun_angle_deg, sun_samples, rng)
        for d in dd:
            sun_t += visible(lift, d, boxes)
        sun_t /= len(dd)
    # sky: cosine-weighted over each normal's hemisphere, directions above the horizon only
    sky = np.zeros(m)
    u1 = (np.arange(sky_samples) + 0.5) / sky_samples
    phi = np.pi * (3 - np.sqrt(5)) * np.arange(sky_samples)
    local = np.stack([np.sqrt(1 - u1) * np.cos(phi), np.sqrt(1 - u1) * np.sin(phi), np.sqrt(u1)], axis=1)
    for nr in np.unique(nrm, axis=0):
        sel = np.all(nrm == nr, axis=1)
        dirs = local @ _frame(nr).T
        acc = np.zeros(sel.sum())
        for d in dirs:
            if d[1] <= 0:
                continue
            acc += visible(lift[sel], d, boxes)
        sky[sel] = acc / sky_samples * np.pi  # int cos V dw = pi * mean over cosine-weighted samples
    irr = e_sun * np.maximum(nrm @ s, 0.0) * sun_t + 1.0 * sky
    rad = alb * irr[:, None] / np.pi
    if exposure is None:
        exposure = 0.8 / max(float(np.percentile(rad.max(axis=1), 99.5)), 1e-6)
    disp = srgb_encode(rad * exposure)
    rot = np.stack([_frame(nr) for nr in nrm])
    sig = 0.6 * spacing
    scales = np.tile([sig, sig, 0.1 * sig], (m, 1))
    sh = ((disp - 0.5) / SH_C0)[:, None, :].astype(np.float32)
    gs = GaussianSet(pts, matrix_to_quaternion(rot), scales, np.full(m, 0.97), sh, label="sun_scene")
    return SunScene(gs, s, float(0.0 if overcast else ratio), float(e_sun), 1.0, alb, nrm, part, rad,
                    [(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi in boxes], float(exposure))
