"""Lights for captures: open or closed, a sun and a sky from the capture's own baked shadows.

Everything here works on the static scene Gaussians in world space (``GaussianSet``, apply the
prims' transforms first), positions in scene units, distances of the configs in METRES
(divided by ``meters_per_unit``), colours the display-referred 3DGS DC colour
``0.5 + C0 * sh[:, 0]`` decoded from sRGB to linear before any ratio (shared/DESIGN.md).

1. :func:`classify_capture`: the capture is **open** when a cube render of the scene from the
   avatars' region leaves a large share of the directions above the horizon empty (alpha < 0.5,
   solid-angle weighted, elevation >= ``horizon_deg``) and the paper's light estimation (3.1)
   finds no compact emitter (an HDR cluster: luminance >= ``emitter_luminance`` with peakness
   >= ``emitter_peakness``, or peakness >= ``emitter_peakness_alone``); a share above
   ``open_share_alone`` is open regardless of emitters (a street lamp under an open sky).
2. :func:`estimate_sun` (open captures): the receivers are the scene's flat ground Gaussians
   near the avatars (one surface: a horizontal band around the ground height), the casters
   everything above it. For candidate sun directions ``s`` (unit, towards the sun) over the
   hemisphere, the directional DGSM absorption model of the casters (eqs. 1-5, evaluated on
   each receiver's ray by ``numba_kernels.sun_shadow``, many directions per call) gives
   each receiver's predicted transmittance ``T_i(s)``; its sky visibility ``V_i`` is the
   cosine-weighted mean of ``T_i`` over the coarse candidates. The model of a Lambertian ground
   under sun and sky is ``Y_i = rho_i (E_sky V_i + E_sun cos(s) T_i) / pi``; the score of a
   direction is the partial correlation of the receivers' linear luminance ``Y`` with ``T(s)``
   given ``[1, V]`` (opacity weighted): 1 for a shadow that explains the darkening the sky
   visibility does not, about 0 under an overcast sky (where ``Y ~ V``). Coarse to fine: a
   Fibonacci hemisphere, then three local grids around the best coarse directions (steps
   ``fine_steps_deg``) with finer buckets. The sun is confident when the score reaches
   ``score_threshold``, the shadowed and lit sets each hold ``min_set`` receivers and the
   lit/shadow ratio says the sun brings at least ``min_direct_share`` of a lit receiver's light.
   Where no coarse direction scores ``fine_min_score`` the capture has no sun to refine (an
   overcast or unshadowed one): the fine grids and the ratio's dense pass are skipped and the
   estimate, from the best coarse direction, is not confident. ``fine_min_score`` lies below
   ``score_threshold`` by much more than the finer passes raised the best score on any scene
   measured (docs/benchmarks.md, "Capture formats, skinning, warm-up, outdoor lights").
   The direction is checked against the shading: an SH irradiance fit (bands 0-1) to the
   scene's luminance on its normals, whose band-1 vector points to the dominant light
   (``shading_direction``, ``shading_angle_deg``: evidence only).
3. Sun-to-sky ratio from lit (``T > 0.9``) and shadowed (``T < 0.1``) receivers of that
   surface: ``Y_lit / Y_shadow = (V_lit + Rc) / V_shadow`` with ``Rc = E_sun cos / E_sky``
   (medians, per channel, with the two sets' sky visibility from a denser hemisphere of
   ``ratio_directions``; with V = 1 this is ``L_lit / L_shadow = 1 + E_sun cos / E_sky``).
   Absolute scale and colour (the capture gives ratios only): the lit ground's total light is
   white with irradiance pi (a white surface in the capture's full light shows radiance 1), so
   per channel ``E_sky = pi / (V_lit + Rc)`` (horizontal irradiance of the unoccluded sky,
   uniform sky radiance ``E_sky / pi``) and ``E_sun = Rc E_sky / cos`` (irradiance at normal
   incidence). ``ratio = lum(E_sun) / lum(E_sky)``. The sun's share of a lit receiver's
   light, ``direct_share = Rc / (V_lit + Rc)``, is the darkening a full new shadow causes there
   (``1 - L_shadow / L_lit`` of the capture's own shadows, linear); ``darkening`` is the same in
   display-referred luminance (``1 - Y'_shadow / Y'_lit`` of the sRGB-encoded median lit colour
   and that colour without the sun's share): the factor the main job applies to the display
   colours it shadows (``usd_gs.shadows.shading``), so a new full shadow on lit ground has the
   display luminance of the capture's own shadows there.
4. :func:`plausible_emitters` (closed captures): a point-light candidate must be visible from
   the avatars' region through the scene's own DGSM (its emitter Gaussians left out) and must
   not lie below the floor it would light; rejected candidates keep their reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from numba_kernels.capsule import within_capsule
from numba_kernels.cubemap_dirs import cube_face_directions
from numba_kernels.grid_neighbours import nearest
from numba_kernels.sun_shadow import transmittance_directions
from usd_gs.colorspace import LUMA
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet, quaternion_to_matrix
from usd_gs.io.envmap import latlong_directions, project_latlong_to_sh
from usd_gs.point_blocks import PointBlocks, within_ball, within_reach
from usd_gs.relight.light_estimation import estimate_lights
from usd_gs.render.rasterize import render_cube_faces
from usd_gs.shadows.dgsm import DGSMConfig, exact_transmittance, prepare_occluders

SH_C0 = 0.28209479177387814
_AXES = {"X": 0, "Y": 1, "Z": 2}
_DISTANCES = ("receiver_radius", "caster_radius", "ground_band", "ground_search", "emitter_radius", "floor_margin",
              "visibility_offset", "coarse_cell", "fine_cell")


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB decode (IEC 61966-2-1) of display values, clipped to [0, 1] first; float64."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def srgb_to_display(x: np.ndarray) -> np.ndarray:
    """sRGB encode (IEC 61966-2-1) of linear values, clipped to [0, 1] first; float64."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def linear_colors(g: GaussianSet) -> np.ndarray:
    """(N, 3) float64 linear RGB of the Gaussians' view-independent (DC) display colour."""
    return srgb_to_linear(0.5 + SH_C0 * g.sh[:, 0].astype(np.float64))


