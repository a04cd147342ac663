"""The static scene's shadow on moving receivers: one DGSM per point light for the whole shot.

The scene Gaussians do not move, so the transmittance they give a voxel of a light's atlas is
the same at every frame. :class:`StaticSceneAtlas` therefore bins the scene's occluders into
light-space tiles once per shot and light, and computes a voxel column (one atlas pixel, every
radial bin) the first time a receiver's lookup needs it; later frames reuse every column
already computed and only add the pixels the moving receivers newly reach. Each voxel is
computed at most once per shot, and no frame needs a look ahead.

Against the per-frame build this trades the tight per-frame bin range for a fixed one:
``t_max`` puts the last bin centre just beyond the farthest scene occluder (receivers farther
away read the last bin, which holds every occluder on the ray), and ``K`` bins span it (default
twice the moving casters' K). Where the bins a lookup blends differ by more than the
refinement contrast (for example a foot just in front of the floor) the lookup is redone
exactly on the point's own ray (``dgsm_sample.lookup_point_refined``), so the coarser radial
spacing costs no accuracy at shadow edges.

Point lights only; a directional light uses the per-frame path of ``usd_gs.shadows.shot``.
Positions in metres (world space); transmittances float64 in [0, 1].
"""

from __future__ import annotations

import numpy as np

from numba_kernels import dgsm_build, dgsm_sample
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders


class StaticSceneAtlas:
    """Lazily filled DGSM of ``occluders`` (static, world space) for a point light at
    ``light_position`` (3,) metres; ``K`` radial bins (None: ``2 * cfg.K``)."""

    def __init__(self, occluders: GaussianSet, light_position, cfg: DGSMConfig, K: int | None = None):
        self.cfg = cfg
        self.light = np.asarray(light_position, np.float64).reshape(3)
        self.width = int(cfg.atlas_size)
        self.K = int(K or 2 * cfg.K)
        self.count = occluders.count
        self.occ, self.dir_dep, cov6 = prepare_occluders(occluders, cfg)
        ext = occluders.extent(cfg.k_sigma).astype(np.float64) if occluders.count else np.zeros((2, 3))
        corners = np.array([[ext[i, 0], ext[j, 1], ext[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        self.t_max = dgsm_build.t_max_for(dgsm_build.far_distance(self.light, corners), self.K)
        wt = self.width // dgsm_build.TILE
        self.tiles = dgsm_build.bin_tiles(self.light, np.ascontiguousarray(self.occ[:, :3]), cov6, self.width,
                                          cfg.k_sigma, np.ones(wt * wt, np.bool_)) if self.count else None
        self.index = np.full(self.width * self.width, -1, np.int32)
        self.values = np.ones((0, self.K), np.float32)
        self.pixels = np.zeros(0, np.int64)
        self.pairs = 0
        self.erf_evals = 0

    @property
    def computed_pixels(self) -> int:
        """Number of atlas pixels (voxel columns) computed so far."""
        return int(self.pixels.size)

    def _extend(self, points: np.ndarray) -> None:
        """Compute the voxel columns of ``points``' trilinear stencils that are not there yet."""
        need, _, _ = dgsm_build.roi_voxels(self.light, points, self.width, self.K, self.t_max)
        new = need[self.index[need] < 0]
        if new.size == 0:
            return
        out = np.ones((new.size, self.K), np.float32)
        pairs = np.zeros(new.size, np.int64)
        erfs = np.zeros(new.size, np.int64)
        dgsm_build.accumulate_pixels(self.light, self.occ, self.dir_dep, new, self.width, self.K, self.t_max, 0,
                                     self.K - 1, self.tiles, True, self.cfg.bin_skip, out, pairs, erfs)
        self.index[new] = np.arange(self.pixels.size, self.pixels.size + new.size, dtype=np.int32)
        self.values = np.concatenate([self.values, out]) if self.values.size else out
        self.pixels = np.concatenate([self.pixels, new])
        self.pairs += int(pairs.sum())
        self.erf_evals += int(erfs.sum())

    def atlas(self) -> dgsm_build.Atlas:
        """The atlas as computed so far (``dgsm_build.Atlas``; uncomputed voxels read 1)."""
        return dgsm_build.Atlas(self.width, self.K, self.t_max, 0, self.K - 1, self.index, self.values, self.pixels,
                                self.pairs, self.erf_evals, self.tiles)

    def transmittance(self, points) -> np.ndarray:
        """(M,) float64 transmittance at ``points`` (M, 3) metres: trilinear lookups, refined
        exactly where the voxels blended differ by more than ``cfg.refine_contrast``."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if self.count == 0 or pts.shape[0] == 0:
            return np.ones(pts.shape[0])
        self._extend(pts)
        atlas = self.atlas()
        if self.cfg.refine_contrast is None:
            return dgsm_sample.lookup_point(atlas, self.light, pts)
        vals, _ = dgsm_sample.lookup_point_refined(atlas, self.light, pts, self.occ, self.dir_dep,
                                                   self.cfg.refine_contrast)
        return vals
