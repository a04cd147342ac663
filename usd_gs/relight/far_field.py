"""Probe renders that draw the far static scene once per place, not once per frame.

A relit prim's probe (``usd_gs.relight.avatar.probe_transfer``) is a cube render of everything
but the prim. Static scene Gaussians far from the probe barely change between frames (their
directions move by ``offset / distance``), yet a render per frame draws every one of them. A
:class:`FarField` (one per relit prim and shot) splits the render in two:

- **far layer**: the static Gaussians (the first ``static_count`` of the shot buffer) whose
  centres lie farther than ``radius`` from an anchor ``a`` (the probe centre snapped to a grid of
  pitch ``tolerance * radius * 2^L``), rendered from ``a`` and kept while the probe centre stays
  in that grid cell (a new cell renders a new layer; the last :data:`KEEP` layers per prim are
  kept). The level ``L`` is the coarsest of :data:`LEVELS` whose anchor has no static Gaussian
  between ``radius`` and ``radius * 2^L``: the far layer's nearest Gaussian is then ``2^L`` times
  farther too, so the direction bound below holds at every level, and a scene whose far part is
  far away gets larger cells (fewer layers rendered as the prims walk). Layers are shared by the
  relit prims of a shot (:class:`FarLayers`): the static part and its mask are the same for all;
- **near render**: everything else the probe draws (the dynamic prims, the static Gaussians
  within ``radius`` of ``a``), from the probe centre itself, every frame;
- the far layer moved from the anchor to the probe centre by its depth
  (``numba_kernels.cube_warp.warp_layer``: each texel of the centre's cube takes the far point the
  anchor saw in that direction), then the two composited, the near layer over the far one
  (premultiplied colour, alpha, expected depth: ``usd_gs.render.rasterize.render_cube_faces``):
  ``rgb = rgb_n + (1 - a_n) rgb_f``, ``alpha = 1 - (1 - a_n)(1 - a_f)``, depth alpha-weighted.

Approximations (measured against the full render in tests/test_far_field.py,
tests/test_cube_warp.py and docs/benchmarks.md): the far layer is rendered from the anchor, at
most ``sqrt(3)/2 * tolerance * radius * 2^L`` from the centre, and its Gaussians are at least
``radius * 2^L`` from it. Seen from the anchor unmoved, a far Gaussian's direction would be off by
up to about ``0.87 * tolerance`` radians (2.5 deg at the default 0.05, under a 32-texel face's
2.8 deg texel); the warp puts far content at the distance its texel holds in its true direction,
so what remains is that bound times the spread of a texel's distances (``r1 (1/r1 - 1/r2)`` for
Gaussians at ``r1 < r2`` in one texel: 0 for a sky dome at one distance), plus the warp's bilinear
resampling (what either does to the relit colour: docs/benchmarks.md, "Probe far field"; a
bright far light low behind near geometry, such as a low sun, is where it shows). Gaussians
within ``tolerance * radius`` of the boundary sphere may composite in the wrong order; with
supersampling the layers are composited after the box filter. The anchor depends only on the
frame's probe centre and the static scene (not on what was rendered before), so a farm chunk
renders what the whole-shot run renders. Where no static Gaussian lies beyond ``radius`` the
result is the full render's, bit for bit.

Where several probes miss their layers at one frame (a shot's first frame), :meth:`FarLayers.batch`
plans them and a :class:`FarBatch` draws them in one rasteriser pass (one cull sweep over the far
Gaussians for every anchor's cube; each layer bit for bit its own render).
"""

from __future__ import annotations

import hashlib
import threading

import numpy as np

from numba_kernels.cube_warp import warp_layer
from usd_gs.point_blocks import PointBlocks, within_ball
from usd_gs.relight.probe import PROBE_DILATION, PROBE_SUPERSAMPLE, render_probe_cubes, render_probe_faces

