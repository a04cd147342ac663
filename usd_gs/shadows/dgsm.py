"""Deep Gaussian Shadow Maps: thin wrapper over ``numba_kernels`` for ``GaussianSet`` inputs.

Occluders (the avatar/object Gaussians) cast shadows on receivers (scene Gaussians) from a
point light (position (3,) metres) or a directional light (propagation direction (3,), e.g. a
UsdLux DistantLight's -Z axis in world space). Positions are in metres in one common world
frame; ``up_axis`` ('Y' default, our captures are Y-up, or 'Z') picks the height axis of the
receiver ROI box. Returned transmittances are float64 in [0, 1] (1 = unshadowed).

Pipeline (paper sec. 3.2-3.3): ROI receivers -> footprint sample points -> atlas build over
the points' voxels -> trilinear lookups averaged per receiver. Receivers outside the ROI get
T = 1 (the paper's "table is 1 outside by construction").

Defaults (``DGSMConfig``) and why (figures from benchmarks/bench_dgsm.py on the bench scene:
biker.ply as occluder, 1M floor/wall receivers, light 2.5 m up): ``atlas_size=512, K=64``:
mean error ~0.002 from the atlas alone, K hardly matters there (angular edges dominate),
W=256 is 4x worse, W=1024 doubles the build time for ~30 % less error;
``k_sigma=4`` (paper: 3): at 3 the culling truncation alone reaches 0.13 in dense regions,
at 4 it is < 3e-4 per occluder; ``refine_contrast=0.1``: exact re-evaluation of the ~2 % of
lookups that straddle a shadow edge sharper than a pixel, bringing the per-receiver max
error from ~0.15 to < 0.05; ``roi_radius=2`` m as the paper; ``mapping='avg'`` (eq. 5);
``sampling='center'``: against the mesh pseudo ground truth on the demo shot (``usdgs bench``)
the centre sample scores SAE 0.023 / SM-IoU 0.843 / BF 0.930 where the paper's MC footprint
(``sampling='mc', n_samples=8, seed=0``, still available) scores 0.034 / 0.812 / 0.879: the
rendered receiver splat already spreads its one value over its footprint, so averaging over the
footprint first blurs shadow edges twice; it is also 8x fewer lookups.
This module imports numba (through the kernels); do not import it from file-I/O modules.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from numba_kernels import dgsm_build, dgsm_directional, dgsm_exact, dgsm_model, dgsm_sample
from usd_gs.errors import GaussianDataError, UserError, first_bad_index
from usd_gs.gaussians import GaussianSet


@dataclass
class DGSMConfig:
    """DGSM options. Lengths in metres.

    atlas_size: octahedral atlas side W (multiple of 8); K: radial bins; t_max: bin range
    (None: from the farthest ROI sample point); k_sigma: culling ellipse radius in sigmas;
    roi_radius: R of the ROI box (inf-norm in the horizontal plane around the avatar's
    alpha-weighted centroid); roi_percentiles / roi_margin: robust height bounds = the given
    percentiles of the avatar's centre heights widened by the margin on both sides;
    up_axis: 'Y' or 'Z'; kappa, mapping: eq. 5 and ablation B (``dgsm_model``); use_roi,
    use_tile_culling, bin_skip: culling flags (``dgsm_build``); sampling 'center' | 'stencil7'
    | 'mc' with n_samples and seed (``dgsm_sample``); refine_contrast: exact re-evaluation of
    lookups whose voxels differ by more than this (``dgsm_sample.lookup_point_refined``, point
    lights only), None to disable (the paper's plain trilinear lookup).
    """

    atlas_size: int = 512
    K: int = 64
    t_max: float | None = None
    k_sigma: float = 4.0
    roi_radius: float = 2.0
    roi_percentiles: tuple[float, float] = (1.0, 99.0)
    roi_margin: float = 0.3
    up_axis: str = "Y"
    kappa: float = 1.0
    mapping: str = "avg"
    use_roi: bool = True
    use_tile_culling: bool = True
    bin_skip: bool = True
    sampling: str = "center"
    n_samples: int = 8
    seed: int = 0
    refine_contrast: float | None = 0.1

    def validate(self) -> DGSMConfig:
        if self.up_axis not in ("Y", "Z"):
            raise UserError(f"DGSM: up_axis must be 'Y' or 'Z', got {self.up_axis!r}")
        if self.mapping not in dgsm_model.MAPPINGS:
            raise UserError(f"DGSM: mapping must be one of {dgsm_model.MAPPINGS}, got {self.mapping!r}")
        if self.sampling not in ("center", "stencil7", "mc"):
            raise UserError(f"DGSM: sampling must be 'center', 'stencil7' or 'mc', got {self.sampling!r}")
        from usd_gs.resources import check_limit

        check_limit("atlas_size", self.atlas_size)
        if self.atlas_size % 8:
            raise UserError(f"DGSM: atlas_size must be a positive multiple of 8, got {self.atlas_size}")
        check_limit("K", self.K, "DGSM K")
        check_limit("n_samples", self.n_samples)
        for name in ("roi_radius", "k_sigma", "kappa"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UserError(f"DGSM: {name} must be a finite number, got {v!r}")
        if not (self.roi_radius > 0 and self.k_sigma > 0):
            raise UserError("DGSM: roi_radius and k_sigma must be > 0")
        return self


@dataclass
class DGSM:
    """A built shadow map with the data needed to sample it.

    light: (3,) float64 light position (point light) or unit propagation direction
    (directional); atlas: ``dgsm_build.Atlas`` or ``dgsm_directional.DirAtlas``; roi: (R,)
    int64 receiver indices in the ROI; points: (R*n, 3) float64 footprint sample points;
    weights: (n,) footprint weights; timings: seconds per stage; stencils: None, or the points'
    ``dgsm_build.Stencils`` in a point-light atlas (what its build computed for them), which the
    refined lookups read instead of computing them again.
    """

    light: np.ndarray
    atlas: dgsm_build.Atlas | dgsm_directional.DirAtlas
    roi: np.ndarray
    points: np.ndarray
    weights: np.ndarray
    config: DGSMConfig
    timings: dict = field(default_factory=dict)
    prepared: tuple | None = None  # (occ, dir_dep, cov6) the atlas was built from
    stencils: dgsm_build.Stencils | None = None


def _wrap_errors(label: str, fn, *args, **kw):
    try:
        return fn(*args, **kw)
    except ValueError as exc:
        raise GaussianDataError(f"{label}: {exc}") from None


def prepare_occluders(occluders: GaussianSet, cfg: DGSMConfig, out=None):
    """Packed occluders ``(occ (N, 16), dir_dep, cov6 (N, 6))`` (``dgsm_model.pack_gaussians``; ``out``:
    its buffers to reuse). Raises ``GaussianDataError`` naming the set, the field and the first bad
    element."""
    return _wrap_errors(occluders.label, dgsm_model.pack_gaussians, occluders.positions, occluders.orientations,
                        occluders.scales, occluders.opacities, cfg.kappa, cfg.mapping, out)


def _axes(up_axis: str):
    return (1, (0, 2)) if up_axis == "Y" else (2, (0, 1))


def roi_box_params(occluders: GaussianSet, cfg: DGSMConfig):
    """``(c (3,), h_lo, h_hi)`` of the ROI box: ``c`` the opacity-weighted centroid of the
    occluder centres (plain mean if every opacity is 0), ``h_lo, h_hi`` the ``roi_percentiles``
    of occluder heights widened by ``roi_margin``."""
    h, _ = _axes(cfg.up_axis)
    p = occluders.positions
    w = occluders.opacities.astype(np.float64)
    c = (w @ p.astype(np.float64)) / w.sum() if w.sum() > 0 else p.astype(np.float64).mean(axis=0)
    lo, hi = np.percentile(p[:, h], cfg.roi_percentiles)
    return c, float(lo) - cfg.roi_margin, float(hi) + cfg.roi_margin


def roi_indices(occluders: GaussianSet, receiver_positions: np.ndarray, cfg: DGSMConfig,
                label: str = "receivers") -> np.ndarray:
    """Receivers inside ``B = {|x - c|_inf (horizontal) <= R, h_lo <= height <= h_hi}``
    (``roi_box_params``); every receiver with ``use_roi=False``. A non-finite receiver
    position raises ``GaussianDataError`` naming ``label`` and the element."""
    pos = np.asarray(receiver_positions)
    n = pos.shape[0]
    if not cfg.use_roi:
        bad = ~np.isfinite(pos).all(axis=1)
        if bad.any():
            i = first_bad_index(bad)
            raise GaussianDataError(f"{label}: 'positions' element {i} is not finite (value {pos[i]})")
        return np.arange(n, dtype=np.int64)
    if occluders.count == 0:
        return np.zeros(0, np.int64)
    h, _ = _axes(cfg.up_axis)
    c, lo, hi = roi_box_params(occluders, cfg)
    idx, bad = dgsm_sample.roi_box(pos, c, cfg.roi_radius, h, lo, hi)
    if bad >= 0:
        raise GaussianDataError(f"{label}: 'positions' element {bad} is not finite (value {pos[bad]})")
    return idx


def _check_receivers(receivers: GaussianSet, idx: np.ndarray) -> None:
    for name in ("scales", "orientations"):
        arr = getattr(receivers, name)[idx]
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            i = int(idx[first_bad_index(bad)])
            raise GaussianDataError(f"{receivers.label}: '{name}' element {i} is not finite "
                                    f"(value {getattr(receivers, name)[i]})")


def footprint_samples(receivers: GaussianSet, idx: np.ndarray, cfg: DGSMConfig):
    """Sample points (len(idx)*n, 3) float64 and weights (n,) of the receivers ``idx``
    (``dgsm_sample.footprint_points_gaussians``)."""
    return dgsm_sample.footprint_points_gaussians(receivers.positions, receivers.orientations, receivers.scales, idx,
                                                  cfg.sampling, cfg.n_samples, cfg.seed)


def _light(light) -> np.ndarray:
    a = np.asarray(light, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise GaussianDataError(f"DGSM: light position must be 3 finite numbers, got {light!r}")
    return a


def _roi_and_points(occluders, receivers, cfg):
    idx = roi_indices(occluders, receivers.positions, cfg, receivers.label)
    _check_receivers(receivers, idx)
    pts, w = footprint_samples(receivers, idx, cfg)
    return idx, pts, w


def build_dgsm(occluders: GaussianSet, receivers: GaussianSet, light, cfg: DGSMConfig | None = None,
               prepared=None) -> DGSM:
    """Build the point-light DGSM (light position (3,) metres) for ``receivers``: ROI,
    footprint sample points, atlas. ``prepared`` may pass ``prepare_occluders``' result."""
    import time

    cfg = (cfg or DGSMConfig()).validate()
    light = _light(light)
    t0 = time.perf_counter()
    occ, dd, cov6 = prepared if prepared is not None else prepare_occluders(occluders, cfg)
    t1 = time.perf_counter()
    idx, pts, w = _roi_and_points(occluders, receivers, cfg)
    t2 = time.perf_counter()
    atlas = _wrap_errors(occluders.label, dgsm_build.build_point, light, occ, dd, cov6, pts, cfg.atlas_size, cfg.K,
                         cfg.t_max, cfg.k_sigma, cfg.use_roi, cfg.use_tile_culling, cfg.bin_skip)
    t3 = time.perf_counter()
    return DGSM(light, atlas, idx, pts, w, cfg, {"prepare_occluders": t1 - t0, "roi_and_points": t2 - t1,
                                                  "atlas": t3 - t2}, (occ, dd, cov6), atlas.stencils)


def build_dgsm_directional(occluders: GaussianSet, receivers: GaussianSet, direction,
                           cfg: DGSMConfig | None = None, prepared=None) -> DGSM:
    """Directional-light DGSM (``direction`` (3,): where the light travels, e.g. a
    DistantLight's world -Z axis); grid of ``atlas_size``^2 x ``K`` depth bins over the ROI."""
    import time

    cfg = (cfg or DGSMConfig()).validate()
    d = _light(direction)
    if not np.linalg.norm(d) > 0:
        raise GaussianDataError("DGSM: light direction has zero length")
    d = d / np.linalg.norm(d)
    t0 = time.perf_counter()
    occ, dd, cov6 = prepared if prepared is not None else prepare_occluders(occluders, cfg)
    t1 = time.perf_counter()
    idx, pts, w = _roi_and_points(occluders, receivers, cfg)
    t2 = time.perf_counter()
    atlas = _wrap_errors(occluders.label, dgsm_directional.build_directional, d, occ, dd, cov6, pts, cfg.atlas_size,
                         max(cfg.K, 2), cfg.k_sigma, cfg.use_tile_culling, cfg.bin_skip)
    t3 = time.perf_counter()
    return DGSM(d, atlas, idx, pts, w, cfg, {"prepare_occluders": t1 - t0, "roi_and_points": t2 - t1,
                                              "atlas": t3 - t2}, (occ, dd, cov6))


def sample_dgsm(dgsm: DGSM) -> np.ndarray:
    """(len(dgsm.roi),) float64 footprint-averaged transmittance of the ROI receivers."""
    if isinstance(dgsm.atlas, dgsm_directional.DirAtlas):
        vals = dgsm_directional.lookup_directional(dgsm.atlas, dgsm.points)
    elif dgsm.config.refine_contrast is not None and dgsm.prepared is not None:
        occ, dd, _ = dgsm.prepared
        vals, _ = dgsm_sample.lookup_point_refined(dgsm.atlas, dgsm.light, dgsm.points, occ, dd,
                                                   dgsm.config.refine_contrast, stencils=dgsm.stencils)
    else:
        vals = dgsm_sample.lookup_point(dgsm.atlas, dgsm.light, dgsm.points)
    return dgsm_sample.weighted_mean(vals, dgsm.weights)


def shadow_transmittance(occluders: GaussianSet, receivers: GaussianSet, light=None,
                         cfg: DGSMConfig | None = None, direction=None) -> np.ndarray:
    """(N_receivers,) float64 transmittance of every receiver (1 outside the ROI), for a
    point light at ``light`` or (``light=None``) a directional light along ``direction``."""
    if (light is None) == (direction is None):
        raise UserError("DGSM: give exactly one of a light position and a light direction")
    d = (build_dgsm(occluders, receivers, light, cfg) if light is not None
         else build_dgsm_directional(occluders, receivers, direction, cfg))
    out = np.ones(receivers.count)
    out[d.roi] = sample_dgsm(d)
    return out


def exact_transmittance(occluders: GaussianSet, points, light, cfg: DGSMConfig | None = None,
                        prepared=None) -> np.ndarray:
    """(M,) float64 exact transmittance at ``points`` (M, 3) from a point light (no atlas)."""
    cfg = (cfg or DGSMConfig()).validate()
    occ, dd, _ = prepared if prepared is not None else prepare_occluders(occluders, cfg)
    return _wrap_errors(occluders.label, dgsm_exact.transmittance_point, _light(light), points, occ, dd)


def exact_transmittance_directional(occluders: GaussianSet, points, direction,
                                    cfg: DGSMConfig | None = None) -> np.ndarray:
    """(M,) float64 exact transmittance at ``points`` for parallel light along ``direction``."""
    cfg = (cfg or DGSMConfig()).validate()
    occ, dd, _ = prepare_occluders(occluders, cfg)
    return _wrap_errors(occluders.label, dgsm_exact.transmittance_directional, direction, points, occ, dd)
