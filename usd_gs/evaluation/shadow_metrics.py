"""Shadow accuracy against a mesh pseudo ground truth (paper sec. 4.2): mattes and metrics.

Two shadow-only mattes of one camera view, both (H, W) float64 in [0, 1] (0 = lit, 1 = all
direct light blocked), on the visible scene surface of a receivers-only render:

- ``S_dagger(p)`` (:func:`mesh_shadow_matte`): the avatar's Gaussians replaced by its posed
  triangle mesh; from the world point of each pixel a shadow ray goes to each light
  (trimesh ray casting, embree backend); per-light binary visibility ``V_l`` is combined
  with the pipeline's per-light shares ``w_l`` (``usd_gs.shadows.shading.light_shares`` at the
  point), ``S_dagger = 1 - sum_l w_l V_l``.
- ``S(p)`` (:func:`render_strength_matte`): the scene Gaussians rendered with the splat
  rasteriser with their colour set to the shadow strength ``1 - T`` of each receiver (SH
  degree 0, DC term ``(s - 0.5) / C0`` so that ``0.5 + C0 DC = s``), normalised by the
  coverage: ``S = C / alpha`` (the alpha-weighted mean strength of the blended splats).

The surface point of a pixel is ``camera centre + ray * depth / cos``, where ``depth`` is
the rasteriser's expected view depth of the same receivers-only render and ``cos`` the
cosine between the pixel's ray and the view axis. Pixels with coverage below
:data:`MIN_COVERAGE` hold no surface and are left out of every metric.

Metrics (:func:`shadow_metrics`) in an avatar-centric ROI (pixels whose surface point lies
in the box ``|(x - c)_horizontal|_inf <= R`` around the avatar's alpha-weighted centroid
``c``, the same box as the paper's receiver ROI, without the height bounds), with
``M = [S > tau]``, ``M_dagger = [S_dagger > tau]``, ``tau = 0.1``,
``Omega_s = {p in ROI : M_dagger(p)}``:

- SAE = mean over ``Omega_s`` of ``|S - S_dagger|`` (None when ``Omega_s`` is empty);
- SM-IoU = ``|M & M_dagger| / |M | M_dagger|`` over the ROI (None when the union is empty);
- BF = F-measure of the two mask boundaries with a tolerance of ``tol`` px (default 2):
  boundary pixels are those of the mask that a 3x3 erosion removes (computed on the whole
  image, then counted inside the ROI, so the ROI's own edge is no boundary); precision is
  the fraction of ``M``'s boundary pixels whose Euclidean distance to ``M_dagger``'s
  boundary is at most ``tol`` (``scipy.ndimage.distance_transform_edt``), recall the
  converse, ``BF = 2 P R / (P + R)`` (0 when ``P + R = 0``; None when both boundaries are
  empty in the ROI).

Units: metres for world points, pixels for the boundary tolerance.
"""

from __future__ import annotations

import numpy as np

from usd_gs.errors import UserError
from usd_gs.render.rasterize import render
from usd_gs.shadows.shading import light_shares

TAU = 0.1
"""Shadow threshold of SM-IoU and BF (paper: 0.1)."""
BOUNDARY_TOL_PX = 2.0
"""Boundary F-measure tolerance in pixels (paper: 2)."""
MIN_COVERAGE = 0.5
"""Pixels of the receivers-only render with less coverage (alpha) hold no surface point."""
SH_C0 = 0.28209479177387814


# ----------------------------------------------------------------------------- metrics
def _scipy_ndimage():
    try:
        from scipy import ndimage
    except ImportError:  # pragma: no cover - scipy is a dependency of the eval extra
        raise UserError("shadow metrics need scipy (pip install 'usd-gs[eval]')") from None
    return ndimage


