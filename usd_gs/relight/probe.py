"""SH environment probe (paper 3.4): fit from cube faces, storage, evaluation, EXR output.

The probe is the radiance arriving at the probe centre from direction ``w`` (unit vector
from the centre toward the scene), in linear RGB, the same units as the cube-face
renders it is fitted to. It is **not** a Gaussian colour: the 3DGS ``0.5 +`` offset applies
to Gaussian SH colours, not to the probe, and the probe is fitted directly to the linear
rendered colours (a dome Gaussian of colour c contributes radiance c).

Storage (``SHProbe.coeffs``, (K, 3) float64, K = (d+1)^2):

- degree <= 3: the 3DGS basis of ``usd_gs.sh3dgs`` (``basis == '3dgs'``), so the probe can be
  evaluated with the same code as Gaussian colours (without the 0.5 offset);
- degree 4..8 (ZH avatars): the RH basis of ``numba_kernels.sh_real`` (``basis == 'rh'``);
  the 3DGS basis does not exist there.

The fit itself runs in the RH basis; ``SHProbe.rh()`` converts explicitly (a sign flip
``(-1)^m`` per coefficient, ``numba_kernels.sh_real.rh_to_3dgs``).

This module writes files (EXR helpers), so numba kernels are imported lazily, inside the
functions that need them: importing it does not import numba.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from usd_gs import sh3dgs
from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.io import envmap

_MAX_DEGREE = 8


PROBE_DILATION = 0.0  # px^2: probe renders measure radiance (see render_probe_faces)
PROBE_SUPERSAMPLE = 1
"""Default of :func:`render_probe_faces`' ``supersample`` (and of ``ProcessOptions.probe_supersample``,
``usdgs process --probe-supersample``): 2 draws the faces at twice the size per axis and
box-filters them down, so that a lamp a few texels wide is integrated over each texel instead of
sampled at its centre; measured benefit and cost in :func:`render_probe_faces`."""


def rh_to_3dgs(coeffs: np.ndarray) -> np.ndarray:
    """(K, C) RH coefficients -> 3DGS basis (degree <= 3): ``numba_kernels.sh_real.rh_to_3dgs``
    (imported here, not at module level, so that importing this module does not import numba)."""
    from numba_kernels.sh_real import rh_to_3dgs as convert

    return convert(coeffs)


threedgs_to_rh = rh_to_3dgs  # the sign flip is an involution


@dataclass
class SHProbe:
    """Radiance SH probe; see the module docstring for units and basis rules."""

    coeffs: np.ndarray  # (K, 3) float64
    basis: str  # '3dgs' (degree <= 3) or 'rh'
    center: np.ndarray | None = None  # (3,) world position, informational

    def __post_init__(self) -> None:
        self.coeffs = np.array(self.coeffs, dtype=np.float64)
        if self.coeffs.ndim != 2 or self.coeffs.shape[1] != 3:
            raise ValueError(f"probe coefficients must have shape (K, 3), got {self.coeffs.shape}")
        if sh3dgs.degree_from_num_coeffs(self.coeffs.shape[0]) > _MAX_DEGREE:
            raise ValueError(f"probe degree must be <= {_MAX_DEGREE}")
        if self.basis not in ("3dgs", "rh"):
            raise ValueError(f"probe basis must be '3dgs' or 'rh', got {self.basis!r}")
        if self.basis == "3dgs" and self.degree > 3:
            raise ValueError(f"the 3DGS SH basis stops at degree 3; a degree {self.degree} probe must be 'rh'")
        if not np.isfinite(self.coeffs).all():
            raise ValueError("probe coefficients are not finite")

    @property
    def degree(self) -> int:
        return sh3dgs.degree_from_num_coeffs(self.coeffs.shape[0])

    def rh(self) -> np.ndarray:
        """(K, 3) coefficients in the RH basis (a copy)."""
        return threedgs_to_rh(self.coeffs) if self.basis == "3dgs" else self.coeffs.copy()

    def to_3dgs(self) -> np.ndarray:
        """(K, 3) coefficients in the 3DGS basis; degree <= 3 only."""
        return self.coeffs.copy() if self.basis == "3dgs" else rh_to_3dgs(self.coeffs)

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """Radiance (..., 3) float64 arriving from unit directions (..., 3) (eq. 8)."""
        if self.basis == "3dgs":
            return sh3dgs.eval_basis(dirs, self.degree) @ self.coeffs
        from numba_kernels.sh_real import eval_basis_rh_numpy

        return eval_basis_rh_numpy(dirs, self.degree) @ self.coeffs

    def to_latlong(self, h: int = 128, w: int = 256) -> np.ndarray:
        """(h, w, 3) float32 lat-long image (``usd_gs.io.envmap`` convention)."""
        return envmap.sh_to_latlong(self.coeffs, h, w, self.basis)

    def write_latlong_exr(self, path, h: int = 128, w: int = 256):
        """Write the reconstructed environment as a lat-long OpenEXR image."""
        return envmap.write_exr(path, self.to_latlong(h, w))


def _stored(coeffs_rh: np.ndarray, center) -> SHProbe:
    degree = sh3dgs.degree_from_num_coeffs(coeffs_rh.shape[0])
    c = None if center is None else np.asarray(center, dtype=np.float64).reshape(3)
    if degree <= 3:
        return SHProbe(rh_to_3dgs(coeffs_rh), "3dgs", c)
    return SHProbe(coeffs_rh, "rh", c)


@lru_cache(maxsize=8)
def _fitter(size: int, degree: int, lam: float):
    from numba_kernels.probe_fit import CubeProbeFitter

    return CubeProbeFitter(size, degree, lam)


def fit_probe(faces: np.ndarray, degree: int = 3, lam: float = 1e-3, center=None,
              mask: np.ndarray | None = None, alpha: np.ndarray | None = None) -> SHProbe:
    """Fit an SH probe to cube faces with eq. 7 (weighted ridge least squares).

    faces: (6, S, S, 3) linear RGB radiance in the cube layout of
    ``numba_kernels.cubemap_dirs`` (OpenGL: +X, -X, +Y, -Y, +Z, -Z). degree: 0..8.
    lam: ridge weight (relative: the solid-angle Gram matrix is ~identity).
    mask: optional (6, S, S) weights in [0, 1] multiplying the texel solid angles (e.g. 0 for
    texels that saw nothing); with a mask the normal equations are rebuilt (slower).
    alpha: optional (6, S, S) coverage from the rasteriser (faces premultiplied, black
    background): texels are un-premultiplied (``rgb / alpha``) and weighted by ``alpha``, so
    what the faces did not see carries no weight (combined with ``mask`` if both are given).
    Returns the probe stored in the 3DGS basis for degree <= 3, else in the RH basis.
    """
    faces = np.asarray(faces)
    if faces.ndim != 4 or faces.shape[0] != 6 or faces.shape[1] != faces.shape[2] or faces.shape[3] != 3:
        raise UserError(f"probe fit: cube faces must have shape (6, S, S, 3), got {faces.shape}")
    if not 0 <= int(degree) <= _MAX_DEGREE:
        raise UserError(f"probe fit: SH degree must be 0..{_MAX_DEGREE}, got {degree}")
    bad = ~np.isfinite(faces)
    if bad.any():
        f, i, j, _ = np.argwhere(bad)[0]
        raise UserError(f"probe fit: cube face {int(f)} pixel (row {int(i)}, column {int(j)}) is not finite")
    size = faces.shape[1]
    if alpha is not None:
        a = np.asarray(alpha, dtype=np.float64)
        if a.shape != faces.shape[:3]:
            raise UserError(f"probe fit: alpha must have shape {faces.shape[:3]}, got {a.shape}")
        if not np.isfinite(a).all():
            raise UserError("probe fit: alpha is not finite")
        a = np.clip(a, 0.0, 1.0)
        faces = np.where(a[..., None] > 1e-6, faces / np.maximum(a, 1e-6)[..., None], 0.0)
        mask = a if mask is None else a * np.asarray(mask, dtype=np.float64)
    from numba_kernels.probe_fit import fit_sh_lstsq

    if mask is None:
        coeffs = _fitter(size, int(degree), float(lam)).fit(faces)
    else:
        from numba_kernels.cubemap_dirs import cube_face_directions, cube_face_solid_angles

        m = np.asarray(mask, dtype=np.float64)
        if m.shape != faces.shape[:3]:
            raise UserError(f"probe fit: mask must have shape {faces.shape[:3]}, got {m.shape}")
        w = cube_face_solid_angles(size) * m
        coeffs = fit_sh_lstsq(cube_face_directions(size).reshape(-1, 3), w.reshape(-1),
                              faces.reshape(-1, 3), int(degree), float(lam))
    return _stored(coeffs, center)


def render_probe_faces(gaussians, centre, size: int = 32, mask: np.ndarray | None = None,
                       dilation: float = PROBE_DILATION, supersample: int = PROBE_SUPERSAMPLE, order=None,
                       blocks=None):
    """The cube render of a probe (paper 3.4) at ``centre`` (3,) metres: six ``size``^2 faces of
    ``gaussians`` (world space; ``mask`` (N,) bool selects the Gaussians drawn, e.g. all but the
    avatar being relit), as ``(rgb, alpha, depth)`` of ``usd_gs.render.rasterize.render_cube_faces``; fit
    it with ``fit_probe(rgb, alpha=alpha)``.

    The probe measures radiance, so the display low-pass filter is off (``PROBE_DILATION`` =
    0 px^2; any other ``dilation`` is applied opacity-compensated, ``antialiased``), and the
    faces are drawn at ``supersample`` x ``size`` and box-filtered down: premultiplied rgb and
    alpha averaged, depth alpha-weighted. Supersampling integrates a small lamp over each texel
    instead of sampling it at texel centres; it is off by default (its gain and cost on the
    known-light ground truth and the demo: docs/design.md, "Probe supersampling";
    ``benchmarks/bench_lighting_limits.py`` prints them). ``order``: instead of ``mask``, the
    increasing indices of the Gaussians drawn; ``blocks``: the cull's row blocks (both as for
    ``usd_gs.render.rasterize.render_batch``: the same image)."""
    return render_probe_cubes(gaussians, [centre], size, mask, dilation, supersample, order, blocks)[0]


def render_probe_cubes(gaussians, centres, size: int = 32, mask: np.ndarray | None = None,
                       dilation: float = PROBE_DILATION, supersample: int = PROBE_SUPERSAMPLE, order=None,
                       blocks=None) -> list:
    """:func:`render_probe_faces` of the same Gaussians at each of ``centres`` (P, 3), the cubes drawn
    together (``usd_gs.render.rasterize.render_cubes``: one cull sweep for several cubes); each
    cube's ``(rgb, alpha, depth)`` bit for bit as :func:`render_probe_faces` gives it alone."""
    from usd_gs.render.rasterize import render_cubes

    k = int(supersample)
    if k < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    cubes = render_cubes(gaussians, centres, int(size) * k, mask=mask, antialiased=True, dilation=float(dilation),
                         order=order, blocks=blocks)
    if k == 1:
        return cubes

    def down(x):
        return x.reshape((6, int(size), k, int(size), k) + x.shape[3:]).mean(axis=(2, 4), dtype=np.float64)

    out = []
    for rgb, alpha, depth in cubes:
        a = down(alpha)
        ad = down(alpha * depth)
        d = np.where(a > 0.0, ad / np.where(a > 0.0, a, 1.0), 0.0)
        out.append((down(rgb).astype(np.float32), a.astype(np.float32), d.astype(np.float32)))
    return out