@dataclass(frozen=True)
class CaptureConfig:
    """Parameters of the capture analysis; distances in metres, angles in degrees.

    open/closed: ``horizon_deg`` (10), ``open_share`` (0.25: open when at least this share of the
    sky above the horizon is empty and no compact emitter exists), ``open_share_alone`` (0.6),
    ``probe_size`` (32), ``sky_near_radius`` (15 m: the render draws the Gaussians this close to
    the avatars first; where they cover the whole sky above the horizon the rest cannot uncover
    any of it, so the answer is the same without drawing them), emitters: ``emitter_luminance``
    (1.05), ``emitter_peakness`` (4),
    ``emitter_peakness_alone`` (8), ``emitter_candidates`` (6).
    sun: ``receiver_radius`` (4 m around the avatars), ``caster_radius`` (8 m), ``ground_band``
    (0.06 m), ``ground_search`` (0.5 m around the ground hint), ``flat_cos`` (0.85: |normal.up|
    of a ground Gaussian), ``max_receivers`` (8000), ``min_elevation_deg`` (5); coarse pass:
    ``coarse_directions`` (96), ``coarse_cell`` (0.08 m buckets), ``coarse_receivers`` (3000, a subset),
    ``coarse_casters`` (60000: above this a random subset whose optical depth is scaled by the
    inverse share, ``alpha' = 1 - (1 - alpha)^(1/share)``); fine passes: every receiver and
    up to ``fine_casters`` (250000, thinned the same way above that), ``fine_cell`` (0.04 m),
    ``fine_steps_deg`` (4, 1.3, 0.45) with ``fine_half`` (2, 1, 1): (2h+1)^2 directions per grid,
    re-centred while the best lies on the grid's edge (at most 3 times); ``fine_seeds`` (2) best
    separated coarse directions; ``fine_min_score`` (0.08, at most ``score_threshold``): no fine
    pass when no coarse direction scores this much (module docstring);
    ``score_threshold`` (0.25), ``min_direct_share`` (0.25), ``min_set`` (30), ``k_sigma`` (3);
    the lit/shadow ratio reads the sky visibility of up to ``ratio_receivers`` (3000) receivers
    of its two sets over ``ratio_directions`` (192) directions with the coarse casters.
    closed: ``emitter_radius`` (0.25 m: the candidate's own Gaussians, left out of the
    visibility test), ``min_visibility`` (0.2), ``visibility_offset`` (0.5 m: the avatar region's
    sample points around the centre), ``floor_margin`` (0.05 m).
    """

    horizon_deg: float = 10.0
    open_share: float = 0.25
    open_share_alone: float = 0.6
    probe_size: int = 32
    sky_near_radius: float = 15.0
    emitter_luminance: float = 1.05
    emitter_peakness: float = 4.0
    emitter_peakness_alone: float = 8.0
    emitter_candidates: int = 6
    receiver_radius: float = 4.0
    caster_radius: float = 8.0
    ground_band: float = 0.06
    ground_search: float = 0.5
    flat_cos: float = 0.85
    max_receivers: int = 8000
    coarse_receivers: int = 3000
    coarse_casters: int = 60000
    fine_casters: int = 250000
    min_elevation_deg: float = 5.0
    coarse_directions: int = 96
    coarse_cell: float = 0.08
    fine_cell: float = 0.04
    fine_steps_deg: tuple = (4.0, 1.3, 0.45)
    fine_half: tuple = (2, 1, 1)
    fine_seeds: int = 2
    fine_min_score: float = 0.08
    score_threshold: float = 0.25
    min_direct_share: float = 0.25
    min_set: int = 30
    ratio_receivers: int = 3000
    ratio_directions: int = 192
    k_sigma: float = 3.0
    emitter_radius: float = 0.25
    min_visibility: float = 0.2
    visibility_offset: float = 0.5
    floor_margin: float = 0.05

    def in_scene_units(self, meters_per_unit: float) -> CaptureConfig:
        m = float(meters_per_unit)
        if not (np.isfinite(m) and m > 0):
            raise UserError(f"capture analysis: metersPerUnit must be > 0, got {m}")
        return replace(self, **{f: getattr(self, f) / m for f in _DISTANCES})


def up_vector(up_axis: str) -> np.ndarray:
    u = np.zeros(3)
    u[_AXES[up_axis.upper()]] = 1.0
    return u


# ----------------------------------------------------------------------------- open / closed
@dataclass
class EmitterCandidate:
    """A paper-3.1 candidate: ``position`` (3,), display ``luminance`` of its colour, ``peakness``
    (score / base intensity), ``score``; ``rejected``: why it is not a light ('' when kept)."""

    position: np.ndarray
    luminance: float
    peakness: float
    score: float
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    intensity: float = 1.0
    rejected: str = ""
    visibility: float = 1.0

    def is_compact(self, cfg: CaptureConfig) -> bool:
        return bool((self.luminance >= cfg.emitter_luminance and self.peakness >= cfg.emitter_peakness)
                    or self.peakness >= cfg.emitter_peakness_alone)


