"""An open outdoor ground truth for relighting with modelled lights (issue 18).

The scene (Y-up, metres): a 16 x 16 m ground (y = 0), a statue-sized caster (a 0.8 x 2.2 x 0.8 m
plinth with a 0.35 m sphere on top) and a few props (a low box, two spheres), a triangle mesh
with flat Gaussians on it, **no sky Gaussians** (what a capture of an open place has). It is lit by

- a sun: ``DistantLight`` with a finite disc (``angle`` 0.53 degrees), irradiance ``sun_e`` at
  normal incidence, visibility by ray casts through 7 points of the disc;
- a sky at infinity, one of: ``'clear'``, the CIE standard clear sky (CIE S 011/E:2003 type 12:
  gradation a = -1, b = -0.32; indicatrix c = 10, d = -3, e = 0.45) for the same sun;
  ``'kiara'``, ``hdri/kiara_1_dawn_1k.hdr`` with its sun removed (the texels above a luminance
  threshold around the brightest one replaced by the median of the ring around them) and the
  analytic sun placed at its direction with the removed energy; ``'overcast'``, the CIE overcast
  sky ``L(Z) = L_z (1 + 2 cos Z) / 3`` and no sun. The sky is zero below the horizon (the ground
  and the props are what lies there).

Colours are **baked display-referred** (sRGB-encoded, as a capture stores them) from the linear
``albedo E / pi``: ``E`` the sun (cap irradiance times visibility) plus the sky quadrature (lat-long
texels split 2 x 2, ray-cast visibility), no interreflection. The avatar (CesiumMan, as the indoor
ground truth: ``relight_groundtruth.make_avatar``) is captured as its sRGB-encoded albedo (its
colour under ``E_ref = pi``, a uniform white sky of radiance 1).

Ground truth of the relit avatar: ``albedo E_i / pi`` (linear; encoded for the display PSNR) with
``E_i`` about the Gaussian's mesh normal: the sun with exact visibility against the scene mesh
**and the avatar's own posed mesh**, the sky where a ray escapes the scene, the baked scene
radiance where it hits the scene (the avatar does not occlude its own sky or bounce light: the
relighting's indirect term models no self-occlusion; its direct term does, by the DGSM).

The relighting under test is the main job's ``relight_factors`` with the authored lights (the
ground truth knows them: the sun as a ``ShotLight`` DistantLight, the sky as a dome ``ShotLight``
with its lat-long image), the sun's visibility from the project's DGSMs (the scene's Gaussians
and the avatar's own, with the main job's biases), ``ProcessOptions`` defaults (sRGB). This
measures the lighting model, not the estimation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from numba_kernels.normals import gaussian_normals
from usd_gs import sh3dgs
from usd_gs.colorspace import srgb_decode, srgb_encode
from usd_gs.demo.mesh_avatar import AVATAR_INSET, gaussians_on_mesh, posed_avatar_frames, posed_meshes, sample_surface
from usd_gs.demo.stage import canonical_matrix, locate_data_dir
from usd_gs.evaluation.colorimetry import luminance
from usd_gs.evaluation.relight_groundtruth import (
    _direct_irradiance,
    _env_dirs,
    _first_hits,
    _intersector,
    psnr,
    quadrature_irradiance,
    relight_like_process,
)
from usd_gs.gaussians import GaussianSet, quaternion_to_matrix
from usd_gs.io import envmap
from usd_gs.io.gltf import load_skinned_mesh
from usd_gs.pipeline.options import ProcessOptions
from usd_gs.relight.direct import cap_irradiance, self_shadow_samples
from usd_gs.shadows.shot import Receivers, caster_transmittance, receiver_points, shared_transmittance
from usd_gs.usd.lux import ShotLight

SKIES = ("clear", "kiara", "overcast")
SUN_ANGLE = 0.53


@dataclass
class OutdoorScene:
    """The generated scene: ``surfaces`` (baked, sRGB), ``mesh``, ``env`` (h, w, 3) linear sky,
    ``sun_dir`` (3,) unit toward the sun, ``sun_e`` (3,) normal-incidence irradiance (zeros for
    overcast), ``albedo`` (N, 3) linear, ``sky`` name."""

    surfaces: GaussianSet
    mesh: object
    env: np.ndarray
    sun_dir: np.ndarray
    sun_e: np.ndarray
    albedo: np.ndarray
    sky: str

    def lights(self) -> list:
        """The authored lights: the sun (if any) and the sky dome, as ``ShotLight``."""

        out = []
        if self.sun_e.max() > 0:
            half = math.radians(SUN_ANGLE) / 2
            radiance = self.sun_e / (math.pi * math.sin(half) ** 2)
            out.append(ShotLight("/Sun", "directional", direction=-self.sun_dir, color=radiance, intensity=1.0,
                                 shape="distant", angle=SUN_ANGLE, source="/Sun"))
        out.append(ShotLight("/Sky", "dome", env=self.env.astype(np.float32), shape="dome", intensity=1.0,
                             source="/Sky"))
        return out


def _sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az)])


def cie_clear_sky(dirs: np.ndarray, sun_dir: np.ndarray, zenith: float = 1.0) -> np.ndarray:
    """Relative CIE standard clear sky (type 12) luminance at ``dirs`` (..., 3) for the sun at
    ``sun_dir``, ``zenith`` at the zenith; 0 below the horizon."""
    a, b, c, d, e = -1.0, -0.32, 10.0, -3.0, 0.45
    cz = np.clip(dirs[..., 1], 1e-3, 1.0)
    zs = math.acos(float(np.clip(sun_dir[1], -1, 1)))
    gam = np.arccos(np.clip(dirs @ sun_dir, -1.0, 1.0))

    def f(x):
        return 1.0 + c * (np.exp(d * x) - math.exp(d * math.pi / 2)) + e * np.cos(x) ** 2

    def phi(cosz):
        return 1.0 + a * np.exp(b / cosz)

    lum = zenith * f(gam) * phi(cz) / (f(np.array(zs)) * phi(np.array(1.0)))
    return np.where(dirs[..., 1] > 0, lum, 0.0)


def sky_image(sky: str, size=(32, 64), sun_dir=None, sky_e: float = 0.8):
    """``(env (h, w, 3) linear lat-long, sun_dir (3,), sun share)`` of sky ``sky`` scaled so that a
    horizontal surface receives ``sky_e`` from the sky alone (unoccluded). For 'kiara' the sun
    direction is the HDR's and the share is the removed sun's irradiance over the sky's
    (horizontal), else None."""

    h, w = size
    dirs = envmap.latlong_directions(h, w)
    om = envmap.latlong_solid_angles(h, w)
    share = None
    if sky == "clear":
        lum = cie_clear_sky(dirs, sun_dir)
        img = lum[..., None] * np.array([0.75, 0.88, 1.15])  # bluish
    elif sky == "overcast":
        img = (np.where(dirs[..., 1] > 0, (1 + 2 * dirs[..., 1]) / 3, 0.0))[..., None] * np.array([1.0, 1.0, 1.02])
    elif sky == "kiara":

        full = np.asarray(envmap.read_envmap(locate_data_dir() / "hdri" / "kiara_1_dawn_1k.hdr"), np.float64)
        fh, fw = full.shape[:2]
        fd = envmap.latlong_directions(fh, fw)
        fo = envmap.latlong_solid_angles(fh, fw)
        y = luminance(full)
        i = np.unravel_index(np.argmax(y), y.shape)
        sun_dir = fd[i]
        ang = np.arccos(np.clip(fd @ sun_dir, -1, 1))
        ring = (ang > math.radians(6)) & (ang < math.radians(10))
        bg = np.median(full[ring], axis=0)
        disc = (ang < math.radians(6)) & (y > 4.0 * float(luminance(bg)))
        removed = ((full[disc] - bg) * fo[disc][:, None]).sum(axis=0)  # the sun's flux (normal incidence)
        full[disc] = bg
        full[fd[..., 1] <= 0] = 0.0
        f = fh // h
        img = envmap.downsample_latlong(full[: h * f, : w * f].astype(np.float32), f).astype(np.float64)
        share = (removed, sun_dir)
    else:
        raise ValueError(f"sky must be one of {SKIES}")
    horiz = float((img[..., 1] * np.maximum(dirs[..., 1], 0.0) * om).sum())
    k = sky_e / horiz
    env = img * k
    if share is not None:
        removed, sun_dir = share
        return env, sun_dir, removed * k
    return env, sun_dir, None


def _scene_mesh():
    """Ground, plinth + head sphere (the statue), a low box and two spheres; part ids 0..4."""
    import trimesh

    parts = []
    g = trimesh.Trimesh(np.array([[-8, 0, 8], [8, 0, 8], [8, 0, -8], [-8, 0, -8]], float), np.array([[0, 1, 2],
                                                                                                    [0, 2, 3]]))
    parts.append((g, 0, False))
    plinth = trimesh.creation.box(extents=(0.8, 2.2, 0.8))
    plinth.apply_translation((1.6, 1.1, -1.2))
    parts.append((plinth, 1, False))
    head = trimesh.creation.icosphere(subdivisions=3, radius=0.35)
    head.apply_translation((1.6, 2.55, -1.2))
    parts.append((head, 2, True))
    low = trimesh.creation.box(extents=(1.2, 0.5, 0.6))
    low.apply_translation((-1.8, 0.25, -1.5))
    parts.append((low, 3, False))
    for c, r in (((-1.0, 0.3, 1.4), 0.3), ((2.2, 0.45, 1.2), 0.45)):
        s = trimesh.creation.icosphere(subdivisions=3, radius=r)
        s.apply_translation(c)
        parts.append((s, 4, True))
    verts, faces, part, normals = [], [], [], []
    off = 0
    for m, k, smooth in parts:
        if not smooth:
            m = m.copy()
            m.unmerge_vertices()
        v, f = np.asarray(m.vertices, float), np.asarray(m.faces)
        if smooth:
            vn = np.asarray(m.vertex_normals)
        else:
            fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
            fn /= np.linalg.norm(fn, axis=1, keepdims=True)
            vn = np.zeros_like(v)
            vn[f[:, 0]] = vn[f[:, 1]] = vn[f[:, 2]] = fn
        verts.append(v)
        faces.append(f + off)
        part.append(np.full(len(f), k))
        normals.append(vn)
        off += len(v)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    return mesh, np.concatenate(part), np.concatenate(normals)


def _disc_dirs(sun_dir: np.ndarray, n_ring: int = 6) -> np.ndarray:
    """7 unit directions over the sun disc: its centre and a ring at 0.7 of its radius."""
    s = sun_dir / np.linalg.norm(sun_dir)
    u = np.cross(s, [0.0, 0.0, 1.0] if abs(s[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(s, u)
    r = math.tan(math.radians(SUN_ANGLE) / 2) * 0.7
    ring = [s + r * (math.cos(t) * u + math.sin(t) * v) for t in np.arange(n_ring) * 2 * math.pi / n_ring]
    d = np.array([s] + ring)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


SKIN_CLEARANCE = 1e-3
"""Metres above the skin from which an avatar Gaussian's sun rays are cast against its own mesh:
each Gaussian sits ``mesh_avatar.AVATAR_INSET`` in-plane sigmas inside the skin, so its rays start
at ``position + (AVATAR_INSET sigma + SKIN_CLEARANCE) normal``, the skin point above it."""


def skin_offsets(avatar: GaussianSet) -> np.ndarray:
    """(N,) metres from each avatar Gaussian's centre to just above the skin (:data:`SKIN_CLEARANCE`)."""

    return AVATAR_INSET * avatar.scales[:, 0].astype(np.float64) + SKIN_CLEARANCE


