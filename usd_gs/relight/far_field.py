"""Probe renders that draw the far static scene once per place, not once per frame.

A relit prim's probe (``usd_gs.relight.avatar.probe_transfer``) is a cube render of everything
but the prim. Static scene Gaussians far from the probe barely change between frames (their
directions move by ``offset / distance``), yet a render per frame draws every one of them. A
:class:`FarField` (one per relit prim and shot) splits the render in two:

- **far layer**: the static Gaussians (the first ``static_count`` of the shot buffer) whose
  centres lie at least ``radius`` from an anchor ``a`` (the probe centre snapped to a grid of
  pitch ``tolerance * radius``), rendered from ``a`` and kept while the probe centre stays in that
  grid cell (a new cell renders a new layer; the last :data:`KEEP` layers are kept);
- **near render**: everything else the probe draws (the dynamic prims, the static Gaussians
  within ``radius`` of ``a``), from the probe centre itself, every frame;
- the two composited, the near layer over the far one (premultiplied colour, alpha, expected
  depth: ``usd_gs.render.rasterize.render_cube_faces``): ``rgb = rgb_n + (1 - a_n) rgb_f``,
  ``alpha = 1 - (1 - a_n)(1 - a_f)``, depth alpha-weighted.

Approximations (measured against the full render in tests/test_far_field.py and
docs/benchmarks.md): the far layer is seen from the anchor, at most ``sqrt(3)/2 * tolerance *
radius`` from the centre, so a far Gaussian's direction is off by at most about
``0.87 * tolerance`` radians (2.5 deg at the default 0.05: below a 32-texel face's 2.8 deg texel);
Gaussians within ``tolerance * radius`` of the boundary sphere may composite in the wrong order;
with supersampling the layers are composited after the box filter. The anchor depends only on the
frame's probe centre, so a farm chunk renders what the whole-shot run renders. Where no static
Gaussian lies beyond ``radius`` the result is the full render's, bit for bit.
"""

from __future__ import annotations

import numpy as np

from usd_gs.relight.probe import PROBE_DILATION, PROBE_SUPERSAMPLE, render_probe_faces

#: far layers kept per prim (a prim that moves back and forth between two cells reuses both)
KEEP = 2


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


class FarField:
    """The far-layer cache of one relit prim (module docstring). ``radius`` and ``tolerance`` in the
    stage's units and as a fraction of ``radius``; ``static_count``: how many leading Gaussians of
    the buffers given to :meth:`render` are static (the same, at the same index, every frame).
    Not thread-safe: one prim's probe task uses it at a time."""

    def __init__(self, radius: float, tolerance: float, static_count: int):
        if not (radius > 0.0 and 0.0 < tolerance <= 0.5):
            raise ValueError(f"far field: radius {radius} must be > 0 and tolerance {tolerance} in (0, 0.5]")
        self.radius = float(radius)
        self.pitch = float(tolerance) * self.radius
        self.static_count = int(static_count)
        self._layers: list = []  # [(key, far mask over the static part or None when none is far, faces)]
        self.renders = 0  # far layers rendered (diagnostics, tests)

    def anchor(self, centre) -> np.ndarray:
        """The grid point (float64 (3,)) the far layer of a probe at ``centre`` is rendered from."""
        return np.round(np.asarray(centre, np.float64) / self.pitch) * self.pitch

    def render(self, everything, centre, size: int, mask: np.ndarray, dilation: float = PROBE_DILATION,
               supersample: int = PROBE_SUPERSAMPLE) -> tuple:
        """``render_probe_faces(everything, centre, size, mask, dilation, supersample)``, with the
        static Gaussians far from the anchor taken from the cached far layer."""
        mask = np.asarray(mask, bool)
        s = self.static_count
        a = self.anchor(centre)
        key = (tuple(a), int(size), float(dilation), int(supersample), everything.count,
               hash(mask[:s].tobytes()))
        hit = next((layer for layer in self._layers if layer[0] == key), None)
        if hit is None:
            d2 = np.sum((everything.positions[:s].astype(np.float64) - a) ** 2, axis=1)
            beyond = d2 >= self.radius * self.radius
            far = np.flatnonzero(beyond & mask[:s])
            faces = near = None
            if far.size:
                faces = render_probe_faces(everything, a, size, None, dilation, supersample, order=far)
                near = np.flatnonzero(~beyond & mask[:s])  # the static Gaussians the near pass draws
                self.renders += 1
            hit = (key, near, faces)
            self._layers = [hit, *self._layers][:KEEP]
        _, near, faces = hit
        if faces is None:  # nothing far: the plain render
            return render_probe_faces(everything, centre, size, mask, dilation, supersample)
        order = np.concatenate([near, s + np.flatnonzero(mask[s:])])  # (increasing: static first)
        return composite_faces(render_probe_faces(everything, centre, size, None, dilation, supersample, order=order),
                               faces)