@dataclass
class CaptureDecision:
    """Open or closed, with the evidence: ``empty_share`` of the sky above the horizon,
    ``compact`` emitters found, the ``mode`` chosen ('outdoor' | 'indoor') and whether the user
    ``forced`` it."""

    is_open: bool
    empty_share: float
    compact: list
    candidates: list
    mode: str
    forced: bool = False

    def line(self) -> str:
        what = "open (sun and sky)" if self.is_open else "closed (point lights)"
        em = (f"{len(self.compact)} compact emitter(s)" if self.compact else "no compact emitter")
        how = " [forced by --lights]" if self.forced else ""
        return f"capture: {what}{how}: {self.empty_share:.0%} of the sky above the horizon is empty, {em}"

    def as_dict(self) -> dict:
        return {"open": self.is_open, "empty_share": round(self.empty_share, 4), "compact_emitters": len(self.compact),
                "mode": self.mode, "forced": self.forced}


def empty_sky_share(scene: GaussianSet, centre, up_axis: str = "Y", size: int = 32, horizon_deg: float = 10.0,
                    mask=None, near_radius: float | None = None, blocks: PointBlocks | None = None) -> float:
    """Solid-angle weighted share of the directions with elevation >= ``horizon_deg`` that a
    cube render of ``scene`` from ``centre`` leaves empty (alpha < 0.5). ``near_radius`` (scene
    units; None: off): where fewer than all Gaussians lie that close to ``centre``, those are
    drawn first, and when they alone cover every such direction (alpha >= 0.5 + 1e-4: drawing
    more Gaussians only lowers a texel's transmittance) the share is 0 without drawing the rest;
    otherwise the whole scene is drawn as without it. ``blocks``: None, or ``scene``'s rows as
    ``usd_gs.point_blocks.PointBlocks`` (the near ball decided block by block: the same share)."""

    centre = np.asarray(centre, np.float64)
    size = int(size)
    d = cube_face_directions(size)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    sel = d[..., _AXES[up_axis.upper()]] >= np.sin(np.radians(horizon_deg))
    if not sel.any():
        return 0.0
    if near_radius is not None and scene.count:
        near = within_ball(blocks, scene.positions, centre, float(near_radius))
        if mask is not None:
            near &= np.asarray(mask, bool)
        if not near.all():
            _, alpha, _ = render_cube_faces(scene, centre, size, order=np.flatnonzero(near))
            if np.all(alpha[sel] >= 0.5 + 1e-4):
                return 0.0
    _, alpha, _ = render_cube_faces(scene, centre, size, mask=mask)
    # texel solid angle on a unit cube face ~ 1 / |d_major|^3 (d unnormalised); use the exact ratio
    raw = cube_face_directions(size)
    w = 1.0 / np.linalg.norm(raw, axis=-1) ** 3 * np.max(np.abs(raw), axis=-1) ** 3
    return float(np.sum(w[sel] * (alpha[sel] < 0.5)) / np.sum(w[sel]))


def emitter_candidates(scene: GaussianSet, centre, k: int, meters_per_unit: float = 1.0,
                       values_checked: bool = False, blocks: PointBlocks | None = None) -> list[EmitterCandidate]:
    """Paper 3.1's ``k`` best candidates (``usd_gs.relight.light_estimation``) with their cues;
    ``values_checked`` and ``blocks`` as ``estimate_lights``'."""

    out = []
    for e in estimate_lights(scene, centre, k=k, meters_per_unit=meters_per_unit, values_checked=values_checked,
                             blocks=blocks):
        lum = float(LUMA @ np.asarray(e.color))
        peak = float(e.score / e.intensity) if e.intensity > 0 else 0.0
        out.append(EmitterCandidate(np.asarray(e.position, np.float64), lum, peak, float(e.score),
                                    np.asarray(e.color, np.float64), float(e.intensity)))
    return out


def classify_capture(scene: GaussianSet, centre, up_axis: str = "Y", meters_per_unit: float = 1.0,
                     config: CaptureConfig | None = None, candidates: list | None = None,
                     blocks: PointBlocks | None = None) -> CaptureDecision:
    """Open or closed (module docstring, step 1); ``candidates``: precomputed
    :func:`emitter_candidates` (computed here when None); ``blocks``: None, or ``scene``'s rows as
    ``usd_gs.point_blocks.PointBlocks`` (ball tests block by block: the same decision)."""
    cfg = config or CaptureConfig()
    share = empty_sky_share(scene, centre, up_axis, cfg.probe_size, cfg.horizon_deg,
                            near_radius=cfg.sky_near_radius / meters_per_unit, blocks=blocks)
    if candidates is None:
        candidates = emitter_candidates(scene, centre, cfg.emitter_candidates, meters_per_unit, blocks=blocks)
    compact = [c for c in candidates if c.is_compact(cfg)]
    is_open = share >= cfg.open_share_alone or (share >= cfg.open_share and not compact)
    return CaptureDecision(bool(is_open), share, compact, candidates, "outdoor" if is_open else "indoor")


