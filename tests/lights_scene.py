"""Generated scenes with known emitters for the light-estimation tests (and its benchmark).

``make_emitter_test_scene`` builds, in metres and Y-up (``up_axis="Z"`` rotates it to Z-up):

- a closed room ``x in [-3, 3], y in [0, 3], z in [-2.5, 2.5]`` of dim, large, flat Gaussians
  on a jittered grid of ``spacing`` (sigma 0.6 * spacing in-plane, 0.01 m along the normal),
  grey-ish colours of luminance 0.2..0.4, opacity 0.7..1;
- optionally a "window": a 1.5 m x 1.2 m patch on the back wall of many moderately bright
  Gaussians (luminance ``window_luminance``), broad, so it must lose against compact emitters;
- compact emitters: each a cluster of ``n_per_emitter`` small (sigma 1..2 cm) bright Gaussians
  spread N(0, 2 cm) around a known centre, recentred so that their mean is exactly the centre,
  colour = ``luminance * chromaticity`` (linear RGB, +-2 % jitter).

Colours become 3DGS DC terms ``f_dc = (rgb - 0.5) / C0``; for degree > 0 the higher
coefficients are small random values (``rest_amplitude``), so views differ slightly.
The avatar centroid is (0, 1, 0) (Y-up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usd_gs.gaussians import GaussianSet
from usd_gs.sh3dgs import C0, num_coeffs

LUMA = np.array([0.2126, 0.7152, 0.0722])

# (centre, chromaticity with luminance 1, luminance): a warm ceiling lamp, a cool wall lamp, a green-ish floor lamp
DEFAULT_EMITTERS = (
    ((-1.5, 2.6, -1.0), (1.0, 0.8, 0.6), 8.0),
    ((2.4, 1.8, 1.2), (0.6, 0.8, 1.0), 5.0),
    ((-2.0, 1.4, 1.6), (0.7, 1.0, 0.6), 3.0),
)


@dataclass
class EmitterScene:
    gaussians: GaussianSet
    centroid: np.ndarray  # (3,) avatar centroid, scene frame
    emitter_centres: np.ndarray  # (E, 3) scene frame, sorted by decreasing luminance
    emitter_rgb: np.ndarray  # (E, 3) linear RGB of the emitters
    window_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def _chroma(c):
    c = np.asarray(c, dtype=np.float64)
    return c / (c @ LUMA)


def _plane(rng, origin, u, v, nu, nv, spacing, normal_axis):
    gu, gv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    pts = (origin + (gu.reshape(-1, 1) + 0.5 + rng.uniform(-0.3, 0.3, (gu.size, 1))) * spacing * u
           + (gv.reshape(-1, 1) + 0.5 + rng.uniform(-0.3, 0.3, (gv.size, 1))) * spacing * v)
    scales = np.full((pts.shape[0], 3), 0.6 * spacing)
    scales[:, normal_axis] = 0.01
    return pts, scales


def make_emitter_test_scene(seed: int = 0, degree: int = 0, spacing: float = 0.12, emitters=DEFAULT_EMITTERS,
                            n_per_emitter: int = 40, window_luminance: float | None = 1.5,
                            rest_amplitude: float = 0.02, up_axis: str = "Y") -> EmitterScene:
    rng = np.random.default_rng(seed)
    pos, scl, rgb, op = [], [], [], []
    ex, ey, ez = np.eye(3)
    lx, ly, lz = 6.0, 3.0, 5.0
    planes = [  # origin, u, v, extent_u, extent_v, normal axis
        ((-3.0, 0.0, -2.5), ex, ez, lx, lz, 1), ((-3.0, 3.0, -2.5), ex, ez, lx, lz, 1),
        ((-3.0, 0.0, -2.5), ex, ey, lx, ly, 2), ((-3.0, 0.0, 2.5), ex, ey, lx, ly, 2),
        ((-3.0, 0.0, -2.5), ey, ez, ly, lz, 0), ((3.0, 0.0, -2.5), ey, ez, ly, lz, 0),
    ]
    for origin, u, v, eu, ev, ax in planes:
        p, s = _plane(rng, np.array(origin), u, v, int(eu / spacing), int(ev / spacing), spacing, ax)
        pos.append(p)
        scl.append(s)
        tint = rng.uniform(0.9, 1.1, (p.shape[0], 3))
        rgb.append(_chroma(np.ones(3)) * tint * rng.uniform(0.2, 0.4, (p.shape[0], 1)))
        op.append(rng.uniform(0.7, 1.0, p.shape[0]))
    n_room = sum(p.shape[0] for p in pos)
    window_index = np.zeros(0, dtype=np.int64)
    if window_luminance is not None:
        p, s = _plane(rng, np.array([0.5, 1.0, -2.49]), ex, ey, 30, 24, 0.05, 2)
        window_index = n_room + np.arange(p.shape[0])
        pos.append(p)
        scl.append(s)
        rgb.append(_chroma([0.9, 0.95, 1.0]) * window_luminance * rng.uniform(0.98, 1.02, (p.shape[0], 1)))
        op.append(np.full(p.shape[0], 0.95))
    centres, cols = [], []
    for centre, chroma, lum in sorted(emitters, key=lambda e: -e[2]):
        off = rng.normal(0.0, 0.02, (n_per_emitter, 3))
        off -= off.mean(axis=0)
        pos.append(np.asarray(centre) + off)
        scl.append(rng.uniform(0.01, 0.02, (n_per_emitter, 3)))
        col = _chroma(chroma) * lum
        rgb.append(col * rng.uniform(0.98, 1.02, (n_per_emitter, 1)))
        op.append(np.full(n_per_emitter, 0.9))
        centres.append(centre)
        cols.append(col)
    positions = np.concatenate(pos)
    rgb = np.concatenate(rgb)
    n = positions.shape[0]
    sh = np.zeros((n, num_coeffs(degree), 3))
    sh[:, 0, :] = (rgb - 0.5) / C0
    if degree > 0:
        sh[:, 1:, :] = rng.uniform(-rest_amplitude, rest_amplitude, (n, num_coeffs(degree) - 1, 3))
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    g = GaussianSet(positions, quats, np.concatenate(scl), np.concatenate(op), sh, label="<emitter test scene>")
    centroid = np.array([0.0, 1.0, 0.0])
    centres = np.array(centres, dtype=np.float64)
    if up_axis.upper() == "Z":  # Y-up -> Z-up: (x, y, z) -> (x, -z, y), a proper rotation
        m = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        xf = np.eye(4)
        xf[:3, :3] = m.T  # USD row-vector convention: p_new = p @ M
        g = g.transformed(xf, label="<emitter test scene, Z-up>")
        centroid = centroid @ m.T
        centres = centres @ m.T
    return EmitterScene(g, centroid, centres, np.array(cols), window_index)


def read_capture(path) -> GaussianSet:
    """Real capture as a GaussianSet: ``usd_gs.io.ply.read_ply`` when that module is available,
    else a minimal INRIA-layout PLY reader (plyfile), SH degree 0..3."""
    try:
        from usd_gs.io.ply import read_ply
    except ImportError:
        read_ply = None
    if read_ply is not None:
        return read_ply(path)
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"].data
    names = v.dtype.names
    n = len(v)
    f = lambda key: np.asarray(v[key], dtype=np.float32)  # noqa: E731
    positions = np.stack([f("x"), f("y"), f("z")], axis=1)
    quats = np.stack([f(f"rot_{i}") for i in range(4)], axis=1)
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    scales = np.exp(np.stack([f(f"scale_{i}") for i in range(3)], axis=1))
    opac = 1.0 / (1.0 + np.exp(-f("opacity").astype(np.float64)))
    dc = np.stack([f(f"f_dc_{i}") for i in range(3)], axis=1)
    rest_names = sorted((k for k in names if k.startswith("f_rest_")), key=lambda k: int(k[7:]))
    k = len(rest_names) // 3 + 1
    sh = np.zeros((n, k, 3), dtype=np.float32)
    sh[:, 0] = dc
    if rest_names:
        rest = np.stack([f(nm) for nm in rest_names], axis=1).reshape(n, 3, k - 1)
        sh[:, 1:] = rest.transpose(0, 2, 1)
    return GaussianSet(positions, quats, scales, opac, sh, label=str(path))