#: far layers kept per relit prim (a prim that moves back and forth between two cells reuses both)
KEEP = 2
#: grid levels tried for a far layer (module docstring): pitch and clearance double per level
LEVELS = 3


def composite_faces(near: tuple, far: tuple) -> tuple:
    """``(rgb, alpha, depth)`` of the cube render ``near`` drawn over ``far`` (each as
    ``render_probe_faces`` returns: premultiplied rgb (6,S,S,3), alpha (6,S,S), alpha-weighted
    expected depth (6,S,S)), float32."""
    rgb_n, a_n, d_n = (np.asarray(x, np.float64) for x in near)
    rgb_f, a_f, d_f = (np.asarray(x, np.float64) for x in far)
    behind = 1.0 - a_n
    rgb = rgb_n + behind[..., None] * rgb_f
    alpha = 1.0 - behind * (1.0 - a_f)
    w = a_n * d_n + behind * a_f * d_f
    depth = np.where(alpha > 0.0, w / np.where(alpha > 0.0, alpha, 1.0), 0.0)
    return rgb.astype(np.float32), alpha.astype(np.float32), depth.astype(np.float32)


def _digest(mask: np.ndarray) -> int:
    """A 64-bit digest of a bool mask that is the same in every process (a far layer's key)."""
    return int.from_bytes(hashlib.blake2b(np.packbits(mask).tobytes(), digest_size=8).digest(), "little")


