"""Shadows of one frame: every caster prim's DGSM per light, sampled on every receiver.

Optical depth is additive over Gaussians, so the transmittance through several caster prims
is the product of each prim's transmittance: ``T = prod_Q T_Q``. Building one DGSM per
caster prim (instead of one for all casters) costs the same (work grows with occluders
times the pixels they cover) and gives two things for free:

- a receiver never shadows itself: receivers of prim ``P`` use ``prod_{Q != P} T_Q``
  (avatar on avatar, object on avatar; not an avatar on itself);
- each caster gets its own receiver ROI, so two avatars far apart do not need one huge ROI.

Receiver ROI (``roi='cone'``, the default): the receivers whose ray from the light can pass
through the caster's bounding sphere (centre and radius of its ``k_sigma`` extent box):
inside the cone from a point light around that sphere and not nearer to the light than
the sphere, or inside the cylinder along a directional light. This is conservative (no
receiver that the caster can shadow is left out) and, unlike the paper's fixed box of
radius R around the avatar (``roi='box'``), does not cut off the long shadows that a lamp
close to an avatar throws across a room.

Static casters (the scene) shadow the dynamic receivers (avatars, objects). Their DGSM
uses no ROI box (the receivers are the avatars themselves, a small set), and every sample
point is moved ``bias`` metres toward the light first so that the scene Gaussians a foot
stands on do not shadow it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from numba_kernels.dgsm_sample import weighted_mean
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import DGSM, DGSMConfig, footprint_samples, prepare_occluders, roi_indices, sample_dgsm


@dataclass
class Receivers:
    """All receiving Gaussians of a frame, concatenated, with each prim's index range."""

    gaussians: GaussianSet
    ranges: dict[str, tuple[int, int]]

    @staticmethod
    def row_ranges(parts: list[tuple[str, GaussianSet]]) -> dict[str, tuple[int, int]]:
        """Each prim's ``(start, end)`` rows when ``parts`` are concatenated in order."""
        ranges, start = {}, 0
        for path, g in parts:
            ranges[path] = (start, start + g.count)
            start += g.count
        return ranges

    @classmethod
    def build(cls, parts: list[tuple[str, GaussianSet]]) -> Receivers:
        sets = [g for _, g in parts]
        merged = GaussianSet.concatenate(sets, label="receivers") if sets else GaussianSet.empty()
        return cls(merged, cls.row_ranges(parts))


