"""A known-light ground truth for relighting (beyond the paper; issue #7).

The scene (Y-up, metres) is a floor, a back wall, a box and two spheres near the avatar
(triangle mesh, flat Gaussians on it), a spherical lamp and an HDR environment at infinity. Its Gaussian colours are
**baked** from that known lighting as a Lambertian capture would record them:

    colour(x) = albedo(x) * E(x, n) / pi,
    E(x, n) = sum_lamps I_l c_l max(0, n.l) / r^2 V(x, lamp)
            + sum_j L_env(w_j) max(0, n.w_j) dOmega_j V(x, w_j),

with exact visibility ``V`` (Embree ray casts against the mesh; no interreflection in the
bake). What the probe renders is the same light field: the environment as a dome of
Gaussians (``usd_gs.relight.probe.hdr_dome_gaussians`` of the same lat-long image), the lamp as a
sphere of Gaussians of radius ``rho`` with radiance ``I / (pi rho^2)`` (a uniform sphere gives
exactly the irradiance ``I cos / r^2`` of the point light), and the baked surfaces.

The avatar (CesiumMan surface Gaussians, ``usd_gs.demo.mesh_avatar``) carries its known
albedo as its colour. Its ground truth is ``albedo * E_i / pi`` with ``E_i`` the irradiance
at Gaussian i's position about its true (mesh) normal from everything it would see: lamp
(shadow ray against the scene mesh), environment where a ray escapes, the baked scene
radiance (colour of the nearest scene Gaussian) where it hits the mesh. The avatar does not
shadow itself in the ground truth (the relighting models no visibility; shadows are the
separate DGSM step). A second reference, ``E`` evaluated at the probe centre for every
Gaussian, isolates the probe + transfer error from the one-probe-per-avatar assumption.

The relighting under test is the project's path, called as ``ShotProcessor._relight`` calls
it: ``gaussian_normals``, the shot's ``probe_parallax.ProbeBlend`` and
``avatar_relight.relight_factors`` (cube faces at the avatar's alpha-weighted centroid from
everything else, parallax-corrected probes, SH transfer) with the ``ProcessOptions`` defaults.
Eq. 10 divides by ``int S = pi`` (q = 1), so the relit colour of
an avatar whose colour is its albedo is ``albedo * E_probe(n) / pi``: the same units as the
ground truth, no exposure factor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from numba_kernels.normals import gaussian_normals
from usd_gs import sh3dgs
from usd_gs.demo.mesh_avatar import gaussians_on_mesh, posed_avatar_frames, sample_surface
from usd_gs.demo.stage import canonical_matrix, locate_data_dir
from usd_gs.errors import UserError
from usd_gs.evaluation.colorimetry import luminance
from usd_gs.evaluation.lighting_metrics import lighting_consistency
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid, quaternion_to_matrix
from usd_gs.io import envmap
from usd_gs.io.gltf import load_skinned_mesh
from usd_gs.pipeline.shot import ProcessOptions
from usd_gs.relight.avatar import relight_factors
from usd_gs.relight.far_field import FarField
from usd_gs.relight.parallax import ProbeBlend
from usd_gs.relight.probe import PROBE_DILATION, hdr_dome_gaussians
from usd_gs.shadows.shading import scale_sh

DEFAULT_HDR = "kiara_1_dawn_1k.hdr"


@dataclass
class KnownLightScene:
    """The generated scene: ``surfaces`` (baked Gaussians), ``emitter`` (lamp Gaussians),
    ``dome`` (environment Gaussians), the occluder ``mesh`` (trimesh), ``env`` (h, w, 3) lat-long
    radiance, lamp ``lamp_pos`` (3,), ``lamp_rgb`` (3,) intensity per channel (irradiance at
    1 m), ``albedo`` (N_surfaces, 3)."""

    surfaces: GaussianSet
    emitter: GaussianSet
    dome: GaussianSet
    mesh: object
    env: np.ndarray
    lamp_pos: np.ndarray
    lamp_rgb: np.ndarray
    albedo: np.ndarray

    @property
    def everything(self) -> GaussianSet:
        return GaussianSet.concatenate([self.surfaces, self.emitter, self.dome], label="known-light scene")

    @property
    def visible(self) -> GaussianSet:
        """The captured scene without the environment dome (surfaces and lamp)."""
        return GaussianSet.concatenate([self.surfaces, self.emitter], label="known-light scene")


def _quad(o, u, v):
    o, u, v = (np.asarray(a, np.float64) for a in (o, u, v))
    return np.array([o, o + u, o + u + v, o + v]), np.array([[0, 1, 2], [0, 2, 3]])


SPHERES = (((-0.7, 0.4, 1.0), 0.4), ((-1.2, 0.5, -0.8), 0.5))
"""Two spheres (centre, radius) within 1.5 m of the avatar's centroid, so that the 4.1 metrics'
scene neighbourhood has normals over the whole upper hemisphere, not just a floor."""


def _scene_mesh(props: bool = True):
    """Floor (10 x 10 m, y = 0), back wall (z = -2.5, facing +z), a box 1 x 0.8 x 1 m and the
    :data:`SPHERES` (with ``props``); part ids 0, 1, 2, 3 (flat-shaded except the spheres)."""
    import trimesh

    parts = [_quad((-5, 0, 5), (10, 0, 0), (0, 0, -10)), _quad((-5, 0, -2.5), (10, 0, 0), (0, 3, 0))]
    box = trimesh.creation.box(extents=(1.0, 0.8, 1.0))
    box.apply_translation((1.6, 0.4, -1.2))
    box.unmerge_vertices()  # flat shading: every face its own vertices and normal
    parts.append((np.asarray(box.vertices), np.asarray(box.faces)))
    verts, faces, part, normals = [], [], [], []
    off = 0
    for k, (v, f) in enumerate(parts):
        verts.append(v)
        faces.append(f + off)
        part.append(np.full(len(f), k))
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        vn = np.zeros_like(v)
        vn[f[:, 0]] = vn[f[:, 1]] = vn[f[:, 2]] = fn / np.linalg.norm(fn, axis=1, keepdims=True)
        normals.append(vn)
        off += len(v)
    for c, r in SPHERES if props else ():
        ball = trimesh.creation.icosphere(subdivisions=3, radius=r)
        verts.append(np.asarray(ball.vertices) + np.asarray(c))
        faces.append(np.asarray(ball.faces) + off)
        part.append(np.full(len(ball.faces), 3))
        normals.append(np.asarray(ball.vertex_normals))
        off += len(ball.vertices)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    return mesh, np.concatenate(part), np.concatenate(normals)


def _intersector(mesh):
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError as exc:
        raise UserError("the relighting ground truth needs Embree ray casts: pip install 'usd-gs[eval]' "
                        f"(embreex) ({exc})") from None

    return RayMeshIntersector(mesh)


def _first_hits(rt, origins, dirs, chunk: int = 1 << 20):
    """(n,) bool hit and (n, 3) hit points (NaN where none) of rays (n, 3), (n, 3)."""
    n = origins.shape[0]
    hit = np.zeros(n, bool)
    loc = np.full((n, 3), np.nan)
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        idx = rt.intersects_first(origins[a:b], dirs[a:b])
        ok = idx >= 0
        if ok.any():
            # distance along the ray to the hit triangle's plane
            tri = rt.mesh.triangles[idx[ok]]
            nrm = rt.mesh.face_normals[idx[ok]]
            o, d = origins[a:b][ok], dirs[a:b][ok]
            t = np.einsum("ij,ij->i", tri[:, 0] - o, nrm) / np.einsum("ij,ij->i", d, nrm)
            loc[a:b][ok] = o + t[:, None] * d
        hit[a:b] = ok
    return hit, loc


def _occluded(rt, points, target):
    """(n,) bool: the segment from each point to ``target`` (3,) hits the mesh."""
    d = target[None, :] - points
    dist = np.linalg.norm(d, axis=1)
    d = d / dist[:, None]
    hit, loc = _first_hits(rt, points, d)
    blocked = np.zeros(len(points), bool)
    blocked[hit] = np.linalg.norm(loc[hit] - points[hit], axis=1) < dist[hit] - 1e-6
    return blocked


def env_image(hdr=None, size=(16, 32), mean_radiance: float = 0.6) -> np.ndarray:
    """Lat-long environment (h, w, 3) float64 from an HDR of ``/work/shared/data/hdri``-like data,
    box-filtered to ``size`` and scaled so that its mean luminance over the sphere is ``mean_radiance``."""

    path = Path(hdr) if hdr is not None else locate_data_dir() / "hdri" / DEFAULT_HDR
    img = np.asarray(envmap.read_envmap(path), np.float64)
    h, w = size
    f = img.shape[0] // h
    img = img[: h * f, : w * f]
    if img.shape[1] != w * f:
        raise UserError(f"{path}: {img.shape[1]} columns cannot be filtered to {w}")
    img = envmap.downsample_latlong(img, f).astype(np.float64)
    om = envmap.latlong_solid_angles(h, w)
    return img * (mean_radiance / (float((luminance(img) * om).sum()) / (4 * np.pi)))


def _env_dirs(env, oversample: int = 1):
    """Quadrature of the sphere for the environment ``env`` (h, w, 3): directions (M, 3), solid
    angles (M,) and radiance (M, 3) of the lat-long grid refined ``oversample`` x per axis
    (each environment texel split into oversample^2 directions with its radiance)."""

    k = int(oversample)
    fine = np.repeat(np.repeat(env, k, axis=0), k, axis=1) if k > 1 else env
    h, w = fine.shape[:2]
    return envmap.latlong_directions(h, w).reshape(-1, 3), envmap.latlong_solid_angles(h, w).reshape(-1), \
        fine.reshape(-1, 3)


def _direct_irradiance(rt, pts, nrm, env, lamp_pos, lamp_rgb, chunk: int = 4096):
    """E (n, 3) of the bake: lamp and environment with visibility, nothing from the surfaces."""
    dirs, om, rad = _env_dirs(env)
    e = np.zeros((len(pts), 3))
    orig = pts + 1e-4 * nrm
    for a in range(0, len(pts), chunk):
        b = min(len(pts), a + chunk)
        cos = np.maximum(nrm[a:b] @ dirs.T, 0.0)  # (m, M)
        i, j = np.nonzero(cos > 0)
        hit, _ = _first_hits(rt, orig[a:b][i], dirs[j])
        w = np.where(hit, 0.0, cos[i, j] * om[j])
        e[a:b] = np.stack([np.bincount(i, w * rad[j, c], minlength=b - a) for c in range(3)], axis=1)
    return e + _lamp_irradiance(rt, pts, nrm, lamp_pos, lamp_rgb)


def _lamp_irradiance(rt, pts, nrm, lamp_pos, lamp_rgb):
    d = lamp_pos[None, :] - pts
    r2 = np.einsum("ij,ij->i", d, d)
    cos = np.maximum(np.einsum("ij,ij->i", nrm, d) / np.sqrt(r2), 0.0)
    vis = ~_occluded(rt, pts + 1e-4 * nrm, lamp_pos)
    return (cos * vis / r2)[:, None] * lamp_rgb[None, :]


def make_scene(n_surface: int = 12000, env_size=(16, 32), hdr=None, lamp_pos=(3.0, 3.2, 2.5),
               lamp_rgb=(30.0, 25.0, 18.0), lamp_radius: float = 0.3, dome_radius: float = 30.0,
               props: bool = True, env_scale: float = 1.0, seed: int = 0) -> KnownLightScene:
    """Generate and bake the known-light scene (module docstring); ``props``: add the :data:`SPHERES`;
    ``env_scale``: the environment's radiance times this (1e-4: practically the lamp alone)."""

    mesh, part, vnormals = _scene_mesh(props)
    rt = _intersector(mesh)
    env = env_image(hdr, env_size) * float(env_scale)
    lamp_pos = np.asarray(lamp_pos, np.float64)
    lamp_rgb = np.asarray(lamp_rgb, np.float64)
    rng = np.random.default_rng(seed)
    face, bary = sample_surface(mesh.vertices, mesh.faces, n_surface, seed)
    base = np.array([[0.55, 0.45, 0.35], [0.70, 0.72, 0.75], [0.25, 0.40, 0.60], [0.75, 0.70, 0.55]])
    albedo = base[part[face]] * (1.0 + 0.08 * rng.standard_normal((n_surface, 1)))
    albedo = np.clip(albedo, 0.02, 0.95)
    g = gaussians_on_mesh(mesh.vertices, mesh.faces, vnormals, face, bary, albedo, opacity=0.97,
                          label="surfaces")
    nrm = quaternion_to_matrix(g.orientations)[:, :, 2].astype(np.float64)
    e = _direct_irradiance(rt, g.positions.astype(np.float64), nrm, env, lamp_pos, lamp_rgb)
    g.sh[:, 0, :] = ((albedo * e / np.pi - 0.5) / sh3dgs.C0).astype(np.float32)
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=lamp_radius)
    bf, bb = sample_surface(ball.vertices, ball.faces, 1500, seed + 1)
    emitter = gaussians_on_mesh(np.asarray(ball.vertices) + lamp_pos, ball.faces, ball.vertex_normals, bf, bb,
                                lamp_rgb / (np.pi * lamp_radius ** 2), opacity=0.99, label="lamp")
    dome = _dome(env, dome_radius)
    return KnownLightScene(g, emitter, dome, mesh, env, lamp_pos, lamp_rgb, albedo.astype(np.float32))