class FarLayers:
    """The far layers of one shot's static part, shared by its relit prims' :class:`FarField`
    caches (thread-safe: the prims' probe tasks run side by side): layers by key, the last
    ``keep`` used, and each anchor's clearance test (:meth:`clear`).

    ``backing``: None, or a store that outlives the process (a farm run's shot cache,
    ``usd_gs.pipeline.shot_cache.ShotCache``: ``get(*key)`` -> tuple of arrays or None,
    ``put(key, arrays)``): a layer missing here is looked up there before it is rendered, and a
    rendered layer with a far part is stored there (keys of str, int and float only).

    ``blocks``: None, or the static part's ``usd_gs.point_blocks.PointBlocks``: the ball tests over
    the static Gaussians (:meth:`within`, :meth:`clear`) then decide whole blocks that lie inside or
    outside a ball at once (the same values; a far scene of many bricks is not tested point by point)."""

    def __init__(self, keep: int = KEEP, backing=None, blocks: PointBlocks | None = None):
        self.keep = max(1, int(keep))
        self.backing = backing
        self.blocks = blocks
        self._lock = threading.Lock()
        self._layers: list = []  # [(key, (near indices or None, faces or None))], most recent first
        self._clear: dict = {}
        self._batches: dict = {}  # key -> the FarBatch that renders it (until it has run)

    def get(self, key):
        with self._lock:
            for i, (k, value) in enumerate(self._layers):
                if k == key:
                    self._layers.insert(0, self._layers.pop(i))
                    return value
        got = self.backing.get("far layer", *key) if self.backing is not None else None
        if got is None:
            return None
        value = (got[0], tuple(got[1:]))
        self.put(key, value, keep_only=True)
        return value

    def put(self, key, value, keep_only: bool = False) -> None:
        """Keep layer ``value`` (``(near indices, faces)``) under ``key``; also in the backing
        store unless ``keep_only`` or the layer has no far part."""
        with self._lock:
            self._layers = [(key, value), *[kv for kv in self._layers if kv[0] != key]][:self.keep]
        if self.backing is not None and not keep_only and value[1] is not None:
            self.backing.put(("far layer", *key), (value[0], *value[1]))

    def has_anchor(self, anchor) -> bool:
        """True when a layer kept here was rendered from ``anchor`` (3,) (a hint: its key may still
        differ in the mask or the render's size)."""
        a = tuple(float(v) for v in anchor)
        with self._lock:
            return any(k[:3] == a for k, _ in self._layers)

    def batch(self, requests) -> FarBatch | None:
        """The far layers that two or more probe renders about to run will miss, as one
        :class:`FarBatch` (its :meth:`FarBatch.run` is the task that renders them; until it has run,
        :meth:`FarField.render` of those probes draws its near part, then runs or waits for it), or
        None where fewer than two would be rendered. ``requests``: ``[(far field, everything,
        centre, size, mask, dilation, supersample)]``, the arguments of the coming
        :meth:`FarField.render` calls (whose far fields share this store)."""
        due = []
        for far, everything, centre, *rest in requests:
            _, a = far.level_anchor(everything.positions[:far.static_count], centre)
            if not self.has_anchor(a):
                due.append((far, everything, a, *rest))
        if len(due) < 2:
            return None
        plans = {}
        for far, everything, a, size, mask, dilation, supersample in due:
            key = far.layer_key(everything, a, size, mask, dilation, supersample)
            if key not in plans and self.get(key) is None and self.due(key) is None:
                plans[key] = (far, everything, a, int(size), float(dilation), int(supersample), np.asarray(mask, bool))
        if len(plans) < 2:
            return None
        batch = FarBatch(self, plans)
        with self._lock:
            for key in plans:
                self._batches[key] = batch
        return batch

    def due(self, key) -> FarBatch | None:
        """The :class:`FarBatch` that renders layer ``key`` and has not run yet, or None."""
        with self._lock:
            return self._batches.get(key)

    def _render_plans(self, batch: FarBatch) -> dict:
        """``{key: (near indices or None, faces or None)}`` of every layer ``batch`` plans (kept here
        too): layers with the same far Gaussians and render settings drawn in one pass
        (``render_probe_cubes``: each bit for bit its own render)."""
        groups: list = []  # [far indices, everything, settings, [(key, far field, anchor, near indices)]]
        seen: dict = {}  # (id(everything), radius) -> the splits made (FarField.split)
        for key, (far, everything, a, size, dilation, supersample, mask) in batch.plans.items():
            near, beyond = far.split(everything, a, mask, seen.setdefault((id(everything), far.radius), []))
            for g in groups:
                if g[1] is everything and g[2] == (size, dilation, supersample) and (
                        g[0] is beyond or np.array_equal(g[0], beyond)):
                    g[3].append((key, far, a, near))
                    break
            else:
                groups.append([beyond, everything, (size, dilation, supersample), [(key, far, a, near)]])
        out = {}
        for beyond, everything, (size, dilation, supersample), members in groups:
            if not beyond.size:
                out.update((key, (None, None)) for key, _, _, _ in members)
                continue
            cubes = render_probe_cubes(everything, [a for _, _, a, _ in members], size, None, dilation, supersample,
                                       order=beyond, blocks=self.cull_bounds(everything))
            for (key, far, _, near), faces in zip(members, cubes, strict=True):
                out[key] = (near, faces)
                far.renders += 1
        for key, value in out.items():
            self.put(key, value)
        return out

    def _ran(self, batch: FarBatch) -> None:
        with self._lock:
            for key in batch.plans:
                if self._batches.get(key) is batch:
                    del self._batches[key]

    def cull_bounds(self, everything) -> tuple | None:
        """The static part's blocks as the rasteriser's cull bounds for renders of ``everything`` (the
        shot buffer, the static part first: ``PointBlocks.cull_bounds``), or None without blocks."""
        return None if self.blocks is None else self.blocks.cull_bounds(everything.positions, everything.scales)

    def within(self, static_positions: np.ndarray, centre, radius: float) -> np.ndarray:
        """(N,) bool: the static Gaussian centres ``static_positions`` (N, 3) (the static part, the
        same every call) within ``radius`` of ``centre``: ``within_capsule``'s values, block by block
        where the store has ``blocks``."""
        return within_ball(self.blocks, static_positions, centre, radius)

    def clear(self, static_positions: np.ndarray, anchor: np.ndarray, inner: float, outer: float) -> bool:
        """True when no static Gaussian centre lies farther than ``inner`` and within ``outer`` of
        ``anchor`` (cached per anchor and radii)."""
        key = (tuple(anchor), float(inner), float(outer))
        with self._lock:
            hit = self._clear.get(key)
        if hit is None:
            hit = not bool(np.any(self.within(static_positions, anchor, outer)
                                  & ~self.within(static_positions, anchor, inner)))
            with self._lock:
                self._clear[key] = hit
        return hit


