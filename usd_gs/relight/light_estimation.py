"""Estimate k dominant point lights of a 3DGS scene around an avatar (paper section 3.1), and
its bright planar emitters (windows, panels) for RectLights (:func:`estimate_rect_lights`).

Thin wrapper around ``numba_kernels.light_estimation`` (imported lazily, so importing this
module does not load numba); the algorithm, its formulas and defaults are documented there
and in :class:`LightEstimationConfig`.

Conventions: the scene Gaussians and ``avatar_centroid`` are in one world frame (apply prim
transforms first, ``GaussianSet.transformed``); distances in the config are METRES and are
divided by ``meters_per_unit`` to get scene units; SH in the 3DGS basis (shared/DESIGN.md).
Only the ``"ring"`` viewpoint layout uses the up axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from usd_gs.errors import GaussianDataError, UserError
from usd_gs.gaussians import GaussianSet

if TYPE_CHECKING:
    from usd_gs.point_blocks import PointBlocks

_DISTANCE_FIELDS = ("roi_radius", "view_radius", "peak_radius", "peak_inner_radius", "nms_distance", "refine_radius")
_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass(frozen=True)
class LightEstimationConfig:
    """Parameters of the light estimation; distances in metres.

    roi_radius: ROI sphere radius around the avatar centroid (6.0 m).
    view_layout: ``"octahedron"`` (centroid +- view_radius along the three axes, 6 views) or
        ``"ring"`` (``num_views`` points on a horizontal circle of radius view_radius around
        the centroid, horizontal = orthogonal to ``up_axis``).
    view_radius: 0.5 m; num_views: 6 (ring only); up_axis: "Y" or "Z" (ring only).
    min_opacity: Gaussians with linear opacity below this are ignored (1/255).
    max_weight: weight of max over mean luminance in the luminance cue (0.25).
    clip_percentile, clip_knee_factor: soft-clip knee = factor * percentile of the ROI
        luminance cue (99.9, 1.0).
    stability_power, dominance_power: exponents of the angular-stability and DC-dominance cues (1, 1).
    tail_fraction, min_candidates, max_candidates: size of the high-score tail (2 %, 1000, 20000).
    peak_radius, peak_inner_radius: neighbourhood shell for peakness (0.3 m, 0.1 m). The inner
        radius excludes a compact emitter's own Gaussians from its neighbourhood; with 0 the
        shell is the full ball of the paper's wording, and a 40-Gaussian lamp scores a peakness
        of about 1 (its own Gaussians dominate the mean).
    peak_eps: regulariser of peakness, times the ROI mean base score (1.0): bounds the
        peakness of an isolated Gaussian (empty shell) by ``score / (peak_eps * mean)``.
    peak_power: exponent of peakness in the final score (1.0).
    nms_distance: greedy NMS suppression distance (1.0 m).
    refine_radius, refine_min_fraction: light position/colour = score-weighted mean of the
        tail Gaussians within refine_radius of the winner with score >= fraction * winner (0.1 m, 0.5).
    """

    roi_radius: float = 6.0
    view_layout: str = "octahedron"
    view_radius: float = 0.5
    num_views: int = 6
    up_axis: str = "Y"
    min_opacity: float = 1.0 / 255.0
    max_weight: float = 0.25
    clip_percentile: float = 99.9
    clip_knee_factor: float = 1.0
    stability_power: float = 1.0
    dominance_power: float = 1.0
    tail_fraction: float = 0.02
    min_candidates: int = 1000
    max_candidates: int = 20000
    peak_radius: float = 0.3
    peak_inner_radius: float = 0.1
    peak_eps: float = 1.0
    peak_power: float = 1.0
    nms_distance: float = 1.0
    refine_radius: float = 0.1
    refine_min_fraction: float = 0.5

    def check(self) -> LightEstimationConfig:
        """Raise ``UserError`` naming the first invalid field."""
        for name in _DISTANCE_FIELDS + ("min_opacity", "max_weight", "clip_percentile", "clip_knee_factor",
                                        "stability_power", "dominance_power", "tail_fraction", "peak_eps",
                                        "peak_power", "refine_min_fraction"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0.0):
                raise UserError(f"light estimation config: '{name}' must be a finite number >= 0, got {v}")
        if self.roi_radius <= 0 or self.peak_radius <= 0:
            raise UserError("light estimation config: 'roi_radius' and 'peak_radius' must be > 0")
        if self.peak_inner_radius > self.peak_radius:
            raise UserError("light estimation config: 'peak_inner_radius' must be <= 'peak_radius'")
        if not 0.0 <= self.max_weight <= 1.0 or not 0.0 <= self.clip_percentile <= 100.0:
            raise UserError("light estimation config: 'max_weight' must be in [0, 1] and 'clip_percentile' in [0, 100]")
        if self.view_layout not in ("octahedron", "ring"):
            raise UserError(f"light estimation config: 'view_layout' must be 'octahedron' or 'ring', "
                            f"got {self.view_layout!r}")
        if self.up_axis.upper() not in _AXES:
            raise UserError(f"light estimation config: 'up_axis' must be X, Y or Z, got {self.up_axis!r}")
        if self.num_views < 1 or self.max_candidates < 1 or self.min_candidates < 0:
            raise UserError("light estimation config: 'num_views' and 'max_candidates' must be >= 1")
        return self

    def in_scene_units(self, meters_per_unit: float) -> LightEstimationConfig:
        """Copy with every distance field divided by ``meters_per_unit``."""
        m = float(meters_per_unit)
        if not (np.isfinite(m) and m > 0):
            raise UserError(f"light estimation: metersPerUnit must be > 0, got {m}")
        return replace(self, **{f: getattr(self, f) / m for f in _DISTANCE_FIELDS})


@dataclass(frozen=True)
class EstimatedLight:
    """One estimated point light, world frame of the scene (scene units).

    position: (3,) float64, score-weighted centre of the winning Gaussian's bright neighbourhood.
    color: (3,) float64 linear RGB the character sees: the 3DGS colour ``max(0, 0.5 + SH(dir))``
        evaluated along ``dir = normalize(p - avatar_centroid)``, score-weighted like the position;
        not normalised (its luminance is the emitter's radiance, not the light's power).
    intensity: base score of the winner without the soft clip: opacity * luminance cue *
        stability * dominance, i.e. linear luminance (capture radiance units) seen from near the
        character, reduced by the reliability cues. Compare intensities within one scene only.
    score: final score (base * peakness^p) used for the NMS ranking.
    index: index of the winning Gaussian in the scene set.
    """

    position: np.ndarray
    color: np.ndarray
    intensity: float
    score: float
    index: int

    @property
    def chromaticity(self) -> np.ndarray:
        """``color`` divided by its Rec.709 luminance (all ones for a black colour)."""
        y = 0.2126 * self.color[0] + 0.7152 * self.color[1] + 0.0722 * self.color[2]
        return self.color / y if y > 0 else np.ones(3)


def make_viewpoints(centroid, config: LightEstimationConfig, meters_per_unit: float = 1.0) -> np.ndarray:
    """Viewpoints near the character (V, 3) float64, scene units (see :class:`LightEstimationConfig`)."""
    c = np.asarray(centroid, dtype=np.float64).reshape(3)
    r = config.view_radius / meters_per_unit
    if config.view_layout == "octahedron":
        return c + r * np.concatenate([np.eye(3), -np.eye(3)])
    up = _AXES[config.up_axis.upper()]
    a, b = [ax for ax in range(3) if ax != up]
    t = 2.0 * np.pi * np.arange(config.num_views) / config.num_views
    out = np.repeat(c[None], config.num_views, axis=0)
    out[:, a] += r * np.cos(t)
    out[:, b] += r * np.sin(t)
    return out


def _roi_scene(scene: GaussianSet, centre: np.ndarray, roi_radius: float, values_checked: bool = False,
               blocks: PointBlocks | None = None) -> tuple[GaussianSet, np.ndarray | None]:
    """``(scene, None)``, or, where every value is finite and the ROI ball (``roi_radius`` scene
    units around ``centre``) holds at most half of the Gaussians, ``(its Gaussians, their indices
    in scene)``: the kernel's steps read only ROI Gaussians (the status, cues, tail and
    neighbourhoods of the others are zero or unused), so the sub-scene gives the same lights, bit
    for bit, with indices mapped back; a scene far larger than the ROI is not scanned again. A
    non-finite value anywhere keeps the whole scene (the kernel names the element);
    ``values_checked``: the caller vouches that every value is finite (no scan for them);
    ``blocks``: None, or the scene's rows as ``usd_gs.point_blocks.PointBlocks`` (the ball test decided
    block by block: the same rows; the result kept there, shared by the calls for the same scene,
    centre and radius: the caller must not modify it)."""
    from usd_gs.point_blocks import within_ball
    from usd_gs.usd.gaussian_layer import all_finite

    if scene.count < 2:
        return scene, None
    if not (values_checked or all(all_finite(a) for a in (scene.positions, scene.opacities, scene.sh))):
        return scene, None

    def roi():
        # (the same float64 test as the kernel's: |p - c|^2 <= r^2)
        near = np.flatnonzero(within_ball(blocks, scene.positions, centre, float(roi_radius)))
        if near.size > scene.count // 2:
            return scene, None
        return scene.subset(near), near

    if blocks is None:
        return roi()
    # (the point and planar estimates ask for the same region: selected and copied once)
    return blocks.memo(("roi", *(float(v) for v in np.asarray(centre).reshape(3)), float(roi_radius)), scene, roi)


def estimate_lights(scene: GaussianSet, avatar_centroid, k: int = 2,
                    config: LightEstimationConfig | None = None, meters_per_unit: float = 1.0,
                    values_checked: bool = False, blocks: PointBlocks | None = None) -> list[EstimatedLight]:
    """The ``k`` dominant point lights of ``scene`` as seen from ``avatar_centroid`` (3,).

    Returns at most k lights (fewer if the ROI holds fewer separated candidates), sorted by
    decreasing intensity. Raises ``GaussianDataError`` naming the first Gaussian with a
    non-finite position, opacity or SH coefficient, ``UserError`` for a bad config or centroid.
    ``values_checked``: the caller has checked every position, opacity and SH coefficient finite
    (as ``usd_gs.usd``'s reads do); the pass over the whole scene that would name a bad one is
    skipped (the same lights).
    """
    config = (config or LightEstimationConfig()).check()
    if int(k) < 0:
        raise UserError(f"light estimation: k must be >= 0, got {k}")
    c = np.asarray(avatar_centroid, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise UserError(f"light estimation: avatar centroid must be 3 finite numbers, got {avatar_centroid!r}")
    from numba_kernels.light_estimation import STATUS_NONFINITE, estimate_lights_arrays

    cfg = config.in_scene_units(meters_per_unit)
    roi, rows = _roi_scene(scene, c, cfg.roi_radius, values_checked, blocks)
    res = estimate_lights_arrays(roi.positions, roi.opacities, roi.sh, c,
                                 make_viewpoints(c, config, meters_per_unit), int(k), cfg)
    if rows is not None:
        res["index"] = rows[res["index"]]
    bad = np.flatnonzero(res["status"] == STATUS_NONFINITE)
    if bad.size:
        i = int(bad[0])
        field = next(name for name, arr in (("positions", scene.positions), ("opacities", scene.opacities),
                                            ("sh", scene.sh)) if not np.all(np.isfinite(arr[i])))
        raise GaussianDataError(f"{scene.label}: '{field}' element {i} is not finite ({bad.size} Gaussians with "
                                f"non-finite values); light estimation needs finite values")
    return [EstimatedLight(position=res["position"][i].copy(), color=res["color"][i].copy(),
                           intensity=float(res["intensity"][i]), score=float(res["score"][i]),
                           index=int(res["index"][i]))
            for i in range(res["index"].shape[0])]


# ----------------------------------------------------------------------------- planar emitters
@dataclass(frozen=True)
class RectLightConfig:
    """Parameters of the planar-emitter (RectLight) detection; distances in metres.

    The bright set is paper 3.1's high-score tail (same cues, knee and tail size as
    :class:`LightEstimationConfig`), kept where the base score is at least ``contrast`` (6)
    times the median base score of the ROI. It is cut into single-linkage clusters
    (``link_distance`` 0.1 m); a cluster of at least ``min_count`` (24) Gaussians is a planar
    emitter when the principal axes of its centres (unweighted PCA, standard deviations
    ``s1 >= s2 >= s3``) give ``s3 < max_flatness * s2`` (0.1), sides ``sqrt(12) s`` (the side
    of a uniform rectangle with that standard deviation) of at least ``min_side`` (0.2 m) and an
    area ``12 s1 s2`` of at least ``min_area`` (0.1 m^2), a brightness variation
    ``std / mean`` of its unclipped scores at most ``max_variation`` (0.5: a panel or window
    is evenly bright, a lit patch of wall fades), and its plane facing the avatars:
    ``|n . (c - centre)| / |c - centre| >= min_facing`` (0.2).
    """

    contrast: float = 6.0
    link_distance: float = 0.1
    min_count: int = 24
    max_flatness: float = 0.1
    min_side: float = 0.2
    min_area: float = 0.1
    max_variation: float = 0.5
    min_facing: float = 0.2

    def check(self) -> RectLightConfig:
        """Raise ``UserError`` naming the first invalid field."""
        for name in ("contrast", "link_distance", "max_flatness", "min_side", "min_area", "max_variation",
                     "min_facing"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0.0):
                raise UserError(f"rect light config: '{name}' must be a finite number >= 0, got {v}")
        if self.link_distance <= 0 or self.min_count < 3:
            raise UserError("rect light config: 'link_distance' must be > 0 and 'min_count' >= 3")
        return self


@dataclass
class EstimatedRectLight:
    """One estimated planar emitter, world frame of the scene (scene units).

    position: (3,) float64 centre (mean of the cluster's Gaussian centres, on its plane).
    normal: (3,) unit emission normal, toward the avatars' side of the plane.
    axes: (3, 3) columns: the light's local x (the longest side, ``width``), y (``height``) and
        z = -normal (UsdLux area lights emit along local -Z); a proper rotation.
    width, height: sides along local x and y (``sqrt(12)`` times the standard deviations).
    color: (3,) linear RGB the character sees: the mean 3DGS colour ``max(0, 0.5 + SH(dir))``
        of the cluster along ``dir = normalize(p - avatar_centroid)``, weighted by the base scores.
    intensity: mean unclipped base score of the cluster (paper 3.1's ``raw``: opacity x
        luminance cue x reliability cues; the point lights' intensity unit).
    score: ``intensity * area`` (area in square metres), the ranking of planar emitters.
    index: (C,) int64 the cluster's Gaussians in the scene set.
    evidence: the figures the acceptance tests read (count, area_m2, flatness, variation,
        facing, contrast), for customData.
    rejected: why it is not a light ('' when kept); visibility: set by the plausibility test.
    """

    position: np.ndarray
    normal: np.ndarray
    axes: np.ndarray
    width: float
    height: float
    color: np.ndarray
    intensity: float
    score: float
    index: np.ndarray
    evidence: dict = field(default_factory=dict)
    rejected: str = ""
    visibility: float = 1.0

    @property
    def area(self) -> float:
        return float(self.width * self.height)

    def contains(self, points, slab: float, margin: float) -> np.ndarray:
        """(M,) bool: points within ``slab`` of the plane and inside the rectangle grown by ``margin``."""
        d = np.asarray(points, np.float64).reshape(-1, 3) - self.position
        u, v, w = d @ self.axes[:, 0], d @ self.axes[:, 1], d @ self.axes[:, 2]
        return (np.abs(w) <= slab) & (np.abs(u) <= self.width / 2 + margin) & (np.abs(v) <= self.height / 2 + margin)


def estimate_rect_lights(scene: GaussianSet, avatar_centroid, config: RectLightConfig | None = None,
                         light_config: LightEstimationConfig | None = None,
                         meters_per_unit: float = 1.0, values_checked: bool = False,
                         blocks: PointBlocks | None = None) -> list[EstimatedRectLight]:
    """The planar emitters of ``scene`` (windows, panels) seen from ``avatar_centroid`` (3,):
    :class:`RectLightConfig`'s clusters of paper 3.1's bright Gaussians, sorted by decreasing
    score. Plausibility (visibility from the avatars, below the floor) is the caller's
    (``usd_gs.relight.sun_estimation.plausible_emitters``). Raises like :func:`estimate_lights`;
    ``values_checked`` and ``blocks`` as there."""
    config = (config or RectLightConfig()).check()
    light_config = (light_config or LightEstimationConfig()).check()
    c = np.asarray(avatar_centroid, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise UserError(f"light estimation: avatar centroid must be 3 finite numbers, got {avatar_centroid!r}")
    from numba_kernels.light_estimation import (
        STATUS_IN_ROI,
        STATUS_NONFINITE,
        estimate_lights_arrays,
        linked_clusters,
        select_tail,
    )

    mpu = float(meters_per_unit)
    cfg = light_config.in_scene_units(mpu)
    # (what follows reads ROI Gaussians only)
    scene, rows = _roi_scene(scene, c, cfg.roi_radius, values_checked, blocks)
    res = estimate_lights_arrays(scene.positions, scene.opacities, scene.sh, c,
                                 make_viewpoints(c, light_config, mpu), 0, cfg)
    bad = np.flatnonzero(res["status"] == STATUS_NONFINITE)
    if bad.size:
        raise GaussianDataError(f"{scene.label}: element {int(bad[0])} has non-finite values ({bad.size} "
                                f"Gaussians); light estimation needs finite values")
    base, raw = res["base"], res["raw"]
    roi = np.flatnonzero(res["status"] == STATUS_IN_ROI)
    if roi.size == 0:
        return []
    med = float(np.median(base[roi]))
    n_tail = min(max(math.ceil(cfg.tail_fraction * roi.size), int(cfg.min_candidates)), int(cfg.max_candidates))
    tail = select_tail(base, n_tail)
    bright = tail[base[tail] >= config.contrast * med] if med > 0 else tail
    if bright.size < config.min_count:
        return []
    p = scene.positions[bright].astype(np.float64)
    labels = linked_clusters(p, config.link_distance / mpu)
    roots, counts = np.unique(labels, return_counts=True)
    out = []
    for root in roots[counts >= config.min_count]:  # a loop over clusters, not Gaussians
        members = np.flatnonzero(labels == root)
        light = _planar_cluster(scene, c, bright[members], p[members], base, raw, med, config, mpu)
        if light is not None:
            if rows is not None:  # (indices in the caller's scene)
                light = replace(light, index=rows[light.index])
            out.append(light)
    out.sort(key=lambda r: -r.score)
    return out


def _planar_cluster(scene, centroid, idx, p, base, raw, median, config, mpu):
    """The :class:`EstimatedRectLight` of one bright cluster, or None where it is not a planar
    emitter (:class:`RectLightConfig`)."""
    from usd_gs.sh3dgs import eval_color

    centre = p.mean(axis=0)
    d = p - centre
    evals, evecs = np.linalg.eigh(d.T @ d / p.shape[0])  # ascending
    s3, s2, s1 = np.sqrt(np.maximum(evals, 0.0))
    flatness = s3 / s2 if s2 > 0 else 1.0
    w, h = math.sqrt(12.0) * s1, math.sqrt(12.0) * s2  # scene units
    area_m2 = w * h * mpu * mpu
    r = raw[idx]
    variation = float(np.std(r) / np.mean(r)) if np.mean(r) > 0 else 1.0
    n = evecs[:, 0].copy()
    to_c = centroid - centre
    dist = float(np.linalg.norm(to_c))
    if n @ to_c < 0:
        n = -n
    facing = float(n @ to_c / dist) if dist > 0 else 1.0
    if (flatness >= config.max_flatness or h * mpu < config.min_side or area_m2 < config.min_area
            or variation > config.max_variation or facing < config.min_facing):
        return None
    x = evecs[:, 2].copy()
    z = -n
    y = np.cross(z, x)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    axes = np.stack([x, y, z], axis=1)
    dirs = scene.positions[idx].astype(np.float64) - centroid
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-300)
    col = np.maximum(eval_color(scene.sh[idx], dirs), 0.0)
    wts = base[idx]
    color = (wts[:, None] * col).sum(0) / wts.sum()
    intensity = float(np.mean(r))
    evidence = {"count": int(idx.size), "area_m2": round(float(area_m2), 4), "flatness": round(float(flatness), 4),
                "variation": round(variation, 4), "facing": round(facing, 4),
                "contrast": round(float(np.mean(base[idx]) / median), 3) if median > 0 else 0.0}
    return EstimatedRectLight(centre, n, axes, float(w), float(h), color, intensity, intensity * area_m2,
                              np.asarray(idx, np.int64), evidence)
