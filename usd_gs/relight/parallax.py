"""Parallax-corrected SH probes: one cube render, probes at several points of an avatar.

The paper (3.4) fits one SH probe at the avatar's centre and relights every Gaussian with it.
Light arriving at a foot differs from light at the chest when surfaces are near (the floor,
furniture, a lamp a few metres away): the measured error of that one-probe assumption on the
known-light ground truth (``usd_gs.evaluation.relight_groundtruth``) is about as large as all others.
This module reuses the centre's cube render with its depth: every texel ``t`` is a patch of
scene surface at ``P_t = c + r_t d_t`` (``r_t`` the distance along the texel's ray) with
radiance ``L_t`` and solid angle ``w_t`` (times its coverage) seen from the centre ``c``.
Seen from another point ``x`` the same patch lies in direction ``d' = (P_t - x) / |P_t - x|``
and subtends

    w'_t = w_t (r_t / |P_t - x|)^2 * cos'_t / cos_t,

with ``cos_t`` and ``cos'_t`` the cosines between the patch normal (from the differences of
neighbouring texel positions within the face, one-sided at the edge of what was drawn,
oriented toward ``c``; facing ``c`` where a texel has no drawn neighbour) and the two viewing directions, regularised as
``(max(cos', 0) + 0.05) / (cos + 0.05)`` (at most 20): exactly 1 at ``c``, bounded where the
depth-gradient normal of a grazing or silhouette texel is unreliable.
Distant texels (the sky, a dome) keep their direction and solid angle. The probe at ``x`` is
the SH projection ``a_lm = sum_t L_t Y_lm(d'_t) w'_t`` (real SH, the RH basis of
``numba_kernels.sh_real``), which is exactly the quadrature that the irradiance
``sum_t L_t max(0, n.d'_t) w'_t`` needs. Occlusion between texels as seen from ``x`` (a prop
moved in front of sky the centre saw beside it) is tested with a z-buffer of the reprojected
texels (``numba_kernels.probe_reprojection``). What this does not model: surfaces hidden from ``c`` but
visible from ``x`` (they are missing).

The probe points are the centres of ``k`` clusters of the avatar's Gaussians (k-means on the
rest pose, labels kept for the shot, each frame's centres are the labels' current means), and
a Gaussian's transfer factor is the blend ``sum_k W_k s_k(n)`` with Gaussian weights of its
distance to the centres (``sigma`` = half the median spacing between neighbouring centres).
Labels and weights are computed once per shot on the prim's first frame (:class:`ProbeBlend`)
and follow the prim: each frame's probe points are the labels' current means.

Shapes: positions (N, 3) metres, world space (any up axis); cube faces in the layout of
``numba_kernels.cubemap_dirs`` (OpenGL order +X, -X, +Y, -Y, +Z, -Z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OCCLUSION_SIZE = 32
"""Face size of the occlusion test's z-buffer (:func:`reprojected_probes`; the default probe
render's size, ``ProcessOptions.probe_size``). The choice and its measured effect on the
known-light ground truth: docs/design.md, "Parallax probes"."""
_DISC = 0.75
"""Disc radius per texel: ``_DISC sqrt(solid angle)`` (the equal-area disc, 0.56, leaves the
corners of a square texel lattice open: 30 % of the sky behind a panel stayed visible)."""
_MIN_SPLAT_COS = 0.3
"""Texels seen from the new point at a grazing angle (``cos < _MIN_SPLAT_COS``: a floor's far
part seen from a foot) hide nothing: their footprint is a sliver, not a disc, and as discs they
hid the dawn sun just above the floor's far edge (docs/design.md, "Parallax probes")."""
_SAME_LAYER = 0.5
"""A disc hides a texel only if it is nearer than ``dist / (1 + _SAME_LAYER)``: neighbouring
texels of one surface never hide each other."""
_MIN_COS = 0.05
_MAX_RATIO = 20.0


@dataclass
class CubeTexels:
    """The centre's cube render as surface patches, flattened over (6, S, S): ``radiance``
    (T, 3) un-premultiplied linear RGB, ``dirs`` (T, 3) unit directions from the centre,
    ``dist`` (T,) metres along the ray (0 where nothing was drawn), ``weight`` (T,) solid angle
    times coverage (sr), ``points`` (T, 3) patch positions, ``cos_c`` (T,) |cos| between the
    patch normal and the ray, ``normals`` (T, 3) patch normals facing the centre, ``centre`` (3,)."""

    radiance: np.ndarray
    dirs: np.ndarray
    dist: np.ndarray
    weight: np.ndarray
    points: np.ndarray
    cos_c: np.ndarray
    normals: np.ndarray
    centre: np.ndarray