def probe_from_latlong(img: np.ndarray, degree: int = 3, center=None) -> SHProbe:
    """Probe by direct SH projection of a lat-long radiance image (exact pixel solid angles)."""
    return _stored(envmap.project_latlong_to_sh(img, int(degree), "rh"), center)


def hdr_dome_gaussians(hdr: np.ndarray, radius: float = 10.0, n: int = 32768, center=(0.0, 0.0, 0.0),
                       sigma_factor: float = 0.3, opacity: float = 0.99, label: str = "<hdr dome>") -> GaussianSet:
    """A sky dome of Gaussians that shows a lat-long HDR image from its centre.

    The image (``usd_gs.io.envmap`` lat-long convention) is box-filtered by the largest power-of-two
    factor that leaves >= 0.75 n pixels (and >= 8 rows); each pixel becomes one flat Gaussian on the
    sphere of ``radius`` around ``center`` at the pixel-centre direction, oriented tangentially
    (axes along phi, theta and the radius), with sigma ``sigma_factor`` x the pixel extent
    (``r sin(theta) dphi`` by ``r dtheta``), degree-0 SH with DC set so that the 3DGS colour
    ``0.5 + C0 * sh0`` equals the pixel's mean radiance, and opacity ``opacity``.

    Each Gaussian thus carries exactly its pixel's radiance and solid angle. With the default
    ``sigma_factor`` the splats barely overlap (coverage ~0.8): fit its cube-face renders with
    ``fit_probe(rgb, alpha=alpha)`` (un-premultiplied, coverage-weighted), which keeps the
    blending order of equal-depth splats from biasing bright, small light sources.
    """
    from usd_gs.gaussians import matrix_to_quaternion

    img = np.asarray(hdr, dtype=np.float32)
    h, w = img.shape[:2]
    f = 1
    def halvable(f: int) -> bool:
        return h % (2 * f) == 0 and w % (2 * f) == 0 and h // (2 * f) >= 8

    while halvable(f) and (h // (2 * f)) * (w // (2 * f)) >= 0.75 * n:
        f *= 2
    if f > 1:
        img = envmap.downsample_latlong(img, f)
    h, w = img.shape[:2]
    dirs = envmap.latlong_directions(h, w).reshape(-1, 3)
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = 2.0 * np.pi * (np.arange(w) + 0.5) / w - np.pi
    t, p = (a.reshape(-1) for a in np.meshgrid(th, ph, indexing="ij"))
    e_phi = np.stack([-np.sin(p), np.zeros_like(p), np.cos(p)], axis=1)
    e_theta = np.stack([np.cos(t) * np.cos(p), -np.sin(t), np.cos(t) * np.sin(p)], axis=1)
    rot = np.stack([e_phi, e_theta, dirs], axis=2)
    rot[np.linalg.det(rot) < 0, :, 0] *= -1.0
    r = float(radius)
    dth, dph = np.pi / h, 2.0 * np.pi / w
    k = float(sigma_factor)
    s_phi = k * r * np.maximum(np.sin(t), 0.5 * dth) * dph
    s_theta = np.full_like(t, k * r * dth)
    scales = np.stack([s_phi, s_theta, 0.1 * np.minimum(s_phi, s_theta)], axis=1)  # thin along the radius
    pos = np.asarray(center, dtype=np.float64)[None, :] + r * dirs
    sh = ((img.reshape(-1, 3).astype(np.float64) - 0.5) / sh3dgs.C0)[:, None, :]
    return GaussianSet(pos, matrix_to_quaternion(rot), scales, np.full(len(pos), float(opacity)), sh, label=label)