def _sun_visibility(rts, pts, nrm, sun_dir, offsets=None) -> np.ndarray:
    """(n,) share of the 7 disc rays from ``pts`` that escape every mesh in ``rts``; ray origins
    moved ``offsets[k]`` metres (scalar or (n,); default 1e-4) along ``nrm`` for mesh k."""

    dd = _disc_dirs(sun_dir)
    vis = np.zeros(len(pts))
    offsets = offsets or [1e-4] * len(rts)
    for d in dd:
        free = np.ones(len(pts), bool)
        for rt, off in zip(rts, offsets, strict=True):
            o = pts + np.reshape(off, (-1, 1)) * nrm
            hit, _ = _first_hits(rt, o, np.broadcast_to(d, o.shape).copy())
            free &= ~hit
        vis += free
    return vis / len(dd)


def _sun_irradiance(pts_n: np.ndarray, sun_dir, sun_e) -> np.ndarray:
    half = math.radians(SUN_ANGLE) / 2
    cos = pts_n @ (sun_dir / np.linalg.norm(sun_dir))
    return (cap_irradiance(cos, math.sin(half)) / (math.pi * math.sin(half) ** 2))[:, None] * np.asarray(sun_e)[None]


def make_outdoor_scene(sky: str = "clear", n_surface: int = 20000, env_size=(32, 64), sun_elevation: float = 40.0,
                       sun_azimuth: float = 200.0, sun_e: float = 2.2, sky_e: float = 0.8,
                       seed: int = 0) -> OutdoorScene:
    """Generate and bake the outdoor scene (module docstring). ``sun_e``: sun irradiance at normal
    incidence (linear, white times (1, 0.97, 0.92)); ``sky_e``: the sky's irradiance on an open
    horizontal surface. For 'kiara' the sun direction and strength come from the HDR."""

    mesh, part, vnormals = _scene_mesh()
    rt = _intersector(mesh)
    sun_dir = _sun_direction(sun_elevation, sun_azimuth)
    env, sd, removed = sky_image(sky, env_size, sun_dir, sky_e)
    if sky == "kiara":
        sun_dir = sd
        sun = removed
    elif sky == "overcast":
        sun = np.zeros(3)
    else:
        sun = sun_e * np.array([1.0, 0.97, 0.92])
    rng = np.random.default_rng(seed)
    face, bary = sample_surface(mesh.vertices, mesh.faces, n_surface, seed)
    base = np.array([[0.45, 0.42, 0.38], [0.62, 0.60, 0.56], [0.62, 0.60, 0.56], [0.30, 0.42, 0.55],
                     [0.70, 0.55, 0.40]])
    albedo = np.clip(base[part[face]] * (1.0 + 0.08 * rng.standard_normal((n_surface, 1))), 0.02, 0.95)
    g = gaussians_on_mesh(mesh.vertices, mesh.faces, vnormals, face, bary, albedo, opacity=0.97, label="ground")
    nrm = quaternion_to_matrix(g.orientations)[:, :, 2].astype(np.float64)
    pts = g.positions.astype(np.float64)
    e = _direct_irradiance(rt, pts, nrm, env, np.zeros(3), np.zeros(3))
    if sun.max() > 0:
        e += _sun_irradiance(nrm, sun_dir, sun) * _sun_visibility([rt], pts, nrm, sun_dir)[:, None]
    lin = albedo * e / np.pi
    g.sh[:, 0, :] = ((srgb_encode(lin) - 0.5) / sh3dgs.C0).astype(np.float32)
    return OutdoorScene(g, mesh, env, sun_dir, np.asarray(sun, np.float64), albedo.astype(np.float32), sky)