def cube_texels(rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, centre) -> CubeTexels:
    """Surface patches of a cube render (``usd_gs.render.rasterize.render_cube_faces`` outputs: rgb
    (6, S, S, 3) premultiplied, alpha (6, S, S), depth (6, S, S) view depth along each face's
    axis) seen from ``centre`` (3,)."""
    from numba_kernels.cubemap_dirs import FACE_FRAMES, cube_face_directions, cube_face_solid_angles

    size = rgb.shape[1]
    c = np.asarray(centre, np.float64).reshape(3)
    a = np.clip(np.asarray(alpha, np.float64), 0.0, 1.0)
    lum = np.where(a[..., None] > 1e-6, np.asarray(rgb, np.float64) / np.maximum(a, 1e-6)[..., None], 0.0)
    d = cube_face_directions(size)
    r = np.asarray(depth, np.float64) / np.einsum("fijc,fc->fij", d, FACE_FRAMES[:, 0])
    pts = c + r[..., None] * d
    gi, oki = _surface_difference(pts, r, axis=1)
    gj, okj = _surface_difference(pts, r, axis=2)
    nrm = np.cross(gi, gj)
    nlen = np.linalg.norm(nrm, axis=-1, keepdims=True)
    good = oki & okj & (nlen[..., 0] > 0)
    nrm = np.where(good[..., None], nrm / np.where(nlen > 0, nlen, 1.0), -d)  # no reliable gradient: faces c
    cos = np.einsum("fijc,fijc->fij", nrm, d)
    nrm *= np.where(cos > 0, -1.0, 1.0)[..., None]  # face the centre
    w = cube_face_solid_angles(size) * a * (r > 0)
    return CubeTexels(lum.reshape(-1, 3), d.reshape(-1, 3), r.reshape(-1), w.reshape(-1), pts.reshape(-1, 3),
                      np.abs(cos).reshape(-1), nrm.reshape(-1, 3), c)


def _surface_difference(pts: np.ndarray, r: np.ndarray, axis: int):
    """Difference of texel positions (6, S, S, 3) along a face ``axis`` (1: rows, 2: columns):
    central where both neighbours were drawn, one-sided toward the drawn one at the edge of
    what was drawn (measured on the known-light ground truth: preferring the shorter one-sided
    difference at depth edges loses 0.5-1 dB). Returns ``(difference, ok)``, ``ok`` False
    where no neighbour was drawn."""
    n = r.shape[axis]
    idx = np.arange(n)
    shape = [1, 1, 1]
    shape[axis] = n

    def side(step):
        j = np.clip(idx + step, 0, n - 1)
        inside = ((idx + step >= 0) & (idx + step < n)).reshape(shape)
        diff = (np.take(pts, j, axis=axis) - pts) * step
        return diff, inside & (r > 0) & (np.take(r, j, axis=axis) > 0)

    df, okf = side(1)
    db, okb = side(-1)
    one = np.where(okf[..., None], df, db)
    return np.where((okf & okb)[..., None], 0.5 * (df + db), one), okf | okb


def reprojected_probes(tex: CubeTexels, points, degree: int,
                       occlusion_size: int | None = OCCLUSION_SIZE) -> np.ndarray:
    """(K, (degree+1)^2, 3) float64 RH SH radiance probes at ``points`` (K, 3) (module doc;
    ``numba_kernels.probe_reprojection``, the points in parallel). A point at the centre gives
    the plain projection of the render. ``occlusion_size``: face size of the z-buffer of the
    occlusion test at each point (None: none, every texel counts)."""
    from numba_kernels.probe_reprojection import reproject_probes

    live = tex.weight > 0
    return reproject_probes(points, tex.points[live], tex.normals[live], tex.dirs[live], tex.dist[live],
                            tex.weight[live], tex.cos_c[live], tex.radiance[live], int(degree),
                            0 if occlusion_size is None else int(occlusion_size), _MIN_COS, _MAX_RATIO, _DISC,
                            _MIN_SPLAT_COS, _SAME_LAYER)