def mask_boundary(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of ``mask`` removed by a 3x3 binary erosion (the image border
    counts as inside, so a mask touching the border has no boundary there)."""
    nd = _scipy_ndimage()
    m = np.asarray(mask, bool)
    return m & ~nd.binary_erosion(m, structure=np.ones((3, 3), bool), border_value=1)


def boundary_f_measure(mask: np.ndarray, mask_ref: np.ndarray, roi: np.ndarray | None = None,
                       tol: float = BOUNDARY_TOL_PX) -> float | None:
    """Boundary F-measure of ``mask`` against ``mask_ref`` (module docstring); None when both
    boundaries are empty inside ``roi`` (default: the whole image)."""
    nd = _scipy_ndimage()
    b, br = mask_boundary(mask), mask_boundary(mask_ref)
    roi = np.ones(b.shape, bool) if roi is None else np.asarray(roi, bool)
    bi, bri = b & roi, br & roi
    if not bi.any() and not bri.any():
        return None
    if not bi.any() or not bri.any():
        return 0.0
    d_to_ref = nd.distance_transform_edt(~br)
    d_to_b = nd.distance_transform_edt(~b)
    precision = float((d_to_ref[bi] <= tol).mean())
    recall = float((d_to_b[bri] <= tol).mean())
    return 0.0 if precision + recall == 0 else 2.0 * precision * recall / (precision + recall)


def shadow_metrics(S: np.ndarray, S_ref: np.ndarray, roi: np.ndarray | None = None, tau: float = TAU,
                   tol: float = BOUNDARY_TOL_PX) -> dict:
    """SAE, SM-IoU and BF of the matte ``S`` against the reference ``S_ref`` (both (H, W),
    values in [0, 1]) inside the bool ``roi`` (module docstring). Returns a dict with
    ``sae``, ``iou``, ``bf`` (float or None), ``shadow_px`` (``|Omega_s|``), ``pred_px``
    (``|M|`` in the ROI) and ``roi_px``."""
    S = np.asarray(S, np.float64)
    S_ref = np.asarray(S_ref, np.float64)
    if S.shape != S_ref.shape or S.ndim != 2:
        raise ValueError(f"shadow_metrics: mattes must be 2D of equal shape, got {S.shape} and {S_ref.shape}")
    roi = np.ones(S.shape, bool) if roi is None else np.asarray(roi, bool)
    m, mr = S > tau, S_ref > tau
    omega = mr & roi
    union = (m | mr) & roi
    sae = float(np.abs(S - S_ref)[omega].mean()) if omega.any() else None
    iou = float((m & mr & roi).sum() / union.sum()) if union.any() else None
    return {"sae": sae, "iou": iou, "bf": boundary_f_measure(m, mr, roi, tol), "shadow_px": int(omega.sum()),
            "pred_px": int((m & roi).sum()), "roi_px": int(roi.sum())}


# ----------------------------------------------------------------------------- geometry of a view
def surface_points(camera, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) float64 world points of a view from its expected view depth (H, W) (scene
    units along the view axis, as :mod:`usd_gs.render.rasterize` returns it)."""
    dirs = camera.pixel_directions()
    fwd = -camera.rotation[:, 2]
    cos = dirs @ fwd
    return camera.position + dirs * (np.asarray(depth, np.float64) / cos)[..., None]


def roi_box_mask(points: np.ndarray, valid: np.ndarray, centre, radius: float, up_axis: str = "Y") -> np.ndarray:
    """(H, W) bool: valid pixels whose point is within ``radius`` of ``centre`` in the
    horizontal inf-norm (the axes other than ``up_axis``)."""
    h = (0, 2) if up_axis == "Y" else (0, 1)
    d = np.abs(points[..., list(h)] - np.asarray(centre, np.float64)[list(h)])
    return np.asarray(valid, bool) & (d.max(axis=-1) <= radius)


# ----------------------------------------------------------------------------- pseudo ground truth
def ray_intersector(vertices: np.ndarray, faces: np.ndarray):
    """An embree ray intersector over the triangle mesh (``vertices`` (V, 3) metres, ``faces``
    (F, 3) int). ``UserError`` when trimesh or its embree backend (embreex) is missing."""
    try:
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError:  # pragma: no cover - both are dependencies of the eval extra
        raise UserError("the mesh pseudo ground truth needs trimesh and embreex (pip install 'usd-gs[eval]')") from None
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    return RayMeshIntersector(mesh)


def mesh_visibility(intersector, points: np.ndarray, light, eps: float = 1e-4) -> np.ndarray:
    """(M,) bool: True where the segment from ``points`` (M, 3) to ``light`` (a
    ``light_prims.ShotLight``: point, or directional = unbounded ray against the travel
    direction) meets no triangle. Rays start ``eps`` metres towards the light."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    vis = np.ones(p.shape[0], bool)
    if p.shape[0] == 0:
        return vis
    if light.kind == "directional":
        d = -np.asarray(light.direction, np.float64)
        d = np.broadcast_to(d / np.linalg.norm(d), p.shape).copy()
        dist = np.full(p.shape[0], np.inf)
    else:
        v = np.asarray(light.position, np.float64) - p
        dist = np.linalg.norm(v, axis=1)
        d = v / np.maximum(dist, 1e-12)[:, None]
    origins = p + eps * d
    locs, ray_idx, _ = intersector.intersects_location(origins, d, multiple_hits=False)
    if len(ray_idx):
        t = np.einsum("ij,ij->i", locs - origins[ray_idx], d[ray_idx])
        blocked = ray_idx[t < dist[ray_idx] - eps]
        vis[blocked] = False
    return vis


def mesh_shadow_matte(points: np.ndarray, valid: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                      lights: list, intersector=None) -> np.ndarray:
    """``S_dagger`` (H, W) float64 (module docstring) at the ``valid`` pixels of ``points``
    (H, W, 3); 0 elsewhere. ``lights``: ``ShotLight`` list (weights from
    ``shading.light_shares``)."""

    out = np.zeros(points.shape[:2])
    sel = np.asarray(valid, bool)
    p = points[sel]
    if p.shape[0] == 0 or not lights:
        return out
    inter = intersector if intersector is not None else ray_intersector(vertices, faces)
    shares = light_shares(lights, p)
    lit = np.zeros(p.shape[0])
    for w, light in zip(shares, lights, strict=True):
        lit += w * mesh_visibility(inter, p, light)
    out[sel] = np.clip(1.0 - lit, 0.0, 1.0)
    return out


# ----------------------------------------------------------------------------- DGSM matte
def strength_gaussians(receivers, strength: np.ndarray):
    """A copy of ``receivers`` (``GaussianSet``) with SH degree 0 whose colour is ``strength``
    (N,) in [0, 1] in every channel."""
    from dataclasses import replace

    s = np.clip(np.asarray(strength, np.float64).reshape(-1), 0.0, 1.0)
    if s.shape[0] != receivers.count:
        raise ValueError(f"strength has {s.shape[0]} values for {receivers.count} receivers")
    dc = ((s - 0.5) / SH_C0).astype(np.float32)
    sh = np.repeat(dc[:, None, None], 3, axis=2)
    return replace(receivers, sh=sh, log_scales=None, logit_opacities=None, extras={})


def render_strength_matte(receivers, strength: np.ndarray, camera):
    """Receivers-only render with colour = shadow strength. Returns ``(S (H, W) float64,
    alpha (H, W), depth (H, W))``; ``S`` is ``colour / alpha`` (0 where alpha is 0)."""

    res = render(strength_gaussians(receivers, strength), camera)
    a = res.alpha.astype(np.float64)
    S = np.where(a > 0, res.rgb[..., 0].astype(np.float64) / np.maximum(a, 1e-12), 0.0)
    return np.clip(S, 0.0, 1.0), res.alpha, res.depth


def evaluate_view(receivers, strength: np.ndarray, camera, vertices: np.ndarray, faces: np.ndarray, lights: list,
                  centre, radius: float = 2.0, up_axis: str = "Y", tau: float = TAU, tol: float = BOUNDARY_TOL_PX,
                  intersector=None, reference=None) -> dict:
    """Metrics of one view (module docstring). ``strength``: (N,) shadow strength ``1 - T`` of
    each receiver. ``reference``: a previous result's ``(S_dagger, roi, valid)`` for the same
    view and frame (skips the ray casting; the surface does not depend on the strengths).

    Returns the :func:`shadow_metrics` dict plus ``S``, ``S_dagger``, ``roi``, ``valid``
    (images) and ``seconds`` (render, rays)."""
    import time

    t0 = time.perf_counter()
    S, alpha, depth = render_strength_matte(receivers, strength, camera)
    t1 = time.perf_counter()
    if reference is None:
        valid = alpha >= MIN_COVERAGE
        pts = surface_points(camera, depth)
        roi = roi_box_mask(pts, valid, centre, radius, up_axis)
        # cast rays a few pixels beyond the ROI too, so the ROI edge is no boundary of M_dagger
        ring = _scipy_ndimage().binary_dilation(roi, iterations=int(np.ceil(tol)) + 2) & valid
        S_ref = mesh_shadow_matte(pts, ring, vertices, faces, lights, intersector)
    else:
        S_ref, roi, valid = reference
    t2 = time.perf_counter()
    out = shadow_metrics(np.where(valid, S, 0.0), S_ref, roi, tau, tol)
    out.update(S=S, S_dagger=S_ref, roi=roi, valid=valid, seconds={"render": t1 - t0, "rays": t2 - t1})
    return out