def make_outdoor_avatar(n: int = 4000, height: float = 1.8, position=(0.0, 0.02, 0.0), seed: int = 0):
    """``(avatar GaussianSet with sRGB-encoded albedo colours, albedo (N, 3) linear, posed mesh
    (trimesh) in the same frame)``: CesiumMan as ``relight_groundtruth.make_avatar``."""
    import trimesh


    mesh = load_skinned_mesh(locate_data_dir() / "humans" / "CesiumMan.glb")
    g = posed_avatar_frames(mesh, [0.0], n_gaussians=n, seed=seed, label="avatar")[0]
    m = canonical_matrix(g.positions, np.eye(3), height)
    m[3, :3] += np.asarray(position, np.float64)
    g = g.transformed(m, label="avatar")
    verts, faces = posed_meshes(mesh, [0.0])[0]
    v = np.c_[verts, np.ones(len(verts))] @ m
    albedo = np.clip(0.5 + sh3dgs.C0 * g.sh[:, 0, :].astype(np.float64), 0.0, 1.0)
    g.sh[:, 0, :] = ((srgb_encode(albedo) - 0.5) / sh3dgs.C0).astype(np.float32)
    return g, albedo, trimesh.Trimesh(v[:, :3], np.asarray(faces), process=False)


def outdoor_avatar_truth(scene: OutdoorScene, avatar: GaussianSet, albedo: np.ndarray, avatar_mesh,
                         chunk: int = 2048, oversample: int = 2) -> np.ndarray:
    """Linear ground-truth colours (N, 3) ``albedo E / pi`` of the avatar (module docstring)."""
    from scipy.spatial import cKDTree


    rt = _intersector(scene.mesh)
    rt_self = _intersector(avatar_mesh)
    nrm = quaternion_to_matrix(avatar.orientations)[:, :, 2].astype(np.float64)
    pts = avatar.positions.astype(np.float64)
    dirs, om, env = _env_dirs(scene.env, oversample)
    tree = cKDTree(scene.surfaces.positions.astype(np.float64))
    surf = srgb_decode(0.5 + sh3dgs.C0 * scene.surfaces.sh[:, 0, :].astype(np.float64))
    e = quadrature_irradiance(rt, pts, nrm, dirs, om, env, surf, tree, chunk)
    if scene.sun_e.max() > 0:
        e += _sun_irradiance(nrm, scene.sun_dir, scene.sun_e) * _sun_visibility(
            [rt, rt_self], pts, nrm, scene.sun_dir, [1e-4, skin_offsets(avatar)])[:, None]
    return np.asarray(albedo, np.float64) * e / np.pi


