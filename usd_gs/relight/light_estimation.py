"""Estimate k dominant point lights of a 3DGS scene around an avatar (paper section 3.1).

Thin wrapper around ``numba_kernels.light_estimation`` (imported lazily, so importing this
module does not load numba); the algorithm, its formulas and defaults are documented there
and in :class:`LightEstimationConfig`.

Conventions: the scene Gaussians and ``avatar_centroid`` are in one world frame (apply prim
transforms first, ``GaussianSet.transformed``); distances in the config are METRES and are
divided by ``meters_per_unit`` to get scene units; SH in the 3DGS basis (shared/DESIGN.md).
Only the ``"ring"`` viewpoint layout uses the up axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from usd_gs.errors import GaussianDataError, UserError
from usd_gs.gaussians import GaussianSet

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


def estimate_lights(scene: GaussianSet, avatar_centroid, k: int = 2,
                    config: LightEstimationConfig | None = None, meters_per_unit: float = 1.0) -> list[EstimatedLight]:
    """The ``k`` dominant point lights of ``scene`` as seen from ``avatar_centroid`` (3,).

    Returns at most k lights (fewer if the ROI holds fewer separated candidates), sorted by
    decreasing intensity. Raises ``GaussianDataError`` naming the first Gaussian with a
    non-finite position, opacity or SH coefficient, ``UserError`` for a bad config or centroid.
    """
    config = (config or LightEstimationConfig()).check()
    if int(k) < 0:
        raise UserError(f"light estimation: k must be >= 0, got {k}")
    c = np.asarray(avatar_centroid, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise UserError(f"light estimation: avatar centroid must be 3 finite numbers, got {avatar_centroid!r}")
    from numba_kernels.light_estimation import STATUS_NONFINITE, estimate_lights_arrays

    cfg = config.in_scene_units(meters_per_unit)
    res = estimate_lights_arrays(scene.positions, scene.opacities, scene.sh, c,
                                 make_viewpoints(c, config, meters_per_unit), int(k), cfg)
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