def _dome(env, radius):
    h, w = env.shape[:2]
    # sigma 0.6 x the pixel extent: coverage ~0.99 (at the default 0.3 the gaps between splats
    # weight the lamp texels up in fit_probe(alpha=...) and the lamp comes out ~1.5x too bright)
    return hdr_dome_gaussians(env.astype(np.float32), radius=radius, n=h * w, sigma_factor=0.6,
                              label="environment")


def make_avatar(n: int = 4000, height: float = 1.8, position=(0.0, 0.02, 0.0), seed: int = 0) -> GaussianSet:
    """CesiumMan surface Gaussians in its first animation pose, ``height`` m tall, feet on y = 0 at
    ``position``, facing +z; colours = its (linear) texture albedo, SH degree 0."""

    mesh = load_skinned_mesh(locate_data_dir() / "humans" / "CesiumMan.glb")
    g = posed_avatar_frames(mesh, [0.0], n_gaussians=n, seed=seed, label="avatar")[0]
    m = canonical_matrix(g.positions, np.eye(3), height)
    m[3, :3] += np.asarray(position, np.float64)
    return g.transformed(m, label="avatar")


def quadrature_irradiance(rt, pts, nrm, dirs, om, env, surf_rgb, tree, chunk: int = 2048) -> np.ndarray:
    """(N, 3) irradiance at ``pts`` (N, 3) with unit normals ``nrm``: the quadrature over the unit
    directions ``dirs`` (D, 3) of solid angles ``om`` (D,), each ray from just above the point
    (1e-4 m along the normal) seeing either the environment radiance ``env`` (D, 3) or, where it
    hits the mesh of the intersector ``rt``, the linear radiance ``surf_rgb`` of the nearest surface
    Gaussian (``tree``: a KD-tree of their positions). ``chunk`` points at a time."""
    e = np.zeros((pts.shape[0], 3))
    for a in range(0, pts.shape[0], chunk):
        b = min(pts.shape[0], a + chunk)
        cos = np.maximum(nrm[a:b] @ dirs.T, 0.0)
        i, j = np.nonzero(cos > 0)
        hit, loc = _first_hits(rt, pts[a:b][i] + 1e-4 * nrm[a:b][i], dirs[j])
        rad = env[j].copy()
        if hit.any():
            rad[hit] = surf_rgb[tree.query(loc[hit])[1]]
        w = cos[i, j] * om[j]
        e[a:b] = np.stack([np.bincount(i, w * rad[:, c], minlength=b - a) for c in range(3)], axis=1)
    return e