def sun_visibility_like_process(scene: OutdoorScene, avatar: GaussianSet, light, options=None) -> np.ndarray:
    """(N,) the sun's visibility at the avatar's Gaussians as the main job computes it: the scene's
    DGSM (every scene Gaussian an occluder, lookups moved ``contact_bias`` toward the sun) times the
    avatar's own (DGSM with ``self_shadow_kappa``, at ``self_shadow_samples`` Gaussians, lookups
    moved ``self_shadow_bias`` toward the sun and ``self_shadow_normal`` median sigmas along the
    ``gaussian_normals``, the others taking their nearest sample's: ``ShotProcessor._self_points``),
    centre sampling
    (``ShotProcessor._centre_cfg``)."""
    from dataclasses import replace


    o = options or ProcessOptions()
    cfg = replace(o.dgsm, sampling="center")
    recv = Receivers.build([("avatar", avatar)])
    v = np.ones(avatar.count)
    idx, val = caster_transmittance(scene.surfaces, recv, light, cfg, roi="cone", bias=o.contact_bias)
    v[idx] *= val
    if o.self_shadow and (light.kind == "directional" or o.self_shadow_lights == "all"):

        sel, nearest = self_shadow_samples(avatar.positions, o.self_shadow_samples)
        idx, pts, w = receiver_points(avatar, recv, light, cfg, roi="all", bias=o.self_shadow_bias, candidates=sel)
        nrm = gaussian_normals(avatar.positions, avatar.orientations, avatar.scales, avatar.opacities)
        off = o.self_shadow_normal * float(np.median(avatar.scales.max(axis=1)))
        pts = pts + off * np.repeat(np.asarray(nrm, np.float64)[idx], len(w), axis=0)
        cfg_o = replace(cfg, kappa=o.self_shadow_kappa)
        (idx, val), = shared_transmittance(avatar, [(idx, pts, w)], light, cfg_o)
        vs = np.ones(sel.size)
        vs[np.searchsorted(sel, idx)] = val
        v *= vs[nearest]
    return v