def _bounding_sphere(ext: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the sphere around a (2, 3) box."""
    ext = np.asarray(ext, np.float64)
    return 0.5 * (ext[0] + ext[1]), 0.5 * float(np.linalg.norm(ext[1] - ext[0]))


def _beam(centres: np.ndarray, c: np.ndarray, r: float, light, rows: np.ndarray | None = None
          ) -> tuple[np.ndarray, np.ndarray]:
    """Geometry of points against the light's beam through the sphere (c, r): a cone from a
    point light (half-angle asin(r / |c - light|)), a cylinder along a directional light.

    Returns ``(gap, depth)`` per point: ``gap`` the distance from the point to the beam
    (<= 0 inside), ``depth`` how far past the sphere's near side the point lies along the
    light (>= 0 beyond the near side). A light inside the sphere gives gap -inf (everything
    is in its beam). ``rows``: the points ``centres[rows]`` only (no gathered copy is made);
    None: every point. One threaded pass (``numba_kernels.beam.beam_gap_depth``)."""
    from numba_kernels.beam import beam_gap_depth

    c = np.asarray(c, np.float64)
    if light.kind == "directional":
        d = np.asarray(light.direction, np.float64)
        return beam_gap_depth(centres, rows, False, c, d / np.linalg.norm(d), r)
    lp = np.asarray(light.position, np.float64)
    dc = float(np.linalg.norm(c - lp))
    if dc <= r:
        gap, dist = beam_gap_depth(centres, rows, True, lp, np.zeros(3), 0.0, 0.0, 0.0, 1.0)
        return np.full(gap.shape[0], -np.inf), dist
    sin_h = r / dc
    return beam_gap_depth(centres, rows, True, lp, (c - lp) / dc, r, dc, sin_h, np.sqrt(1.0 - sin_h * sin_h))


def occluder_sphere(occluders: GaussianSet, k_sigma: float = 3.0) -> tuple[np.ndarray, float]:
    """Bounding sphere (centre, radius) of the occluders' ``k_sigma`` extent; compute it once per
    frame and pass it to the functions below instead of recomputing it per light."""
    return _bounding_sphere(occluders.extent(k_sigma))


def shadow_cone_indices(occluders: GaussianSet, positions: np.ndarray, light, k_sigma: float = 3.0,
                        sphere=None, rows: np.ndarray | None = None) -> np.ndarray:
    """Receivers (indices into ``positions`` (N, 3), or into ``rows`` when given: the points
    ``positions[rows]``) that ``occluders`` can shadow from ``light``: inside the beam through the
    occluders' bounding sphere and not before its near side."""
    c, r = sphere if sphere is not None else occluder_sphere(occluders, k_sigma)
    gap, depth = _beam(positions, c, r * (1.0 + 1e-6) + 1e-9, light, rows)
    return np.flatnonzero((gap <= 0.0) & (depth >= 0.0))


def toward_mask(centres: np.ndarray, reach: np.ndarray, receiver_positions: np.ndarray, light) -> np.ndarray:
    """(N,) bool: spheres (``centres`` (N, 3), radii ``reach`` (N,)) that can lie between
    ``light`` and the receivers: they meet the beam through the receivers' bounding sphere
    and do not lie beyond its far side."""
    x = receiver_positions.astype(np.float64)
    c, r = _bounding_sphere(np.stack([x.min(axis=0), x.max(axis=0)]))
    gap, depth = _beam(centres, c, r, light)
    return (gap <= reach) & (depth <= 2.0 * r + reach)


def occluders_toward(occluders: GaussianSet, receiver_positions: np.ndarray, light, k_sigma: float = 3.0,
                     candidates: np.ndarray | None = None) -> np.ndarray:
    """Indices of the ``occluders`` (among ``candidates``, default all) that can lie between
    ``light`` and the receivers: an occluder matters only if its ``k_sigma`` sphere meets
    :func:`toward_mask`'s region. Conservative: dropping the others changes no receiver's
    transmittance."""
    if occluders.count == 0 or receiver_positions.shape[0] == 0:
        return np.zeros(0, np.int64)
    cand = np.arange(occluders.count, dtype=np.int64) if candidates is None else np.asarray(candidates, np.int64)
    reach = k_sigma * occluders.scales[cand].astype(np.float64).max(axis=1)
    return cand[toward_mask(occluders.positions[cand], reach, receiver_positions, light)]


def _build(occluders: GaussianSet, prepared, light, points: np.ndarray, cfg: DGSMConfig):
    from numba_kernels import dgsm_build, dgsm_directional

    if light.kind == "directional":
        d = np.asarray(light.direction, np.float64)
        return d, dgsm_directional.build_directional(d / np.linalg.norm(d), *prepared, points, cfg.atlas_size,
                                                    max(cfg.K, 2), cfg.k_sigma, cfg.use_tile_culling, cfg.bin_skip)
    pos = np.asarray(light.position, np.float64)
    return pos, dgsm_build.build_point(pos, *prepared, points, cfg.atlas_size, cfg.K, cfg.t_max, cfg.k_sigma,
                                       cfg.use_roi, cfg.use_tile_culling, cfg.bin_skip)


def receiver_points(occluders: GaussianSet, receivers: Receivers, light, cfg: DGSMConfig,
                    exclude: str | None = None, roi: str = "cone", bias: float = 0.0,
                    candidates: np.ndarray | None = None, sphere=None):
    """The receivers ``occluders`` can shadow and their footprint sample points:
    ``(idx (M,) int64 receiver indices, points (M*n, 3) float64, weights (n,))``, or None when
    there are none. Arguments as :func:`caster_transmittance`."""
    g = receivers.gaussians
    if occluders.count == 0 or g.count == 0:
        return None
    cand = np.arange(g.count, dtype=np.int64) if candidates is None else np.asarray(candidates, np.int64)
    if exclude is not None and exclude in receivers.ranges:
        a, b = receivers.ranges[exclude]
        cand = cand[(cand < a) | (cand >= b)]
    if cand.size == 0:
        return None
    if roi == "all" or not cfg.use_roi:
        idx = cand
    elif roi == "box":
        idx = cand[roi_indices(occluders, g.positions[cand], cfg)]
    else:
        idx = cand[shadow_cone_indices(occluders, g.positions, light, cfg.k_sigma, sphere, rows=cand)]
    if idx.size == 0:
        return None
    pts, w = footprint_samples(g, idx, cfg)
    if bias > 0:
        if light.kind == "directional":
            toward = -np.asarray(light.direction, np.float64)
            pts = pts + bias * (toward / np.linalg.norm(toward))
        else:
            from numba_kernels.beam import offset_toward_point

            pts = offset_toward_point(pts, light.position, bias)
    return idx, pts, w


#: a directional light's transmittance is evaluated exactly on each sample point's own ray
#: (``dgsm_directional.transmittance_points``) instead of through an atlas when there are at most
#: this many points per atlas pixel their stencils touch: an atlas pixel costs about one point's ray
#: times the few bins of each pair's erf window (measured on the outdoor shot's casters: points
#: 1.7-4x faster at 0.3-1.7 points per pixel, even at 2.8; the exact rays also drop the atlas's
#: interpolation error, mean 4e-4-1e-2 there)
EXACT_POINTS_PER_PIXEL = 2.5


def _directional_exact(occluders, light, pts, cfg, prepared):
    """Exact per-point transmittance (M,) of ``pts`` for a directional light, or None where the
    atlas is cheaper (:data:`EXACT_POINTS_PER_PIXEL`)."""
    from numba_kernels import dgsm_directional

    d = np.asarray(light.direction, np.float64)
    d = d / np.linalg.norm(d)
    if len(pts) > EXACT_POINTS_PER_PIXEL * dgsm_directional.roi_pixel_count(d, pts, cfg.atlas_size):
        return None
    occ, dep, cov6 = prepared
    return dgsm_directional.transmittance_points(d, occ, dep, cov6, pts, cfg.k_sigma)[0]


def shared_transmittance(occluders: GaussianSet, parts: list, light, cfg: DGSMConfig,
                         prepared=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """One DGSM of ``occluders`` for several receiver sets: ``parts`` are
    :func:`receiver_points` results (None entries allowed); the atlas covers the union of
    their voxels (one culling pass and one accumulation instead of one per set) and each part
    gets ``(idx, values)`` back as :func:`caster_transmittance` gives it (empty for None). A
    directional light's sample points take their exact transmittance instead where that is
    cheaper (:data:`EXACT_POINTS_PER_PIXEL`)."""
    empty = (np.zeros(0, np.int64), np.zeros(0))
    live = [p for p in parts if p is not None]
    if not live:
        return [empty for _ in parts]
    prepared = prepared if prepared is not None else prepare_occluders(occluders, cfg)
    pts = np.ascontiguousarray(np.concatenate([p[1] for p in live]) if len(live) > 1 else live[0][1])
    exact = _directional_exact(occluders, light, pts, cfg, prepared) if light.kind == "directional" else None
    if exact is None:
        key, atlas = _build(occluders, prepared, light, pts, cfg)
        stencils = getattr(atlas, "stencils", None)  # (a point light's: the lookups read what the build computed)
    out, start = [], 0
    for p in parts:
        if p is None:
            out.append(empty)
            continue
        idx, ppts, w = p
        sub = slice(start, start + len(ppts))
        start += len(ppts)
        if exact is not None:
            out.append((idx, weighted_mean(exact[sub], w)))
        else:
            out.append((idx, sample_dgsm(DGSM(key, atlas, idx, pts[sub], w, cfg, prepared=prepared,
                                              stencils=None if stencils is None else stencils.rows(sub)))))
    return out


def caster_transmittance(occluders: GaussianSet, receivers: Receivers, light, cfg: DGSMConfig,
                         exclude: str | None = None, roi: str = "cone", bias: float = 0.0,
                         prepared=None, candidates: np.ndarray | None = None,
                         sphere=None) -> tuple[np.ndarray, np.ndarray]:
    """Transmittance through ``occluders`` of the receivers it can shadow, sparse:
    ``(idx (M,) int64 receiver indices, values (M,) float64)``; every other receiver has 1.

    ``candidates``: receiver indices to consider (None: all), e.g. the Gaussians of the
    bricks whose bounds meet the caster's shadow. ``exclude``: a receiver prim path whose
    Gaussians are not sampled (the caster itself). ``roi``: 'cone' (module docstring),
    'box' (the paper's box around the occluders) or 'all' (every candidate; also what
    ``cfg.use_roi = False`` gives). ``bias``: metres to move sample points toward the light
    (against self-contact shadowing). ``sphere``: :func:`occluder_sphere` if already known.
    """
    part = receiver_points(occluders, receivers, light, cfg, exclude, roi, bias, candidates, sphere)
    return shared_transmittance(occluders, [part], light, cfg, prepared)[0]


def prim_boxes(receivers: Receivers, k_sigma: float = 3.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(starts (P+1,) int64, boxes (P, 2, 3) float64, ok (P,) bool)``: each receiver prim's
    ``k_sigma`` extent (``numba_kernels.extent.block_extents`` of its rows, the prims in threads, one
    pass, no copies; ``ok`` False for an empty prim or a box beyond float32), the prims in the order of
    ``receivers.ranges``, which tile the rows in order (as :meth:`Receivers.build` makes them). The
    blocks of ``usd_gs.shadows.static_scene.BlockExtents`` when the same set is the static casters."""
    from numba_kernels.extent import block_extents

    g = receivers.gaussians
    spans = list(receivers.ranges.values())
    starts = np.array([a for a, _ in spans] + [spans[-1][1] if spans else 0], np.int64)
    boxes, ok = block_extents(g.positions, g.orientations, g.scales, starts, k_sigma)
    return starts, boxes, ok


def prim_spheres(receivers: Receivers, k_sigma: float = 3.0,
                 boxes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> dict[str, tuple[np.ndarray, float]]:
    """Bounding sphere (centre (3,), radius) of each receiver prim's ``k_sigma`` extent (prims with
    Gaussians only), from ``boxes`` (:func:`prim_boxes` of the same arguments; None: computed here)."""
    starts, box, ok = prim_boxes(receivers, k_sigma) if boxes is None else boxes
    g = receivers.gaussians
    out = {}
    for i, (path, (a, b)) in enumerate(receivers.ranges.items()):
        if b <= a:
            continue
        ext = (box[i].astype(np.float32) if ok[i] else g.subset(slice(a, b)).extent(k_sigma)).astype(np.float64)
        out[path] = (0.5 * (ext[0] + ext[1]), 0.5 * float(np.linalg.norm(ext[1] - ext[0])))
    return out


def prims_in_shadow(spheres: dict, occluders: GaussianSet, light, k_sigma: float = 3.0, sphere=None) -> list[str]:
    """Receiver prims whose bounding sphere can meet the shadow of ``occluders`` (conservative)."""
    if not spheres or occluders.count == 0:
        return []
    names = list(spheres)
    centres = np.array([spheres[n][0] for n in names])
    radii = np.array([spheres[n][1] for n in names])
    c, r = sphere if sphere is not None else occluder_sphere(occluders, k_sigma)
    gap, depth = _beam(centres, c, r, light)
    hit = (gap <= radii) & (depth >= -radii)
    return [n for n, h in zip(names, hit, strict=True) if h]