# ----------------------------------------------------------------------------- ground and casters
def smallest_axes(g: GaussianSet, idx: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) unit axis of each Gaussian's smallest scale (its surface normal up to sign); ``idx``:
    of those rows only (M, 3), the same values."""
    q, s = (g.orientations, g.scales) if idx is None else (g.orientations[idx], g.scales[idx])
    r = quaternion_to_matrix(q.astype(np.float64))
    k = np.argmin(s, axis=1)
    return r[np.arange(len(s)), :, k]


def _flat_rows(g: GaussianSet, idx: np.ndarray, up: np.ndarray, flat_cos: float) -> np.ndarray:
    """(M,) bool over the rows ``idx``: the Gaussians whose smallest axis is within ``flat_cos`` of
    ``up`` (the axes are computed for those rows only)."""
    return np.abs(smallest_axes(g, idx) @ up) >= flat_cos


def _flat_among(g: GaussianSet, sel: np.ndarray, up: np.ndarray, flat_cos: float) -> np.ndarray:
    """``sel`` (N,) bool narrowed to the flat Gaussians (:func:`_flat_rows`)."""
    idx = np.flatnonzero(sel)
    out = np.zeros_like(sel)
    out[idx[_flat_rows(g, idx, up, flat_cos)]] = True
    return out


def _within_horizontal(g: GaussianSet, up: np.ndarray, centre: np.ndarray, radius: float,
                       blocks: PointBlocks | None = None) -> np.ndarray:
    """Increasing indices of the Gaussian centres of ``g`` within a little more than ``radius`` of the
    vertical line through ``centre``, a superset of those within ``radius``: one capsule pass along
    an axis-aligned ``up`` (its segment's ends 1e150 away, so the along-axis part cancels exactly
    and the distance is the horizontal one); every index for another ``up``. ``blocks``: None, or
    ``g``'s rows as ``usd_gs.point_blocks.PointBlocks``, for ``g`` with finite scales: the capsule
    test block by block (``within_reach`` with no reach of their own: the same rows)."""
    if np.count_nonzero(up) != 1:
        return np.arange(g.count)
    half = 1e150 * np.asarray(up, np.float64)
    a, b, r = centre - half, centre + half, radius * (1.0 + 1e-6) + 1e-9
    if blocks is None:
        return np.flatnonzero(within_capsule(g.positions, a, b, r))
    return np.flatnonzero(within_reach(blocks, g.positions, a, b, r, g.scales, 0.0))


def ground_height(g: GaussianSet, up: np.ndarray, centre, radius: float, hint: float | None, search: float,
                  flat_cos: float, bin_size: float, blocks: PointBlocks | None = None) -> float | None:
    """Height (along ``up``) of the densest flat horizontal layer of ``g`` within ``radius`` of
    ``centre`` (horizontal distance), searched within ``search`` of ``hint`` when given; None
    when no flat Gaussian is there. Weighted by opacity x footprint area. ``blocks``: None, or
    ``g``'s rows as ``usd_gs.point_blocks.PointBlocks`` where its values are finite (the same height)."""
    if not g.count:
        return None
    c = np.asarray(centre, np.float64)
    cand = _within_horizontal(g, up, c, radius, blocks)  # (a superset of the test below, in one pass)
    p = g.positions[cand].astype(np.float64)
    h = p @ up
    horiz = (p - c) - np.outer(h - c @ up, up)
    near = np.einsum("ij,ij->i", horiz, horiz) <= radius * radius
    rows = near & (g.opacities[cand] > 0.2)  # (over cand)
    if hint is not None:
        rows &= np.abs(h - hint) <= search
    rows = np.flatnonzero(rows)
    rows = rows[_flat_rows(g, cand[rows], up, flat_cos)]
    if rows.size < 10:
        return None
    idx = cand[rows]
    s = np.sort(g.scales[idx], axis=1)
    w = g.opacities[idx] * s[:, 1] * s[:, 2]
    hs = h[rows]
    lo, hi = hs.min(), hs.max()
    nb = max(int(np.ceil((hi - lo) / bin_size)), 1)
    hist, edges = np.histogram(hs, bins=nb, range=(lo, lo + nb * bin_size), weights=w)
    k = int(np.argmax(np.convolve(hist, np.ones(3), mode="same")))
    band = (hs >= edges[max(k - 1, 0)]) & (hs <= edges[min(k + 2, nb)])
    return float(np.average(hs[band], weights=w[band]))


@dataclass
class _Ground:
    recv: np.ndarray  # receiver indices into the scene
    casters: np.ndarray  # caster indices
    height: float


def _ground_split(g: GaussianSet, up, centre, cfg: CaptureConfig, hint) -> _Ground | None:
    h0 = ground_height(g, up, centre, cfg.receiver_radius, hint, cfg.ground_search, cfg.flat_cos,
                       cfg.ground_band / 3)
    if h0 is None:
        return None
    p = g.positions.astype(np.float64)
    h = p @ up
    c = np.asarray(centre, np.float64)
    horiz = (p - c) - np.outer(h - c @ up, up)
    d2 = np.einsum("ij,ij->i", horiz, horiz)
    recv = np.flatnonzero(_flat_among(g, (np.abs(h - h0) <= cfg.ground_band) & (g.opacities > 0.3)
                                      & (d2 <= cfg.receiver_radius ** 2), up, cfg.flat_cos))
    casters = np.flatnonzero((h > h0 + cfg.ground_band) & (d2 <= cfg.caster_radius ** 2) & (g.opacities > 1 / 255))
    if recv.size > cfg.max_receivers:
        rng = np.random.default_rng(0)
        recv = np.sort(rng.choice(recv, cfg.max_receivers, replace=False))
    return _Ground(recv, casters, h0)


# ----------------------------------------------------------------------------- directions
def fibonacci_hemisphere(n: int, up: np.ndarray, min_elevation_deg: float) -> np.ndarray:
    """(n, 3) area-uniform unit directions with elevation >= ``min_elevation_deg`` above ``up``."""
    z0 = np.sin(np.radians(min_elevation_deg))
    i = np.arange(n) + 0.5
    z = z0 + (1.0 - z0) * i / n
    phi = np.pi * (3.0 - np.sqrt(5.0)) * np.arange(n)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    a, b = _tangent(up)
    return (r * np.cos(phi))[:, None] * a + (r * np.sin(phi))[:, None] * b + z[:, None] * up


def _tangent(n: np.ndarray):
    h = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(n, h)
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


