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

A point light's bins span the occluders' range, at most :data:`SERVE_RADIUS` from the light where
they reach farther (a scene with a far part, such as a landscape beyond the room the avatars are
in): the receivers within that distance are looked up in those bins (each bin holds the
transmittance at its own depth on its ray, whatever the range; a served receiver lies before the
last bin centre, so no lookup reads the last bin for a point beyond it), and the receivers beyond
it in a second atlas whose bins span the whole range (the single atlas otherwise), built the
first time one is asked about. Either way a receiver's value depends only on its position, the
light and the scene, so a farm chunk gets the whole run's.

The point-light atlas packs only the occluders that can reach a lookup: those near the capsule
from the light to a ball holding every receiver asked about so far (a scene far from the avatars
costs nothing per light), packing again with a grown ball when the receivers leave it; the
lookups are bit for bit those of the atlas of every occluder (``bounded=False``).

:class:`StaticSceneSunAtlas` does the same for a directional light on a fixed lattice orthogonal to
it (no per-frame grid to fit: the lattice is the shot's). Positions in metres (world space);
transmittances float64 in [0, 1].
"""

from __future__ import annotations

import numpy as np

from numba_kernels import dgsm_build, dgsm_sample
from numba_kernels.capsule import within_capsule
from numba_kernels.lattice_lookup import CORNERS, lattice_interpolate, lattice_stencils
from usd_gs.gaussians import GaussianSet
from usd_gs.point_blocks import PointBlocks, within_reach
from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders
from usd_gs.shadows.lattice_index import LatticeIndex


class _ColumnStore:
    """Append-only (M, K) float32 voxel columns in a buffer that doubles when full, so adding a
    frame's new columns copies only them (not every column computed so far)."""

    def __init__(self, K: int):
        self._buf = np.ones((0, int(K)), np.float32)
        self.size = 0

    def append(self, cols: np.ndarray) -> int:
        """Store ``cols`` (m, K); returns the row of the first one."""
        m = cols.shape[0]
        if self.size + m > self._buf.shape[0]:
            grown = np.ones((max(2 * self._buf.shape[0], self.size + m, 1024), self._buf.shape[1]), np.float32)
            grown[: self.size] = self._buf[: self.size]
            self._buf = grown
        self._buf[self.size: self.size + m] = cols
        self.size += m
        return self.size - m

    @property
    def values(self) -> np.ndarray:
        """(M, K) view of the columns stored so far, in the order they were added."""
        return self._buf[: self.size]


class BlockExtents:
    """``GaussianSet.extent`` of rows of one large set ``g``, from the extents of row blocks computed
    once: fixed chunks of :data:`CHUNK` rows (all in one threaded pass, on the first call), or the
    blocks ``starts`` (B+1,) (increasing, from 0 to ``g.count``) whose ``boxes`` (B, 2, 3) float64 and
    ``ok`` (B,) bool a caller already has (``numba_kernels.extent.block_extents`` of those blocks, e.g.
    ``usd_gs.shadows.shot.prim_boxes``: the prims' boxes). :meth:`of` a row mask recomputes only the
    blocks the mask cuts into. The same bits as the extent of the masked subset (float64 minima and
    maxima, rounded to float32 once), whatever the blocks."""

    CHUNK = 1 << 16

    def __init__(self, g: GaussianSet, n_sigma: float, starts: np.ndarray | None = None,
                 boxes: np.ndarray | None = None, ok: np.ndarray | None = None):
        self.g, self.n_sigma = g, float(n_sigma)
        if starts is not None and (boxes is None or ok is None):
            raise ValueError("BlockExtents: blocks given without their boxes")
        self._blocks = None if starts is None else (np.asarray(starts, np.int64), boxes, ok)

    def blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(starts, boxes, ok)`` of the blocks (the fixed chunks computed on the first call)."""
        if self._blocks is None:
            from numba_kernels.extent import block_extents

            starts = np.append(np.arange(0, self.g.count, self.CHUNK), self.g.count).astype(np.int64)
            boxes, ok = block_extents(self.g.positions, self.g.orientations, self.g.scales, starts, self.n_sigma)
            self._blocks = (starts, boxes, ok)
        return self._blocks

    def _box(self, a: int, rows: np.ndarray) -> np.ndarray | None:
        """The extent of the block at ``a``'s ``rows`` (None: none, or not finite)."""
        from numba_kernels.extent import gaussian_extent

        g = self.g
        if not rows.size:
            return None
        idx = a + rows
        return gaussian_extent(g.positions[idx], g.orientations[idx], g.scales[idx], self.n_sigma)

    def of(self, keep: np.ndarray | None = None) -> np.ndarray:
        """(2, 3) float32 extent of the rows ``keep`` (N,) bool (None: every row) at least one of
        which is kept; ``GaussianDataError`` as ``GaussianSet.extent`` for a box that overflows."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        if not self.g.count:
            return np.stack([lo, hi]).astype(np.float32)
        starts, boxes, ok = self.blocks()
        sizes = np.diff(starts)
        if keep is None:
            kept = sizes
        else:  # each block's size less its dropped rows (few: no running count over every row)
            dropped = np.flatnonzero(~np.asarray(keep, bool))
            kept = sizes - np.diff(np.searchsorted(dropped, starts))
        whole = (kept == sizes) & (kept > 0)
        if not ok[whole].all():  # a box beyond float32: the subset's own extent names the element
            return self._named_error(keep)
        if whole.any():
            lo, hi = boxes[whole, 0].min(axis=0), boxes[whole, 1].max(axis=0)
        for i in np.flatnonzero((kept > 0) & ~whole):  # the blocks the mask cuts into
            a, b = int(starts[i]), int(starts[i + 1])
            box = self._box(a, np.flatnonzero(keep[a:b]))
            if box is None:
                return self._named_error(keep)
            lo, hi = np.minimum(lo, box[0]), np.maximum(hi, box[1])
        return np.stack([lo, hi]).astype(np.float32)

    def _named_error(self, keep: np.ndarray | None) -> np.ndarray:
        """The kept rows' own ``GaussianSet.extent``, for a block whose box is not finite in float32:
        it raises the ``GaussianDataError`` that names the first such element."""
        sub = self.g if keep is None else self.g.subset(keep)
        return sub.extent(self.n_sigma)


#: metres: a point light's atlas bins span at most this far for the receivers this close to it
#: (module docstring); where the lights' own irradiance is at least 1/225 of what it is at 1 m
SERVE_RADIUS = 15.0


class StaticSceneAtlas:
    """Lazily filled DGSM of ``occluders`` (static, world space) for a point light at
    ``light_position`` (3,) metres; ``K`` radial bins (None: ``2 * cfg.K``); ``bounded``: pack
    only the occluders the receivers' reach needs (module docstring), else all of them; ``blocks``:
    None, or the occluders' rows as ``usd_gs.point_blocks.PointBlocks`` (a scene of many bricks),
    whose capsule test then decides whole bricks at once (the same occluders); ``serve_radius``
    (scene units; None: no limit): the bins span at most this far, for the receivers within it of
    the light, and a second atlas over the whole range serves those beyond (module docstring)."""

    def __init__(self, occluders: GaussianSet, light_position, cfg: DGSMConfig, K: int | None = None,
                 bounded: bool = True, keep: np.ndarray | None = None, extents: BlockExtents | None = None,
                 blocks: PointBlocks | None = None, serve_radius: float | None = None):
        self.cfg = cfg
        self._blocks = blocks
        self.light = np.asarray(light_position, np.float64).reshape(3)
        self.width = int(cfg.atlas_size)
        self.K = int(K or 2 * cfg.K)
        self._all = occluders
        self._keep = None if keep is None or keep.all() else np.asarray(keep, bool)
        self.count = occluders.count if self._keep is None else int(self._keep.sum())
        self._bounded = bool(bounded)
        if not self.count:
            ext = np.zeros((2, 3))
        elif extents is not None:
            ext = extents.of(self._keep).astype(np.float64)
        else:
            ext = (occluders if self._keep is None else occluders.subset(self._keep)).extent(cfg.k_sigma).astype(
                np.float64)
        corners = np.array([[ext[i, 0], ext[j, 1], ext[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        t_far = dgsm_build.far_distance(self.light, corners)
        self.serve = None  # (scene units) the receivers this atlas serves, None: all
        self._beyond = None  # the atlas of the receivers beyond ``serve`` (built on first need)
        if serve_radius is not None and self.count and t_far > float(serve_radius) > 0.0:
            self.serve = t_far = float(serve_radius)
            self._whole = (occluders, light_position, cfg, K, bounded, keep, extents, blocks)
        self.t_max = dgsm_build.t_max_for(t_far, self.K)
        self.reach: tuple[np.ndarray, float] | None = None  # (centre, radius) of the receivers served
        self.kept = 0
        self.builds = 0  # packings of the occluders (a reach that grows packs again)
        self.occ = self.dir_dep = self.tiles = None
        self.index = np.full(self.width * self.width, -1, np.int32)
        self._columns = _ColumnStore(self.K)
        self.pixels = np.zeros(0, np.int64)
        self.pairs = 0
        self.erf_evals = 0
        if not self._bounded:
            self._build(np.arange(occluders.count) if self._keep is None else np.flatnonzero(self._keep))

    def _build(self, keep: np.ndarray) -> None:
        """Pack and bin the occluders ``keep`` (increasing indices); no column computed yet."""
        sub = self._all if keep.size == self._all.count else self._all.occluder_subset(keep)
        self.kept = int(keep.size)
        self.builds += 1
        self.occ, self.dir_dep, cov6 = prepare_occluders(sub, self.cfg)
        wt = self.width // dgsm_build.TILE
        self.tiles = dgsm_build.bin_tiles(self.light, self.occ, cov6, self.width,
                                          self.cfg.k_sigma, np.ones(wt * wt, np.bool_)) if keep.size else None
        self.index = np.full(self.width * self.width, -1, np.int32)
        self._columns = _ColumnStore(self.K)
        self.pixels = np.zeros(0, np.int64)
        self.pairs = 0
        self.erf_evals = 0

    def _reach_for(self, pts: np.ndarray) -> None:
        """Bound the occluders by the receivers: when ``pts`` leave the current reach (a ball), a
        reach holding them and the old one (grown by half, plus one scene unit, so that walking
        avatars seldom leave it) is taken and the occluders that can matter to a lookup inside it
        are packed again (the columns computed so far are dropped: same values, computed again)."""
        if self.reach is not None:
            c, r = self.reach
            if within_capsule(pts, c, c, r).all():  # (one threaded pass: the usual frame ends here)
                return
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if self.reach is not None:
            lo, hi = np.minimum(lo, c - r), np.maximum(hi, c + r)
        centre = 0.5 * (lo + hi)
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        radius = 1.5 * radius + 1.0
        self.reach = (centre, radius)
        near = self._in_reach(centre, radius)
        self._build(np.flatnonzero(near if self._keep is None else near & self._keep))

    def _in_reach(self, centre: np.ndarray, radius: float) -> np.ndarray:
        """(N,) bool: the occluders whose ``k_sigma`` sphere comes within ``radius`` plus a margin of
        the segment from the light to ``centre``: that capsule holds every ray from the light to a
        point of the reach, so an occluder outside it adds nothing to a voxel a lookup there reads.
        The margin covers the voxels those lookups blend: one radial bin beyond the point and the
        neighbouring pixels' rays (two pixel angles of the octahedral map, at most 4/W radians)."""
        length = float(np.linalg.norm(centre - self.light))
        far = length + radius + self.t_max / self.K
        margin = self.t_max / self.K + 2.0 * (4.0 / self.width) * far
        return within_reach(self._blocks, self._all.positions, self.light, centre, radius + margin, self._all.scales,
                            self.cfg.k_sigma)

    @property
    def computed_pixels(self) -> int:
        """Number of atlas pixels (voxel columns) computed so far."""
        return int(self.pixels.size)

    @property
    def values(self) -> np.ndarray:
        """(computed_pixels, K) float32 voxel columns, in the order of ``pixels``."""
        return self._columns.values

    def _extend(self, points: np.ndarray) -> dgsm_build.Stencils:
        """Compute the voxel columns of ``points``' trilinear stencils that are not there yet;
        returns the stencils (``dgsm_build.point_stencils``) for the lookups of these points."""
        stencils = dgsm_build.point_stencils(self.light, points, self.width, self.K, self.t_max)
        need, _, _ = dgsm_build.stencil_roi(stencils, self.width)
        new = need[self.index[need] < 0]
        if new.size == 0:
            return stencils
        out = np.ones((new.size, self.K), np.float32)
        pairs = np.zeros(new.size, np.int64)
        erfs = np.zeros(new.size, np.int64)
        dgsm_build.accumulate_pixels(self.light, self.occ, self.dir_dep, new, self.width, self.K, self.t_max, 0,
                                     self.K - 1, self.tiles, True, self.cfg.bin_skip, out, pairs, erfs)
        first = self._columns.append(out)
        self.index[new] = np.arange(first, first + new.size, dtype=np.int32)
        self.pixels = np.concatenate([self.pixels, new])
        self.pairs += int(pairs.sum())
        self.erf_evals += int(erfs.sum())
        return stencils

    def atlas(self) -> dgsm_build.Atlas:
        """The atlas as computed so far (``dgsm_build.Atlas``; uncomputed voxels read 1)."""
        return dgsm_build.Atlas(self.width, self.K, self.t_max, 0, self.K - 1, self.index, self.values, self.pixels,
                                self.pairs, self.erf_evals, self.tiles)

    def transmittance(self, points) -> np.ndarray:
        """(M,) float64 transmittance at ``points`` (M, 3) metres: trilinear lookups, refined
        exactly where the voxels blended differ by more than ``cfg.refine_contrast``; the points
        beyond ``serve`` from the light in the atlas of the whole range (class docstring)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if self.serve is None:
            return self._served(pts)
        d = pts - self.light
        near = np.einsum("ij,ij->i", d, d) <= self.serve * self.serve
        if near.all():
            return self._served(pts)
        if self._beyond is None:
            self._beyond = StaticSceneAtlas(*self._whole)
        out = np.empty(pts.shape[0])
        out[near] = self._served(pts[near])
        out[~near] = self._beyond.transmittance(pts[~near])
        return out

    def _served(self, pts: np.ndarray) -> np.ndarray:
        """:meth:`transmittance` of points within ``serve`` (all of them where it is None)."""
        if self.count == 0 or pts.shape[0] == 0:
            return np.ones(pts.shape[0])
        if self._bounded:
            self._reach_for(pts)
            if self.kept == 0:
                return np.ones(pts.shape[0])
        stencils = self._extend(pts)
        atlas = self.atlas()
        if self.cfg.refine_contrast is None:
            return dgsm_sample.lookup_point(atlas, self.light, pts)
        vals, _ = dgsm_sample.lookup_point_refined(atlas, self.light, pts, self.occ, self.dir_dep,
                                                   self.cfg.refine_contrast, stencils=stencils)
        return vals


#: lattice pitch (metres) of :class:`StaticSceneSunAtlas` in the main job: on the seal shot's statue
#: casting on the biker, 6 mm pixels gave the per-frame atlas's error of 3 mm pixels (mean 0.0008 vs
#: 0.0007 against the exact transmittance), and the refinement redoes the sharp edges exactly
SUN_ATLAS_PITCH = 0.005


class StaticSceneSunAtlas:
    """Lazily filled shot-long DGSM of the static ``occluders`` for a directional light travelling
    along ``direction`` (3,): a fixed lattice of square pixels of side ``pitch`` (scene units) on
    the plane through the world origin orthogonal to the light, and ``K`` depth bins (None:
    ``2 * cfg.K``) spanning the occluders' ``k_sigma`` depth range along it (first bin centre at
    its start, last at its end: receivers deeper read the last bin, which holds every occluder on
    the ray). A voxel column is computed the first time a lookup's bilinear stencil needs it
    (``numba_kernels.dgsm_directional.lattice_columns``: its values do not depend on the order the
    columns come in, so a farm chunk that starts later computes the same ones) and kept for the
    shot; a lookup whose eight voxels differ by more than ``cfg.refine_contrast`` is redone
    exactly on the point's own ray (``transmittance_points``), which also covers points just above
    the ground the coarse bins cannot resolve (an avatar's feet)."""

    def __init__(self, occluders: GaussianSet, direction, cfg: DGSMConfig, pitch: float, K: int | None = None):
        from numba_kernels import dgsm_directional as dd

        self.cfg = cfg
        self.basis = dd.light_basis(direction)
        self.direction = self.basis[2].copy()
        self.K = int(K or 2 * cfg.K)
        self.h = float(pitch)
        self.count = occluders.count
        self.occ, self.dir_dep, self.cov6 = prepare_occluders(occluders, cfg)
        self.c = np.zeros(3)
        if self.count:
            depth = dd.dot_rows(occluders.positions, self.direction)
            reach = cfg.k_sigma * occluders.scales.astype(np.float64).max(axis=1)
            s0, s1 = float((depth - reach).min()), float((depth + reach).max())
        else:
            s0, s1 = 0.0, 1.0
        self.ds = max(s1 - s0, 1e-6) / (self.K - 1)
        self.tb = s0 - 0.5 * self.ds
        self._index = LatticeIndex()  # computed lattice pixels (i, j) -> their rows in the store
        self._pixels = np.zeros((0, 2), np.int64)  # (i, j) of the stored columns, in row order
        self._columns = _ColumnStore(self.K)
        self.pairs = 0
        # each occluder's lattice coordinates and culling reach, in pixels (for _near)
        if self.count:
            mu = self.occ[:, :3] - self.c
            self._u = dd.dot_rows(mu, self.basis[0]) / self.h - 0.5
            self._v = dd.dot_rows(mu, self.basis[1]) / self.h - 0.5
            self._r = cfg.k_sigma / np.min(self.occ[:, 12:15], axis=1) / self.h + 1.0

    @property
    def computed_pixels(self) -> int:
        """Number of lattice pixels (voxel columns) computed so far."""
        return int(self._columns.size)

    @property
    def keys(self) -> np.ndarray:
        """(computed_pixels,) int64 sorted keys (:meth:`_key`) of the computed lattice pixels."""
        return np.sort(self._key(self._pixels))

    @property
    def values(self) -> np.ndarray:
        """(computed_pixels, K) float32 voxel columns in the order of :attr:`keys`."""
        return self._columns.values[np.argsort(self._key(self._pixels), kind="stable")]

    @staticmethod
    def _key(ij: np.ndarray) -> np.ndarray:
        return (ij[:, 0] + (1 << 31)) * (1 << 32) + (ij[:, 1] + (1 << 31))

    def _near(self, ij: np.ndarray, cell: int = 32) -> np.ndarray:
        """Indices of the occluders whose culling circle can reach a lattice pixel of ``ij`` (M, 2):
        conservative, by the occupied ``cell`` x ``cell``-pixel cells (a summed-area table)."""
        ci, cj = ij[:, 0] // cell, ij[:, 1] // cell
        i0, j0 = int(ci.min()), int(cj.min())
        grid = np.zeros((int(ci.max()) - i0 + 1, int(cj.max()) - j0 + 1), np.int64)
        grid[ci - i0, cj - j0] = 1
        sat = np.zeros((grid.shape[0] + 1, grid.shape[1] + 1), np.int64)
        sat[1:, 1:] = grid.cumsum(0).cumsum(1)
        a0 = np.clip(np.floor((self._u - self._r) / cell).astype(np.int64) - i0, 0, grid.shape[0])
        a1 = np.clip(np.floor((self._u + self._r) / cell).astype(np.int64) - i0 + 1, 0, grid.shape[0])
        b0 = np.clip(np.floor((self._v - self._r) / cell).astype(np.int64) - j0, 0, grid.shape[1])
        b1 = np.clip(np.floor((self._v + self._r) / cell).astype(np.int64) - j0 + 1, 0, grid.shape[1])
        hits = sat[a1, b1] - sat[a0, b1] - sat[a1, b0] + sat[a0, b0]
        return np.flatnonzero(hits > 0)

    def _rows(self, ij: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(M,) rows in the column store of the lattice pixels ``ij`` (M, 2), computing the voxel
        columns that are not there yet (each distinct pixel once). ``rows``: their rows as the map
        gave them (-1 where missing; filled in place)."""
        from numba_kernels import dgsm_directional as dd

        miss = np.flatnonzero(rows < 0)
        if miss.size == 0:
            return rows
        _, first, inverse = np.unique(self._key(ij[miss]), return_index=True, return_inverse=True)
        new = ij[miss[first]]
        near = self._near(new)
        vals, pairs = dd.lattice_columns(self.basis, self.occ[near], self.dir_dep, self.cov6[near], self.c, self.h,
                                         new, self.tb, self.ds, self.K, self.cfg.k_sigma, self.cfg.bin_skip)
        self.pairs += pairs
        start = self._columns.append(vals)
        self._index.insert(new, np.arange(start, start + new.shape[0], dtype=np.int64))
        self._pixels = np.concatenate([self._pixels, new])
        rows[miss] = start + inverse.reshape(-1)
        return rows

    def transmittance(self, points) -> np.ndarray:
        """(M,) float64 transmittance at ``points`` (M, 3) (scene units, world space)."""
        from numba_kernels import dgsm_directional as dd

        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if self.count == 0 or pts.shape[0] == 0:
            return np.ones(pts.shape[0])
        index = self._index
        ij0, w, k0, rows = lattice_stencils(pts, self.c, self.basis, self.h, self.tb, self.ds, self.K,
                                            *index.arrays())
        if (rows < 0).any():  # columns no lookup needed before: computed now, in the corners' order
            ij = np.concatenate([ij0 + np.array(off) for off in CORNERS])
            rows = self._rows(ij, rows.reshape(-1)).reshape(4, -1)
        out, spread = lattice_interpolate(rows, self._columns.values, k0, w)
        if self.cfg.refine_contrast is not None:
            redo = np.flatnonzero(spread > self.cfg.refine_contrast)
            if redo.size:
                near = self._near(ij0[redo])
                out[redo] = dd.transmittance_points(self.direction, self.occ[near], self.dir_dep, self.cov6[near],
                                                    pts[redo], self.cfg.k_sigma)[0]
        return out