def avatar_ground_truth(scene: KnownLightScene, avatar: GaussianSet, albedo: np.ndarray, at=None,
                        chunk: int = 2048, oversample: int = 1) -> np.ndarray:
    """Ground-truth colours (N, 3) ``albedo * E / pi`` of the avatar (module docstring).

    ``at``: None evaluates ``E`` at each Gaussian's position; a point (3,) evaluates it there for
    every Gaussian (the probe-centre reference). Normals: each Gaussian's local z axis.
    ``oversample``: the quadrature's directions per environment texel and axis (``_env_dirs``).
    """
    from scipy.spatial import cKDTree

    rt = _intersector(scene.mesh)
    nrm = quaternion_to_matrix(avatar.orientations)[:, :, 2].astype(np.float64)
    pts = avatar.positions.astype(np.float64) if at is None else np.tile(np.asarray(at, np.float64), (avatar.count, 1))
    dirs, om, env = _env_dirs(scene.env, oversample)
    tree = cKDTree(scene.surfaces.positions.astype(np.float64))
    surf_rgb = np.maximum(0.5 + sh3dgs.C0 * scene.surfaces.sh[:, 0, :].astype(np.float64), 0.0)
    if at is None:
        e = quadrature_irradiance(rt, pts, nrm, dirs, om, env, surf_rgb, tree, chunk)
    else:
        hit, loc = _first_hits(rt, np.tile(pts[0], (len(dirs), 1)), dirs)
        rad = env.copy()
        if hit.any():
            rad[hit] = surf_rgb[tree.query(loc[hit])[1]]
        e = np.maximum(nrm @ dirs.T, 0.0) @ (rad * om[:, None])
    e += _lamp_irradiance(rt, pts, nrm, scene.lamp_pos, scene.lamp_rgb)
    return np.asarray(albedo, np.float64) * e / np.pi