def local_grid(s: np.ndarray, step_deg: float, half: int) -> np.ndarray:
    """((2 half + 1)^2, 3) unit directions on a tangent-plane grid around unit ``s``."""
    a, b = _tangent(s)
    k = np.radians(step_deg) * np.arange(-half, half + 1)
    u, v = np.meshgrid(k, k, indexing="ij")
    d = s + np.tan(u.ravel())[:, None] * a + np.tan(v.ravel())[:, None] * b
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def elevation_azimuth(s: np.ndarray, up_axis: str) -> tuple[float, float]:
    """Elevation above the horizon and azimuth (degrees): for Y-up azimuth from +X towards -Z...
    measured as atan2 of the two horizontal components in axis order (Y-up: atan2(-z, x);
    Z-up: atan2(y, x))."""
    up = _AXES[up_axis.upper()]
    el = float(np.degrees(np.arcsin(np.clip(s[up], -1, 1))))
    az = float(np.degrees(np.arctan2(-s[2], s[0]))) if up == 1 else float(np.degrees(np.arctan2(s[1], s[0])))
    return el, az


def angle_deg(a, b) -> float:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


# ----------------------------------------------------------------------------- scoring
class _Scorer:
    """Transmittance of the receivers for candidate sun directions, and the partial
    correlation score (module docstring). ``sub``: receiver rows used by the coarse pass."""

    def __init__(self, casters: GaussianSet, points: np.ndarray, y: np.ndarray, w: np.ndarray, cfg: CaptureConfig):
        self.cfg = cfg
        dcfg = DGSMConfig()
        rng = np.random.default_rng(1)
        self.full = (self._thinned(casters, cfg.fine_casters, rng, dcfg) if casters.count > cfg.fine_casters
                     else prepare_occluders(casters, dcfg))
        self.coarse = (self._thinned(casters, cfg.coarse_casters, rng, dcfg) if casters.count > cfg.coarse_casters
                       else self.full)
        self.points = np.ascontiguousarray(points, np.float64)
        m = self.points.shape[0]
        self.sub = (np.sort(rng.choice(m, cfg.coarse_receivers, replace=False)) if m > cfg.coarse_receivers
                    else np.arange(m))
        self.y_all = y
        self.w_all = w / w.sum()
        self.rows = np.arange(m)
        self.builds = 0
        self.V_all = None

    @staticmethod
    def _thinned(casters: GaussianSet, n: int, rng, dcfg):
        """Packed occluders of a random subset of ``n`` casters whose optical depth is scaled by the
        inverse share (``alpha' = 1 - (1 - alpha)^(1/share)``): the same mean absorption."""

        share = n / casters.count
        thin = casters.subset(np.sort(rng.choice(casters.count, n, replace=False)))
        thin.opacities = (1.0 - (1.0 - np.clip(thin.opacities, 0.0, 0.999)) ** (1.0 / share)).astype(np.float32)
        return prepare_occluders(thin, dcfg)

    def transmittance(self, dirs: np.ndarray, cell: float, coarse: bool = False) -> np.ndarray:
        """(M', D) float32 transmittance of the receivers (the coarse subset with ``coarse``)
        for sun directions ``dirs`` (D, 3): the DGSM absorption model of the casters along each
        direction (``numba_kernels.sun_shadow``, buckets of ``cell`` scene units)."""

        occ, dep, cov6 = self.coarse if coarse else self.full
        pts = self.points[self.sub] if coarse else self.points
        self.builds += len(dirs)
        return transmittance_directions(-np.asarray(dirs, np.float64), occ, dep, cov6, pts, self.cfg.k_sigma, cell)

    def scores(self, t: np.ndarray, coarse: bool = False) -> np.ndarray:
        """(D,) partial correlation of the receivers' luminance with each column of ``t`` given [1, V]."""
        rows = self.sub if coarse else self.rows
        y, w, v = self.y_all[rows], self.w_all[rows], self.V_all[rows]
        w = w / w.sum()
        x = np.stack([np.ones_like(v), v], axis=1)
        xw = x * w[:, None]
        g = x.T @ xw + 1e-12 * np.eye(2)

        def resid(a):
            return a - x @ np.linalg.solve(g, xw.T @ a)

        ry = resid(y)
        rt = resid(t.astype(np.float64))
        num = (w * ry) @ rt
        den = np.sqrt(((w * ry) @ ry) * np.einsum("m,md,md->d", w, rt, rt))
        return np.where(den > 1e-18, num / np.where(den > 1e-18, den, 1.0), 0.0)


@dataclass
class SkyEstimate:
    """A uniform sky: ``radiance`` (3,) linear RGB above the horizon, ``ground`` (3,) below
    (the ground's mean linear colour), ``up_axis``. :meth:`latlong` is its lat-long image in
    ``usd_gs.io.envmap``'s convention (Y-up texture: a Z-up stage rotates the dome prim)."""

    radiance: np.ndarray
    ground: np.ndarray
    up_axis: str = "Y"

    def latlong(self, h: int = 32, w: int = 64) -> np.ndarray:
        d = latlong_directions(h, w)
        img = np.where((d[..., 1] >= 0.0)[..., None], self.radiance, self.ground)
        return img.astype(np.float32)

    def sh_rh(self, degree: int = 2) -> np.ndarray:
        """((degree+1)^2, 3) real-SH (Ramamoorthi-Hanrahan basis) radiance coefficients of
        :meth:`latlong` (texture frame, Y up)."""

        return project_latlong_to_sh(self.latlong(64, 128), degree, basis="rh")