class FarBatch:
    """Far layers that several probes need at one frame (:meth:`FarLayers.batch`), rendered in one
    rasteriser pass by the first thread that calls :meth:`run` - the batch's own task, or a probe
    render that needs one of its layers first; a later caller waits until it is done (so a wait is
    only ever on a thread that is rendering). ``layers``: key -> ``(near indices, faces)`` once run;
    an error while rendering is raised to every caller."""

    def __init__(self, store: FarLayers, plans: dict):
        self.store = store
        self.plans = plans  # key -> (far field, everything, anchor, size, dilation, supersample, mask)
        self.layers: dict = {}
        self._lock = threading.Lock()
        self._ran = False
        self._error: BaseException | None = None

    def run(self) -> None:
        with self._lock:
            if not self._ran:
                self._ran = True
                try:
                    self.layers = self.store._render_plans(self)
                except BaseException as exc:
                    self._error = exc
                    raise
                finally:
                    self.store._ran(self)
            elif self._error is not None:
                raise self._error


class FarField:
    """The far-layer cache of one relit prim (module docstring). ``radius`` and ``tolerance`` in the
    stage's units and as a fraction of ``radius``; ``static_count``: how many leading Gaussians of
    the buffers given to :meth:`render` are static (the same, at the same index, every frame);
    ``shared``: the shot's :class:`FarLayers` for this static part (None: this prim's own).
    One prim's probe task uses it at a time."""

    def __init__(self, radius: float, tolerance: float, static_count: int, shared: FarLayers | None = None):
        if not (radius > 0.0 and 0.0 < tolerance <= 0.5):
            raise ValueError(f"far field: radius {radius} must be > 0 and tolerance {tolerance} in (0, 0.5]")
        self.radius = float(radius)
        self.pitch = float(tolerance) * self.radius
        self.static_count = int(static_count)
        self._store = shared if shared is not None else FarLayers(KEEP)
        self.renders = 0  # far layers this prim rendered (diagnostics, tests)
        self.level = 0  # the grid level of the last render

    @property
    def store(self) -> FarLayers:
        """The :class:`FarLayers` this prim's layers are kept in (shared by the shot's relit prims)."""
        return self._store

    def anchor(self, centre, level: int = 0) -> np.ndarray:
        """The grid point (float64 (3,)) the far layer of a probe at ``centre`` is rendered from,
        on the grid of ``level`` (pitch ``tolerance * radius * 2^level``)."""
        pitch = self.pitch * 2.0 ** int(level)
        return np.round(np.asarray(centre, np.float64) / pitch) * pitch

    def level_anchor(self, static_positions: np.ndarray, centre) -> tuple[int, np.ndarray]:
        """``(level, anchor)`` of the far layer for a probe at ``centre``: the coarsest level whose
        anchor has no static Gaussian between ``radius`` and ``radius * 2^level`` (module docstring)."""
        for level in range(LEVELS - 1, 0, -1):
            a = self.anchor(centre, level)
            if self._store.clear(static_positions, a, self.radius, self.radius * 2.0 ** level):
                return level, a
        return 0, self.anchor(centre, 0)

    def key(self, everything, centre, size: int, mask: np.ndarray, dilation: float = PROBE_DILATION,
            supersample: int = PROBE_SUPERSAMPLE) -> tuple:
        """``(level, anchor, key)`` of the far layer that :meth:`render` of these arguments draws."""
        level, a = self.level_anchor(everything.positions[:self.static_count], centre)
        return level, a, self.layer_key(everything, a, size, mask, dilation, supersample)

    def layer_key(self, everything, anchor, size: int, mask: np.ndarray, dilation: float = PROBE_DILATION,
                  supersample: int = PROBE_SUPERSAMPLE) -> tuple:
        """The key of the far layer rendered from ``anchor`` (a layer depends on its anchor, not on the
        level that chose it)."""
        return (*(float(v) for v in anchor), int(size), float(dilation), int(supersample), int(everything.count),
                _digest(np.asarray(mask, bool)[:self.static_count]))

    def split(self, everything, anchor, mask: np.ndarray, seen: list | None = None) -> tuple:
        """``(near, far)``: the increasing indices of the static Gaussians drawn (``mask``) within
        ``radius`` of ``anchor`` (None where none lies beyond) and beyond it. ``seen``: None, or a
        list of earlier splits of the same static part (kept there): where one had the same rows
        within the radius and the same drawn rows (nearby anchors of a batch, whose ball holds
        the same bricks), its arrays are returned, not made again."""
        s = self.static_count
        inside = self._store.within(everything.positions[:s], anchor, self.radius)
        drawn = np.asarray(mask, bool)[:s]
        for ins, dr, got in seen or ():
            if np.array_equal(ins, inside) and np.array_equal(dr, drawn):
                return got
        beyond = np.flatnonzero(drawn & ~inside)
        got = (np.flatnonzero(drawn & inside) if beyond.size else None), beyond
        if seen is not None:
            seen.append((inside, drawn, got))
        return got

    def render(self, everything, centre, size: int, mask: np.ndarray, dilation: float = PROBE_DILATION,
               supersample: int = PROBE_SUPERSAMPLE) -> tuple:
        """``render_probe_faces(everything, centre, size, mask, dilation, supersample)``, with the
        static Gaussians far from the anchor taken from the cached far layer, moved to ``centre``
        (a layer a :class:`FarBatch` renders: the near part drawn first, then the batch run or
        waited for)."""
        mask = np.asarray(mask, bool)
        blocks = self._store.cull_bounds(everything)
        self.level, a, key = self.key(everything, centre, size, mask, dilation, supersample)
        hit = self._store.get(key)
        if hit is None:
            batch = self._store.due(key)
            if batch is not None:
                near, _ = self.split(everything, a, mask)
                drawn = self._near_render(everything, centre, size, mask, near, dilation, supersample, blocks)
                batch.run()
                return self._composite(drawn, batch.layers[key][1], a, centre)
            near, beyond = self.split(everything, a, mask)
            faces = None
            if beyond.size:
                faces = render_probe_faces(everything, a, size, None, dilation, supersample, order=beyond,
                                           blocks=blocks)
                self.renders += 1
            hit = (near, faces)
            self._store.put(key, hit)
        near, faces = hit
        return self._composite(self._near_render(everything, centre, size, mask, near, dilation, supersample, blocks),
                               faces, a, centre)

    def _near_render(self, everything, centre, size, mask, near, dilation, supersample, blocks) -> tuple:
        """The probe's render of the static Gaussians ``near`` (None: every static one drawn) and the
        moving ones ``mask`` draws."""
        if near is None:  # nothing far: the plain render
            return render_probe_faces(everything, centre, size, mask, dilation, supersample, blocks=blocks)
        order = np.concatenate([near, self.static_count + np.flatnonzero(mask[self.static_count:])])
        return render_probe_faces(everything, centre, size, None, dilation, supersample, order=order, blocks=blocks)

    def _composite(self, near_faces: tuple, far_faces, anchor, centre) -> tuple:
        """``near_faces`` over the far layer ``far_faces`` rendered from ``anchor`` (None: nothing far)."""
        if far_faces is None:
            return near_faces
        return composite_faces(near_faces, warp_layer(*far_faces, anchor, centre, self.radius * 2.0 ** self.level))