def psnr(a, b, peak: float = 1.0) -> float:
    """PSNR in dB over all Gaussians and channels of two colour arrays (N, 3)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(peak * peak / mse)


def relight_like_process(avatar: GaussianSet, others: GaussianSet, options=None, dilation: float | None = None,
                         normals: np.ndarray | None = None, lights=(), visibility=None, others_mask=None,
                         appearance: dict | None = None):
    """The main job's relighting of one avatar: ``(relit SH (N, K, 3), probe, normals)``.

    Calls what ``ShotProcessor._relight`` calls, with ``ProcessOptions`` (defaults if None):
    outward ``gaussian_normals`` (or the given ``normals`` (N, 3)), ``ProbeBlend`` and
    ``usd_gs.relight.avatar.relight_factors`` at the alpha-weighted centroid with ``others``
    drawn (the static scene, in metres: those beyond ``probe_far_radius`` from the probe's far-field
    anchor drawn into its far layer, ``usd_gs.relight.far_field``, as the main job draws a shot's
    static Gaussians; ``probe_far_radius`` 0: all in one render), and the relit colour factor
    applied to the SH. ``dilation``: the probe render's low-pass
    term in px^2 (None: its default, which is what the main job uses). ``lights`` /
    ``visibility`` / ``appearance``: as ``relight_factors`` takes them; ``others_mask`` (bool,
    ``others.count``): which of ``others`` the probe draws (None: all).
    """

    o = options or ProcessOptions()
    centre = alpha_weighted_centroid(avatar)
    everything = GaussianSet.concatenate([others, avatar], label="shot")
    mask = np.ones(everything.count, bool)
    mask[others.count:] = False
    if others_mask is not None:
        mask[:others.count] = np.asarray(others_mask, bool)
    if normals is None:
        normals = gaussian_normals(avatar.positions, avatar.orientations, avatar.scales, avatar.opacities)
    far = FarField(o.probe_far_radius, o.probe_far_tolerance, others.count) if o.probe_far_radius > 0 else None
    scale, probe = relight_factors(avatar, everything, mask, centre, normals,
                                   ProbeBlend.build(avatar.positions, o.probe_points), o,
                                   PROBE_DILATION if dilation is None else dilation, lights=lights,
                                   visibility=visibility, appearance=appearance, far=far)
    return scale_sh(avatar.sh, scale), probe, normals


def relight_ground_truth(n_avatar: int = 4000, n_surface: int = 12000, env_size=(16, 32), hdr=None,
                         probe_size: int | None = None, lamp: bool = True, metrics: bool = True,
                         dilation: float | None = None, props: bool = True, oversample: int = 2,
                         env_scale: float = 1.0, probe_supersample: int | None = None, seed: int = 0,
                         far_radius: float | None = None, far_tolerance: float | None = None) -> dict:
    """Relight the known-albedo avatar in the known-light scene and compare with the ground truth.

    ``lamp=False``: environment only (the lamp's intensity is 0). ``probe_size``: cube-face size
    (default ``ProcessOptions().probe_size``); ``probe_supersample``, ``far_radius``
    (``probe_far_radius``, metres; the environment's dome lies 30 m away) and ``far_tolerance``
    (``probe_far_tolerance``) likewise (``ProcessOptions``).
    ``dilation``: see :func:`relight_like_process`.
    ``props``: the two spheres near the avatar (:data:`SPHERES`). ``oversample``: directions per
    environment texel and axis in the ground truth's quadrature (2: within 51 dB of 4, against
    44 dB for 1, measured per Gaussian). ``env_scale``: see :func:`make_scene` (with ``lamp=False``
    and ``env_scale=1`` the environment alone, with ``env_scale=1e-4`` the lamp alone).
    Returns ``{'psnr_relit', 'psnr_orig'}`` (dB against the per-Gaussian ground truth),
    ``'psnr_relit_true_normals'`` (the same probe, transfer with the mesh normals instead of
    ``gaussian_normals``), ``'flipped_normals'`` (share of ``gaussian_normals`` pointing into
    the body) and ``'psnr_relit_unflipped'`` (PSNR over the other Gaussians),
    ``{'psnr_relit_centre', 'psnr_orig_centre'}`` (against the probe-centre reference),
    ``'metrics'``: :func:`usd_gs.evaluation.lighting_metrics.lighting_consistency` for orig vs relit and
    ``'metrics_gt'`` for orig vs the ground truth (what perfect relighting scores), plus
    ``'timings'`` (s), the colours (``'orig'``, ``'relit'``, ``'truth'``, ``'truth_centre'``,
    (N, 3)) and the counts.
    """
    from dataclasses import replace


    t = {}
    t0 = time.perf_counter()
    scene = make_scene(n_surface, env_size, hdr, lamp_rgb=(30.0, 25.0, 18.0) if lamp else (0.0, 0.0, 0.0),
                       props=props, env_scale=env_scale, seed=seed)
    avatar = make_avatar(n_avatar, seed=seed)
    t["scene"] = time.perf_counter() - t0
    albedo = 0.5 + sh3dgs.C0 * avatar.sh[:, 0, :].astype(np.float64)
    t0 = time.perf_counter()
    truth = avatar_ground_truth(scene, avatar, albedo, oversample=oversample)
    centre = alpha_weighted_centroid(avatar)
    truth_c = avatar_ground_truth(scene, avatar, albedo, at=centre, oversample=oversample)
    t["ground_truth"] = time.perf_counter() - t0
    opts = ProcessOptions(color_space="linear")  # this generator bakes and stores linear colours
    if probe_size is not None:
        opts = replace(opts, probe_size=int(probe_size))
    if probe_supersample is not None:
        opts = replace(opts, probe_supersample=int(probe_supersample))
    if far_radius is not None:
        opts = replace(opts, probe_far_radius=float(far_radius))
    if far_tolerance is not None:
        opts = replace(opts, probe_far_tolerance=float(far_tolerance))
    t0 = time.perf_counter()
    sh, probe, normals = relight_like_process(avatar, scene.everything, opts, dilation)
    t["relight"] = time.perf_counter() - t0
    relit_rgb = 0.5 + sh3dgs.C0 * sh[:, 0, :].astype(np.float64)
    true_n = quaternion_to_matrix(avatar.orientations)[:, :, 2].astype(np.float32)
    sh_tn, _, _ = relight_like_process(avatar, scene.everything, opts, dilation, normals=true_n)
    relit_tn = 0.5 + sh3dgs.C0 * sh_tn[:, 0, :].astype(np.float64)
    flipped = np.einsum("ij,ij->i", normals.astype(np.float64), true_n) < 0
    out = {"psnr_relit": psnr(relit_rgb, truth), "psnr_orig": psnr(albedo, truth),
           "psnr_relit_true_normals": psnr(relit_tn, truth), "flipped_normals": float(flipped.mean()),
           "psnr_relit_unflipped": psnr(relit_rgb[~flipped], truth[~flipped]),
           "psnr_relit_centre": psnr(relit_rgb, truth_c), "psnr_orig_centre": psnr(albedo, truth_c),
           "orig": albedo, "relit": relit_rgb, "truth": truth, "truth_centre": truth_c, "probe": probe,
           "n_avatar": avatar.count, "n_scene": scene.surfaces.count, "probe_size": opts.probe_size,
           "centre": centre, "timings": t}
    if metrics:

        t0 = time.perf_counter()
        relit = avatar.with_label("avatar")
        relit.sh = sh
        gt = avatar.with_label("avatar")
        gt.sh = ((truth - 0.5) / sh3dgs.C0)[:, None, :].astype(np.float32)
        out["metrics"] = lighting_consistency(avatar, relit, scene.visible)
        out["metrics_gt"] = lighting_consistency(avatar, gt, scene.visible)
        t["metrics"] = time.perf_counter() - t0
    return out