@dataclass
class SunEstimate:
    """The result of :func:`estimate_sun` (module docstring for the model and units).

    direction: (3,) unit vector towards the sun (world); ``propagation = -direction``;
    score: partial correlation at the best direction; confident: the sun passes every test
    (``reasons`` lists those it failed); irradiance: (3,) E_sun at normal incidence, linear
    RGB; sky: :class:`SkyEstimate`; ratio: lum(E_sun) / lum(E_sky); ratio_cos: Rc (luminance);
    direct_share: Rc / (V_lit + Rc); n_lit, n_shadow: receivers in each set; shading_direction
    and shading_angle_deg: the band-1 check; sky_visibility: V_lit, the lit receivers' median sky
    visibility; lit_luminance: their median linear luminance; evidence: a flat dict for customData
    and summaries.
    """

    direction: np.ndarray
    score: float
    confident: bool
    irradiance: np.ndarray
    sky: SkyEstimate
    ratio: float
    ratio_cos: float
    direct_share: float
    n_lit: int
    n_shadow: int
    n_receivers: int
    shading_direction: np.ndarray | None
    shading_angle_deg: float | None
    elevation_deg: float
    azimuth_deg: float
    reasons: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    ground_height: float | None = None
    darkening: float = 0.0
    sky_visibility: float = 1.0
    lit_luminance: float = 0.5
    coarse_score: float | None = None  # the coarse pass's best score (the fine passes start there)

    @property
    def propagation(self) -> np.ndarray:
        return -self.direction

    def evidence(self) -> dict:
        return {"score": round(float(self.score), 4), "confident": bool(self.confident),
                "elevation_deg": round(self.elevation_deg, 2), "azimuth_deg": round(self.azimuth_deg, 2),
                "sun_sky_ratio": round(float(self.ratio), 4),
                "lit_over_shadow_minus_1": round(float(self.ratio_cos), 4),
                "direct_share": round(float(self.direct_share), 4),
                "display_darkening": round(float(self.darkening), 4), "lit_receivers": int(self.n_lit),
                "lit_sky_visibility": round(float(self.sky_visibility), 4),
                "lit_luminance": round(float(self.lit_luminance), 4),
                "shadow_receivers": int(self.n_shadow), "receivers": int(self.n_receivers),
                "shading_angle_deg": None if self.shading_angle_deg is None else round(self.shading_angle_deg, 2),
                "failed": "; ".join(self.reasons)}

    def line(self) -> str:
        s = self.direction
        state = "confident" if self.confident else f"LOW CONFIDENCE ({'; '.join(self.reasons)}): not used as a sun"
        chk = "" if self.shading_angle_deg is None else f", shading check {self.shading_angle_deg:.0f} deg off"
        coarse = "" if self.coarse_score is None else f" (coarse pass {self.coarse_score:.2f})"
        return (f"sun: towards ({s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f}), elevation {self.elevation_deg:.1f} deg, azimuth "
                f"{self.azimuth_deg:.1f} deg, score {self.score:.2f}{coarse}, sun/sky {self.ratio:.2f}, its share "
                f"of the lit ground's light {self.direct_share:.2f} (display darkening {self.darkening:.2f}; "
                f"{self.n_lit} lit / {self.n_shadow} shadowed receivers){chk}: "
                f"{state}")


def _shading_check(g: GaussianSet, idx: np.ndarray, up: np.ndarray, centre) -> np.ndarray | None:
    """Band-1 dominant direction of an SH irradiance fit to the scene's linear luminance on its
    normals (smallest axis, oriented away from the local opacity-weighted centroid of the
    casters' centre: outward on a convex statue, up on the ground)."""
    if idx.size < 50:
        return None
    if idx.size > 50000:
        idx = np.sort(np.random.default_rng(3).choice(idx, 50000, replace=False))
    sub = g.subset(idx)
    n = smallest_axes(sub)
    p = sub.positions.astype(np.float64)
    c = np.average(p, axis=0, weights=sub.opacities.astype(np.float64) + 1e-9)
    out = p - c
    flip = np.einsum("ij,ij->i", n, out) < 0
    n[flip] *= -1.0
    y = LUMA @ linear_colors(sub).T
    x = np.concatenate([np.ones((len(n), 1)), n], axis=1)
    w = sub.opacities.astype(np.float64)
    xw = x * w[:, None]
    beta = np.linalg.lstsq(x.T @ xw, xw.T @ y, rcond=None)[0]
    v = beta[1:]
    nv = np.linalg.norm(v)
    return v / nv if nv > 0 else None