def probe_clusters(positions: np.ndarray, k: int, iterations: int = 12, sample: int = 4096,
                   seed: int = 0) -> np.ndarray:
    """(N,) int64 cluster label of each Gaussian: deterministic k-means (``k`` centres; farthest
    point initialisation on a sample of at most ``sample`` Gaussians, Lloyd iterations on it),
    then nearest centre for all. ``k`` is capped at the number of Gaussians."""
    x = np.asarray(positions, np.float64).reshape(-1, 3)
    n = x.shape[0]
    k = int(max(1, min(k, n)))
    if k == 1 or n == 0:
        return np.zeros(n, np.int64)
    rng = np.random.default_rng(seed)
    s = x[np.sort(rng.choice(n, size=min(n, sample), replace=False))]
    cen = [s[np.argmax(np.linalg.norm(s - s.mean(axis=0), axis=1))]]
    d2 = np.sum((s - cen[0]) ** 2, axis=1)
    for _ in range(1, k):
        cen.append(s[np.argmax(d2)])
        d2 = np.minimum(d2, np.sum((s - cen[-1]) ** 2, axis=1))
    cen = np.array(cen)
    for _ in range(iterations):
        lab = np.argmin(np.sum((s[:, None, :] - cen[None]) ** 2, axis=2), axis=1)
        for j in range(k):
            if np.any(lab == j):
                cen[j] = s[lab == j].mean(axis=0)
    return nearest_centre(x, cen)


def nearest_centre(positions: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(N,) int64 index of the nearest of ``centres`` (K, 3) for each position (N, 3)."""
    x = np.asarray(positions, np.float64)
    best = np.zeros(x.shape[0], np.int64)
    bd = np.full(x.shape[0], np.inf)
    for j, c in enumerate(np.asarray(centres, np.float64)):
        d = np.sum((x - c) ** 2, axis=1)
        closer = d < bd
        best[closer], bd[closer] = j, d[closer]
    return best


def cluster_centres(positions: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """(K, 3) mean position of each label's Gaussians (this frame's probe points)."""
    x = np.asarray(positions, np.float64)
    cnt = np.maximum(np.bincount(labels, minlength=k), 1)
    return np.stack([np.bincount(labels, x[:, c], minlength=k) for c in range(3)], axis=1) / cnt[:, None]


def blend_weights(positions: np.ndarray, centres: np.ndarray, cutoff: float = 3e-2) -> np.ndarray:
    """(N, K) float64 weights (rows sum to 1): Gaussian in the distance to each centre with
    sigma = half the median distance from a centre to its nearest other centre; weights below
    ``cutoff`` of a row's largest are dropped (so each Gaussian uses only nearby probes)."""
    x = np.asarray(positions, np.float64)
    c = np.asarray(centres, np.float64)
    if c.shape[0] == 1:
        return np.ones((x.shape[0], 1))
    cc = np.sqrt(np.sum((c[:, None] - c[None]) ** 2, axis=2))
    np.fill_diagonal(cc, np.inf)
    sigma = max(0.5 * float(np.median(cc.min(axis=1))), 1e-6)
    d2 = np.maximum(np.einsum("ij,ij->i", x, x)[:, None] - 2.0 * (x @ c.T) + np.einsum("ij,ij->i", c, c)[None], 0.0)
    logw = -(d2 - d2.min(axis=1, keepdims=True)) / (2.0 * sigma * sigma)
    w = np.exp(logw)
    w[w < cutoff] = 0.0
    return w / w.sum(axis=1, keepdims=True)


@dataclass
class ProbeBlend:
    """Probe points of one prim for a shot: ``labels`` (N,) cluster per Gaussian, ``k`` probes and
    ``weights`` (N, K) float32, :func:`blend_weights` on the first frame (rows sum to 1)."""

    labels: np.ndarray
    k: int
    weights: np.ndarray

    @classmethod
    def build(cls, positions: np.ndarray, k: int) -> ProbeBlend:
        labels = probe_clusters(positions, k)
        k = int(labels.max()) + 1 if labels.size else 1
        w = blend_weights(positions, cluster_centres(positions, labels, k)) if labels.size else np.ones((0, 1))
        return cls(labels, k, np.ascontiguousarray(w, dtype=np.float32))

    @classmethod
    def from_arrays(cls, labels: np.ndarray, weights: np.ndarray) -> ProbeBlend:
        """The blend that :meth:`build` returned as ``labels`` and ``weights`` (a stored copy)."""
        return cls(labels, int(weights.shape[1]), weights)

    def centres(self, positions: np.ndarray) -> np.ndarray:
        """(K, 3) this frame's probe points (the labels' mean positions)."""
        return cluster_centres(positions, self.labels, self.k)