def outdoor_ground_truth(sky: str = "clear", n_avatar: int = 4000, n_surface: int = 20000, env_size=(32, 64),
                         options=None, position=(0.0, 0.02, 0.0), seed: int = 0, **scene_kw) -> dict:
    """Relight the known-albedo avatar standing at ``position`` in the outdoor scene with the
    authored sun and sky and compare with the ground truth. Returns ``psnr_linear`` (dB, linear
    ``albedo E / pi``, peak 1), ``psnr_display`` (dB, sRGB-encoded), ``psnr_orig_display`` (the
    unrelit avatar), ``psnr_true_normals_display`` (mesh normals in the transfer), the colours
    (``relit``, ``truth`` linear (N, 3)), ``sun_visibility`` (N,), ``timings``."""

    t = {}
    t0 = time.perf_counter()
    scene = make_outdoor_scene(sky, n_surface, env_size, seed=seed, **scene_kw)
    avatar, albedo, amesh = make_outdoor_avatar(n_avatar, position=position, seed=seed)
    t["scene"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    truth = outdoor_avatar_truth(scene, avatar, albedo, amesh)
    t["ground_truth"] = time.perf_counter() - t0
    o = options or ProcessOptions()
    lights = scene.lights()
    t0 = time.perf_counter()
    vis = [sun_visibility_like_process(scene, avatar, lt, o) if lt.kind != "dome" else None for lt in lights]
    t["visibility"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sh, probe, normals = relight_like_process(avatar, scene.surfaces, o, lights=lights, visibility=vis)
    t["relight"] = time.perf_counter() - t0
    relit_disp = np.clip(0.5 + sh3dgs.C0 * sh[:, 0, :].astype(np.float64), 0.0, None)
    relit = srgb_decode(relit_disp) if o.color_space == "srgb" else relit_disp
    true_n = quaternion_to_matrix(avatar.orientations)[:, :, 2].astype(np.float32)
    sh_tn, _, _ = relight_like_process(avatar, scene.surfaces, o, normals=true_n, lights=lights, visibility=vis)
    relit_tn = srgb_decode(np.clip(0.5 + sh3dgs.C0 * sh_tn[:, 0, :].astype(np.float64), 0.0, None))
    orig = srgb_decode(0.5 + sh3dgs.C0 * avatar.sh[:, 0, :].astype(np.float64))
    enc = srgb_encode
    sunv = vis[0] if vis and vis[0] is not None else np.ones(avatar.count)
    return {"sky": sky, "psnr_linear": psnr(relit, truth), "psnr_display": psnr(enc(relit), enc(truth)),
            "psnr_orig_display": psnr(enc(orig), enc(truth)), "psnr_true_normals_display": psnr(enc(relit_tn),
                                                                                                enc(truth)),
            "relit": relit, "truth": truth, "sun_visibility": sunv, "probe": probe, "sun_dir": scene.sun_dir,
            "sun_e": scene.sun_e, "n_avatar": avatar.count, "n_scene": scene.surfaces.count, "timings": t}