def estimate_sun(scene: GaussianSet, centre, up_axis: str = "Y", meters_per_unit: float = 1.0,
                 config: CaptureConfig | None = None, ground_hint: float | None = None) -> SunEstimate | None:
    """The sun and sky of an open capture (module docstring, steps 2-3); ``centre``: the
    avatars' region (scene units), ``ground_hint``: the height the avatars stand at (None: the
    densest flat layer near ``centre``). None when the capture has no flat ground near
    ``centre`` to read shadows from."""
    t0 = time.perf_counter()
    cfg = (config or CaptureConfig()).in_scene_units(meters_per_unit)
    up = up_vector(up_axis)
    split = _ground_split(scene, up, centre, cfg, ground_hint)
    if split is None or split.recv.size < 2 * cfg.min_set:
        return None
    recv = scene.subset(split.recv)
    cast = scene.subset(split.casters)
    lin = linear_colors(recv)
    y = lin @ LUMA
    w = recv.opacities.astype(np.float64)
    pts = recv.positions.astype(np.float64)
    scorer = _Scorer(cast, pts, y, w, cfg)
    timings = {"setup": time.perf_counter() - t0}

    t = time.perf_counter()
    coarse = fibonacci_hemisphere(cfg.coarse_directions, up, cfg.min_elevation_deg)
    tc = scorer.transmittance(coarse, cfg.coarse_cell, coarse=True)
    cosw = coarse @ up
    # sky visibility of every receiver: the coarse pass on the subset (V is smooth); the other
    # receivers take their nearest subset receiver's value
    v_sub = (tc.astype(np.float64) @ cosw) / cosw.sum()
    scorer.V_all = _nearest_values(pts, pts[scorer.sub], v_sub)
    sc = scorer.scores(tc, coarse=True)
    timings["coarse"] = time.perf_counter() - t

    if not float(np.max(sc)) >= min(cfg.fine_min_score, cfg.score_threshold):  # no sun to refine
        t = time.perf_counter()
        j = int(np.argmax(sc))
        best_t = scorer.transmittance(coarse[j:j + 1], cfg.fine_cell)[:, 0]
        est = _sun_and_sky(coarse[j], float(sc[j]), best_t.astype(np.float64), scorer.V_all, lin, up, up_axis, cfg,
                           pts)
        timings["fine"] = time.perf_counter() - t
        return _finish(est, float(sc[j]), split, scene, up, centre, timings, scorer, t0)

    t = time.perf_counter()
    order = np.argsort(-sc)
    seeds = []
    for j in order:
        if all(angle_deg(coarse[j], coarse[k]) > 15.0 for k in seeds):
            seeds.append(int(j))
        if len(seeds) >= cfg.fine_seeds:
            break
    min_up = np.sin(np.radians(cfg.min_elevation_deg))
    finals = []
    for j in seeds:
        s, s_score, s_t = coarse[j], -2.0, None
        for step, half in zip(cfg.fine_steps_deg, cfg.fine_half, strict=True):
            for _ in range(3):
                cand = local_grid(s, step, half)
                keep = cand @ up >= min_up
                tt = scorer.transmittance(cand[keep], cfg.fine_cell)
                ss = np.full(len(cand), -2.0)
                ss[keep] = scorer.scores(tt)
                k = int(np.argmax(ss))
                if ss[k] > s_score:
                    s, s_score, s_t = cand[k], float(ss[k]), tt[:, int(np.sum(keep[:k]))]
                n = 2 * half + 1
                if not (k // n in (0, n - 1) or k % n in (0, n - 1)):
                    break  # the best is inside the grid: next finer step
        finals.append((s_score, s, s_t))
    finals.sort(key=lambda f: -f[0])
    best_score, best_s, best_t = finals[0]
    timings["fine"] = time.perf_counter() - t

    t = time.perf_counter()
    # the sky visibility of the receivers the ratio reads, from a denser hemisphere
    v_fine = scorer.V_all.copy()
    sets = np.flatnonzero((best_t < 0.1) | (best_t > 0.9))
    if sets.size:
        pick = sets if sets.size <= cfg.ratio_receivers else np.sort(
            np.random.default_rng(2).choice(sets, cfg.ratio_receivers, replace=False))
        dense = fibonacci_hemisphere(cfg.ratio_directions, up, 1.0)
        td = _dense_transmittance(scorer, dense, pick, cfg)
        cw = dense @ up
        v_fine[pick] = (td @ cw) / cw.sum()
        keep = np.zeros(len(v_fine), bool)
        keep[pick] = True
        best_t = np.where(keep, best_t, 0.5)  # only receivers with a dense V enter the sets
    est = _sun_and_sky(best_s, best_score, best_t.astype(np.float64), v_fine, lin, up, up_axis, cfg, pts)
    timings["ratio"] = time.perf_counter() - t
    return _finish(est, float(np.max(sc)), split, scene, up, centre, timings, scorer, t0)


def _finish(est: SunEstimate, coarse_score: float, split, scene: GaussianSet, up, centre, timings: dict, scorer,
            t0: float) -> SunEstimate:
    """``est`` with the coarse pass's best score, the receivers' count and height, the shading check
    against its direction and the timings (``estimate_sun``'s last step)."""
    est.coarse_score = float(coarse_score)
    est.n_receivers = int(split.recv.size)
    est.ground_height = split.height
    v = _shading_check(scene, split.casters if split.casters.size else split.recv, up, centre)
    if v is not None:
        est.shading_direction = v
        est.shading_angle_deg = angle_deg(v, est.direction)
    timings["builds"] = scorer.builds
    timings["total"] = time.perf_counter() - t0
    est.timings = timings
    return est


def _nearest_values(points: np.ndarray, ref: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(M,) ``values`` of the nearest ``ref`` point of each point (``grid_neighbours.nearest``)."""
    if ref.shape[0] == points.shape[0]:
        return values

    return values[nearest(ref, points)]


def _dense_transmittance(scorer: _Scorer, dirs: np.ndarray, rows: np.ndarray, cfg: CaptureConfig) -> np.ndarray:
    """(len(rows), D) float64 transmittance of receivers ``rows`` for sun directions ``dirs``."""

    occ, dep, cov6 = scorer.coarse  # the sky visibility is smooth: the coarse casters suffice
    return transmittance_directions(-dirs, occ, dep, cov6, scorer.points[rows], cfg.k_sigma,
                                    cfg.coarse_cell).astype(np.float64)


def _sun_and_sky(s, score, t, V, lin, up, up_axis, cfg, pts=None) -> SunEstimate:
    lit = (t > 0.9) & (V > 0.7)
    sh = t < 0.1
    reasons = []
    cos = max(float(s @ up), 1e-3)
    if lit.sum() >= cfg.min_set and sh.sum() >= cfg.min_set:
        vl = float(np.median(V[lit]))
        yl = np.median(lin[lit], axis=0)
        ys = np.maximum(np.median(lin[sh], axis=0), 1e-6)
        rc = np.maximum(yl / ys * float(np.median(V[sh])) - vl, 0.0)
    else:
        reasons.append(f"too few lit/shadowed receivers ({int(lit.sum())}/{int(sh.sum())}, need {cfg.min_set})")
        vl = float(np.median(V))
        rc = np.zeros(3)
    e_sky = np.pi / (vl + rc)
    e_sun = rc * e_sky / cos
    rc_l = float(LUMA @ (rc * e_sky)) / float(LUMA @ e_sky)
    share = rc_l / (vl + rc_l) if vl + rc_l > 0 else 0.0
    ratio = float(LUMA @ e_sun) / float(LUMA @ e_sky)
    if score < cfg.score_threshold:
        reasons.append(f"score {score:.2f} < {cfg.score_threshold:.2f}")
    if share < cfg.min_direct_share:
        reasons.append(f"the sun brings {share:.2f} < {cfg.min_direct_share:.2f} of the lit ground's light")
    ground = np.mean(lin, axis=0)
    sky = SkyEstimate(e_sky / np.pi, ground, up_axis)
    el, az = elevation_azimuth(s, up_axis)
    # display-referred darkening of a full new shadow on lit ground: the sun's share of each
    # channel removed from the median lit colour, in display luminance (what the colours hold)
    yl_lin = np.median(lin[lit], axis=0) if lit.any() else np.median(lin, axis=0)
    share_c = rc / np.maximum(vl + rc, 1e-12)
    disp_lit = float(LUMA @ srgb_to_display(yl_lin))
    disp_sh = float(LUMA @ srgb_to_display(yl_lin * (1.0 - share_c)))
    darkening = 1.0 - disp_sh / disp_lit if disp_lit > 0 else 0.0
    return SunEstimate(np.asarray(s, np.float64), float(score), not reasons, e_sun, sky, ratio, rc_l, float(share),
                       int(lit.sum()), int(sh.sum()), 0, None, None, el, az, reasons, darkening=float(darkening),
                       sky_visibility=float(vl), lit_luminance=float(LUMA @ yl_lin))


def overcast_sky(scene: GaussianSet, centre, up_axis: str = "Y", meters_per_unit: float = 1.0,
                 config: CaptureConfig | None = None) -> SkyEstimate:
    """A sky with no sun: uniform radiance 1 (the lit ground's irradiance pi, as in
    :func:`estimate_sun`) above the horizon, the scene's mean colour near ``centre`` below."""
    cfg = (config or CaptureConfig()).in_scene_units(meters_per_unit)
    p = scene.positions.astype(np.float64)
    near = np.sum((p - np.asarray(centre, np.float64)) ** 2, axis=1) <= cfg.receiver_radius ** 2
    ground = linear_colors(scene.subset(np.flatnonzero(near))).mean(axis=0) if near.any() else np.full(3, 0.2)
    return SkyEstimate(np.ones(3), ground, up_axis)


# ----------------------------------------------------------------------------- closed captures
def plausible_emitters(scene: GaussianSet, candidates: list, region_points: np.ndarray, up_axis: str = "Y",
                       meters_per_unit: float = 1.0, config: CaptureConfig | None = None,
                       floor_height: float | None = None, blocks: PointBlocks | None = None) -> list:
    """Mark each :class:`EmitterCandidate` ``rejected`` with a reason where it is not a
    plausible light for the shot: below the floor (``floor_height`` - margin, the avatars'
    ground) or hidden from every point of ``region_points`` (M, 3) by the scene's own Gaussians
    (the DGSM's absorption model, eq. 1-5, evaluated exactly on the few rays from the candidate
    to the points, ``usd_gs.shadows.dgsm.exact_transmittance``, over the Gaussians within
    :data:`_OFF_RAY_SIGMAS` sigmas of those rays; the candidate's own emitter Gaussians within
    ``emitter_radius`` left out): best transmittance < ``min_visibility``.
    Sets ``visibility``; returns ``candidates``. ``blocks``: None, or ``scene``'s rows as
    ``usd_gs.point_blocks.PointBlocks`` (the ball and capsule tests block by block: the same values)."""

    cfg = (config or CaptureConfig()).in_scene_units(meters_per_unit)
    up = up_vector(up_axis)
    pts = np.asarray(region_points, np.float64).reshape(-1, 3)
    for c in candidates:
        if floor_height is not None and float(c.position @ up) < floor_height - cfg.floor_margin:
            c.rejected = (f"{floor_height - float(c.position @ up):.2f} below the floor the avatars stand on "
                          "(a reflection in the floor, not a light)")
            continue
        keep = np.flatnonzero(~within_ball(blocks, scene.positions, c.position, cfg.emitter_radius)
                              & _near_rays(scene, c.position, pts, blocks))
        vis = float(np.max(exact_transmittance(scene.subset(keep), pts, c.position))) if pts.size else 1.0
        c.visibility = vis
        if vis < cfg.min_visibility:
            c.rejected = (f"hidden from the avatars' region by the scene (best transmittance {vis:.2f}): a bright "
                          "patch behind or inside a surface")
    return candidates


#: occluders farther than this many of their largest sigmas from every ray a visibility test
#: casts are left out of it: their optical depth on the ray is below exp(-32) of their peak
_OFF_RAY_SIGMAS = 8.0


def _near_rays(scene: GaussianSet, origin: np.ndarray, targets: np.ndarray,
               blocks: PointBlocks | None = None) -> np.ndarray:
    """(N,) bool: the Gaussians of ``scene`` within :data:`_OFF_RAY_SIGMAS` of their largest sigmas
    of the capsule that holds every segment from ``origin`` to a point of ``targets`` (M, 3):
    around the segment to their centre, with their spread around it as its radius (``blocks``: as
    :func:`plausible_emitters`')."""
    if targets.size == 0:
        return np.zeros(scene.count, bool)
    centre = targets.mean(axis=0)
    spread = float(np.sqrt(np.max(np.sum((targets - centre) ** 2, axis=1))))
    return within_reach(blocks, scene.positions, origin, centre, spread, scene.scales, _OFF_RAY_SIGMAS)


def region_points(centre, up_axis: str, offset: float) -> np.ndarray:
    """(7, 3) the centre and the centre +- ``offset`` along the three axes."""
    c = np.asarray(centre, np.float64)
    return np.concatenate([c[None], c + offset * np.eye(3), c - offset * np.eye(3)])
