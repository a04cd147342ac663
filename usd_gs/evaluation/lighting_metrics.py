"""Lighting-consistency metrics without ground truth (paper section 4.1): PAA-Y, APF-Y, NCM-ab.

Inputs are :class:`usd_gs.gaussians.GaussianSet` objects in **world space** (units of the
stage; ``meters_per_unit`` converts the neighbourhood radius given in metres).

Conventions (each choice the paper leaves open is fixed here):

- **Per-Gaussian colour** ``I_i`` (:func:`gaussian_colors`): by default the DC colour
  ``0.5 + C0 * sh[:, 0]`` (3DGS basis), which is the Gaussian's colour averaged over all
  viewing directions (bands >= 1 integrate to zero over the sphere), so the metrics do not
  depend on a camera. ``view_from=p`` instead evaluates the full SH seen from the point
  ``p`` (e.g. a camera), direction ``x_i - p``. Negative colours are clamped to 0.
- **Luminance** CIE Y and **CIE-Lab** (D65) of linear Rec.709 RGB (``usd_gs.evaluation.colorimetry``).
- **Pseudo-normals** (:func:`pseudo_normals`): local PCA of the Gaussian centres within
  ``radius`` (default: ``numba_kernels.normals.estimate_radius``, ~24 neighbours), each
  neighbour weighted by ``opacity_j * exp(-d^2 / (2 (radius/2)^2))`` (alpha and distance);
  the normal is the smallest-eigenvalue eigenvector. Sign: toward a point (scene
  neighbourhood: toward the avatar centroid, the side the avatar sees), or agreeing with
  reference normals (avatars: the outward smallest-axis normals of
  ``numba_kernels.normals.gaussian_normals``, the ones the relighting uses).
- **Irradiance model** ``E(n; c) = sum_{l<=3} c_lm Y_lm(n)`` in the real orthonormal
  Ramamoorthi-Hanrahan SH basis (``numba_kernels.sh_real``), 16 coefficients.
- **Factorisation** ``Y_i ~ alpha_i E(n_i; c)`` (:func:`fit_factorization`). Two ambiguities:
  (1) global scale: ``(k alpha, c / k)`` fits equally, so ``c`` is reported normalised to
  ``c_00 = 1`` (``E / c_00 Y_00`` is irradiance relative to its spherical mean; exposure and
  mean albedo drop out); (2) with a free ``alpha_i`` per Gaussian *any* ``c`` with ``E > 0``
  fits exactly (``alpha_i = Y_i / E_i``), so ``c`` is not identifiable without a prior on
  ``alpha``. We use a shrinkage prior: the objective is
  ``sum_i huber(Y_i - alpha_i E_i) + lam * m^2 * sum_i (alpha_i - mean(alpha))^2``
  (``m`` = median ``E`` over the fit, ``lam`` = ``alpha_prior``, default 1: the lighting
  explains luminance variation with orientation, the scales absorb what it cannot), solved
  by alternating a Huber least-squares step on ``c`` (``scipy.optimize.least_squares``,
  ``loss='huber'``, ``f_scale = 1.345 * 1.4826 * MAD``) with the closed-form, IRLS-weighted
  step on ``alpha`` (clipped at 0), with a ridge :data:`RIDGE` on ``c_lm, l >= 1`` (normals
  that cover only part of the sphere, e.g. a floor and two walls, leave the rest at 0) and 5 %
  trimming (the Gaussians with the largest absolute residuals do not enter the next
  ``c`` step). ``alpha_prior=inf`` is one common scale (plain robust regression).
- **PAA-Y** ``= ||P (k_a c_avatar - k_s c_scene)||_1`` (:func:`paa_y`): ``P`` the projector onto
  the coefficients the neighbourhood's normals determine (:func:`identified_subspace`), each
  vector rescaled to mean irradiance ``Y_00`` over those normals (``k = Y_00 / mean_i E(n_i; c)``).
  With normals spread over the whole sphere (SH rank 16) ``P = I`` and ``k ~ 1``: the paper's L1
  distance of the ``c_00``-normalised vectors. A floor and a wall determine a few combinations
  only (a floor alone: one, its level, which the normalisation removes: PAA-Y 0), and the
  ridge's zeros elsewhere are no measurement: with the plain L1 an unlit, flat avatar scored
  better than the exact known-light colours (0.68 against 1.76 in the open known-light scene).
- **APF-Y**: affine ``(s, b)`` fit of ``Y_a ~ s E(n_a; c_scene) + b`` (Huber, 5 % trimming),
  then the mean absolute residual over **all** avatar Gaussians (luminance units, white = 1).
- **NCM-ab**: 1-Wasserstein distance between the (a*, b*) point clouds of the avatar and the
  neighbourhood (Euclidean ground cost, uniform weights, exact LP of POT ``ot.emd2``), each
  cloud subsampled without replacement to ``max_points`` with a fixed seed.
- **Neighbourhood** ``N``: scene Gaussians within ``radius`` metres (default 1.5, the paper's
  range is [1, 2]) of the avatar's opacity-weighted centroid that the centroid sees
  (``usd_gs.evaluation.point_visibility.visible_from``: depth test against the cube render of the
  neighbourhood, 3 cm tolerance). The hidden ones (the undersides and far sides of props)
  face away from the avatar: the "face the centroid" sign rule flips their pseudo-normals, and
  in the known-light scene with props their 6 % turned ``c_scene``'s vertical lobe around
  (-0.10 against +0.44 with the true normals).
- **Deltas**: ``delta = relit - orig`` (the paper's definition in 4.1: negative is an
  improvement) and ``improvement = orig - relit`` (the sign printed in the paper's table 1:
  positive is an improvement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from numba_kernels.grid_neighbours import build_grid, radius_neighbours
from numba_kernels.normals import estimate_radius, gaussian_normals
from numba_kernels.sh_real import eval_basis_rh_numpy
from usd_gs import sh3dgs
from usd_gs.errors import UserError
from usd_gs.evaluation.colorimetry import luminance, rgb_to_lab
from usd_gs.evaluation.point_visibility import visible_from
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid

SH_ORDER = 3
HUBER_K = 1.345
TRIM = 0.05
METRICS = ("paa_y", "apf_y", "ncm_ab")
PAA_MIN_RANK = 4
"""PAA-Y needs the scene neighbourhood's normals to determine at least this many SH coefficients
(:func:`sh_rank`; 4 = the l <= 1 band, the normals span three directions): below it the
neighbourhood's luminance says nothing about where the light comes from that the unknown
albedo does not explain as well (a floor alone: only its level; a floor and one wall: one ratio,
the two albedos' as much as the light's). Measured on the demo: CesiumMan's neighbourhood is a
floor (rank 1) or floor and wall (rank 2), and the room's *own* shading model applied to
CesiumMan (the exact lighting, ``usd_gs.demo.room``) scores PAA-Y 0.364 -> 0.497 at rank 2
(``benchmarks/bench_lighting_limits.py``), worse than the unlit avatar. Such frames report
PAA-Y as NaN (undetermined) and are left out of the means."""
RIDGE = 1e-2
"""Ridge on ``c_lm, l >= 1`` relative to the data (a coefficient of 1 costs ``RIDGE`` x the summed
squared luminance): with 1e-3 a floor-only neighbourhood overfits the few-degree noise of its
pseudo-normals (``||c||_1`` ~ 4); with 1e-2 it comes out flat, as it should."""


# ----------------------------------------------------------------------------- colours
def gaussian_colors(g: GaussianSet, view_from=None) -> np.ndarray:
    """Per-Gaussian linear RGB (N, 3) float64, clamped at 0 (see the module docstring)."""
    if view_from is None:
        col = 0.5 + sh3dgs.C0 * g.sh[:, 0, :].astype(np.float64)
    else:
        d = g.positions.astype(np.float64) - np.asarray(view_from, np.float64).reshape(1, 3)
        ln = np.linalg.norm(d, axis=1, keepdims=True)
        d = np.where(ln > 0, d / np.where(ln > 0, ln, 1.0), np.array([0.0, 0.0, 1.0]))
        col = sh3dgs.eval_color(g.sh, d)
    return np.maximum(col, 0.0)


# ----------------------------------------------------------------------------- normals
def weighted_local_pca(positions, weights, radius: float, kernel_sigma: float = 0.5):
    """Alpha/distance-weighted local PCA of point positions.

    positions (N, 3), weights (N,) >= 0 (opacities). For each point i, the neighbours j
    within ``radius`` (itself included; ``numba_kernels.grid_neighbours``) get weight
    ``weights_j * exp(-|x_j - x_i|^2 / (2 (kernel_sigma * radius)^2))``. Returns
    ``(axis (N, 3) float64 unit smallest-eigenvalue eigenvectors (sign arbitrary),
    count (N,) int64 neighbours)``; the axis is meaningless where count < 3.
    """

    pos = np.ascontiguousarray(positions, np.float64).reshape(-1, 3)
    w_pt = np.maximum(np.asarray(weights, np.float64).reshape(-1), 0.0)
    n = pos.shape[0]
    if n == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    offsets, idx = radius_neighbours(build_grid(pos, radius), pos, radius)
    count = np.diff(offsets)
    owner = np.repeat(np.arange(n), count)
    d = pos[idx] - pos[owner]
    h2 = 2.0 * (kernel_sigma * radius) ** 2
    w = w_pt[idx] * np.exp(-np.einsum("ij,ij->i", d, d) / h2) + 1e-12
    wsum = np.bincount(owner, w, minlength=n)
    mean = np.stack([np.bincount(owner, w * d[:, a], minlength=n) for a in range(3)], axis=1) / wsum[:, None]
    dc = d - mean[owner]
    cov = np.empty((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(owner, w * dc[:, a] * dc[:, b], minlength=n) / wsum
    return np.linalg.eigh(cov)[1][:, :, 0], count


def pseudo_normals(g: GaussianSet, radius: float | None = None, toward=None, reference=None) -> np.ndarray:
    """Unit pseudo-normals (N, 3) float64 of a Gaussian set (module docstring).

    radius: PCA neighbourhood (scene units; None: automatic). Sign: ``toward`` (3,) point the
    normals face; else ``reference`` (N, 3) normals they agree with; else the outward
    smallest-axis normals of ``gaussian_normals``, also used where PCA has < 3 neighbours.
    """

    pos = g.positions.astype(np.float64)
    r = float(estimate_radius(pos)) if radius is None else float(radius)
    axis, count = weighted_local_pca(pos, g.opacities, r)
    if reference is None and (toward is None or (count < 3).any()):
        reference = gaussian_normals(g.positions, g.orientations, g.scales, g.opacities, radius=r)
    if reference is not None:
        ref = np.asarray(reference, np.float64).reshape(-1, 3)
        axis = np.where((count < 3)[:, None], ref, axis)
    if toward is not None:
        s = np.einsum("ij,ij->i", axis, np.asarray(toward, np.float64).reshape(1, 3) - pos)
    else:
        s = np.einsum("ij,ij->i", axis, ref)
    axis = axis * np.where(s < 0, -1.0, 1.0)[:, None]
    return axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-300)


def sh_basis(normals) -> np.ndarray:
    """(N, 16) real RH SH basis of order :data:`SH_ORDER` at unit normals (N, 3)."""

    return eval_basis_rh_numpy(np.asarray(normals, np.float64), SH_ORDER)


def identified_subspace(normals, rel: float = 1e-2) -> np.ndarray:
    """(16, 16) orthogonal projector onto the SH coefficients the normals (N, 3) determine: the
    eigenvectors of the Gram matrix ``B^T B / N`` with eigenvalues above ``rel`` x ``1 / (4 pi)``
    (the value for normals spread over the sphere). Identity for normals over the whole sphere;
    a floor alone determines only the mean (and whatever its few-degree spread resolves)."""
    b = sh_basis(normals)
    k = (SH_ORDER + 1) ** 2
    if b.shape[0] == 0:
        return np.zeros((k, k))
    w, v = np.linalg.eigh(b.T @ b / b.shape[0])
    u = v[:, w > rel / (4.0 * np.pi)]
    return u @ u.T


def sh_rank(normals, rel: float = 1e-2) -> int:
    """How many of the 16 SH coefficients the normals determine (the rank of
    :func:`identified_subspace`). A floor alone gives 1; below 16, PAA-Y compares the lighting
    only where the scene shows it."""
    return int(round(float(np.trace(identified_subspace(normals, rel)))))


def irradiance(normals, coeffs) -> np.ndarray:
    """``E(n; c)`` (N,) for unit normals (N, 3) and RH coefficients (16,)."""
    return sh_basis(normals) @ np.asarray(coeffs, np.float64)


# ----------------------------------------------------------------------------- robust fits
def _huber_scale(res: np.ndarray, ref: np.ndarray) -> float:
    mad = float(np.median(np.abs(res - np.median(res)))) * 1.4826
    floor = 1e-6 * (float(np.mean(np.abs(ref))) + 1e-12)
    return HUBER_K * max(mad, floor)


def _trimmed(res: np.ndarray, trim: float) -> np.ndarray:
    """Bool mask keeping the (1 - trim) share of the smallest absolute residuals."""
    if trim <= 0 or res.size < 20:
        return np.ones(res.size, bool)
    return np.abs(res) <= np.quantile(np.abs(res), 1.0 - trim)


def _huber_lstsq(a: np.ndarray, y: np.ndarray, x0: np.ndarray, f_scale: float, extra_rows=None) -> np.ndarray:
    """argmin_x sum huber(a x - y) (+ plain rows ``extra_rows @ x``), scipy ``least_squares``."""
    from scipy.optimize import least_squares

    if extra_rows is not None:
        a = np.vstack([a, extra_rows])
        y = np.concatenate([y, np.zeros(extra_rows.shape[0])])
    sol = least_squares(lambda x: a @ x - y, x0, jac=lambda x: a, loss="huber", f_scale=f_scale, method="trf",
                        x_scale="jac", max_nfev=50)
    return sol.x


@dataclass
class FactorizationFit:
    """Result of :func:`fit_factorization`: ``coeffs`` (16,) RH, normalised to ``c_00 = 1``;
    ``scales`` (N,) the ``alpha_i >= 0`` with ``Y_i ~ alpha_i E(n_i; coeffs)``; ``kept`` (N,)
    bool, not trimmed in the last step; ``residual`` (N,) ``Y - alpha E``."""

    coeffs: np.ndarray
    scales: np.ndarray
    kept: np.ndarray
    residual: np.ndarray


def fit_factorization(y, normals, alpha_prior: float = 1.0, ridge: float = RIDGE, trim: float = TRIM,
                      n_iter: int = 8, label: str = "Gaussians") -> FactorizationFit:
    """Robust alternating fit of ``Y_i ~ alpha_i E(n_i; c)``, ``alpha_i >= 0`` (module docstring).

    y (N,) luminance >= 0, normals (N, 3) unit. ``alpha_prior`` (lam) weights the pull of
    the scales toward their mean (``inf``: one common scale). Raises ``UserError`` for fewer
    than 16 Gaussians or a fit whose mean irradiance ``c_00`` is not positive.
    """
    y = np.asarray(y, np.float64).reshape(-1)
    basis = sh_basis(normals)
    n, k = basis.shape
    if n < k:
        raise UserError(f"{label}: {n} Gaussians, the order-{SH_ORDER} SH factorisation needs at least {k}")
    if not np.isfinite(y).all():
        raise UserError(f"{label}: luminance is not finite")
    alpha = np.ones(n)
    c = np.zeros(k)
    kept = np.ones(n, bool)
    res = y.copy()
    f_scale = _huber_scale(y, y)
    for it in range(int(n_iter)):
        a = alpha[kept, None] * basis[kept]
        abar = float(np.mean(alpha[kept]))
        rows = math.sqrt(ridge * kept.sum()) * abar * np.eye(k)[1:] * sh_basis(np.array([[0.0, 0.0, 1.0]]))[0, 0]
        if it == 0:
            c = np.linalg.lstsq(np.vstack([a, rows]), np.concatenate([y[kept], np.zeros(k - 1)]), rcond=None)[0]
        else:
            c = _huber_lstsq(a, y[kept], c, f_scale, rows)
        if not c[0] > 0:
            raise UserError(f"{label}: the SH irradiance fit has a non-positive mean (c_00 = {c[0]:.3g}); "
                            "the luminance does not follow the pseudo-normals")
        alpha *= c[0]
        c = c / c[0]
        e = basis @ c
        res = y - alpha * e
        f_scale = _huber_scale(res[kept], y)
        if math.isfinite(alpha_prior):
            wgt = np.minimum(1.0, f_scale / np.maximum(np.abs(res), 1e-300))
            m2 = float(np.median(np.abs(e[kept]))) ** 2
            abar = float(np.mean(alpha[kept]))
            alpha = np.maximum((wgt * e * y + alpha_prior * m2 * abar) / (wgt * e * e + alpha_prior * m2), 0.0)
        else:
            alpha = np.full(n, float(np.mean(alpha)))
        res = y - alpha * e
        kept = _trimmed(res, trim)
    return FactorizationFit(c, alpha, kept, res)


def fit_affine(x, y, trim: float = TRIM) -> tuple[float, float]:
    """Robust ``y ~ s x + b``: least squares, 5 % trimming, then Huber on the kept points."""
    x = np.asarray(x, np.float64).reshape(-1)
    y = np.asarray(y, np.float64).reshape(-1)
    a = np.stack([x, np.ones_like(x)], axis=1)
    p = np.linalg.lstsq(a, y, rcond=None)[0]
    kept = _trimmed(y - a @ p, trim)
    p = _huber_lstsq(a[kept], y[kept], p, _huber_scale(y[kept] - a[kept] @ p, y))
    return float(p[0]), float(p[1])


# ----------------------------------------------------------------------------- the metrics
def paa_y(c_avatar, c_scene, scene_normals=None) -> float:
    """PAA-Y of two coefficient vectors (16,) (RH, normalised to ``c_00 = 1``).

    ``scene_normals`` None: the plain ``||c_avatar - c_scene||_1``. Given (M, 3), the
    comparison is restricted to what those normals determine (module docstring): ``P`` =
    :func:`identified_subspace`, each vector rescaled by ``k = Y_00 / mean_i E(n_i; c)`` (its
    mean irradiance over the scene's normals; ``k = 1`` for flat lighting, and what the
    neighbourhood measures, while ``c_00`` is not, for a floor alone) and
    ``||P (k_a c_avatar - k_s c_scene)||_1`` returned. Raises ``UserError`` when a mean
    irradiance is not positive.
    """
    ca = np.asarray(c_avatar, np.float64)
    cs = np.asarray(c_scene, np.float64)
    if scene_normals is None:
        return float(np.abs(ca - cs).sum())
    return _paa_restricted(ca, cs, identified_subspace(scene_normals), sh_basis(scene_normals).mean(axis=0))


def _paa_restricted(ca: np.ndarray, cs: np.ndarray, identified: np.ndarray, mean_basis: np.ndarray) -> float:
    """:func:`paa_y` with the scene normals' projector (16, 16) and mean SH basis (16,) given."""
    y00 = float(sh_basis(np.array([[0.0, 0.0, 1.0]]))[0, 0])
    ka, ks = float(mean_basis @ ca), float(mean_basis @ cs)
    if not (ka > 0 and ks > 0):
        raise UserError(f"PAA-Y: a mean irradiance over the scene's normals is not positive ({ka:.3g}, {ks:.3g})")
    return float(np.abs(identified @ (ca * (y00 / ka) - cs * (y00 / ks))).sum())


def apf_y(y_avatar, normals_avatar, c_scene, trim: float = TRIM) -> tuple[float, float, float]:
    """APF-Y and its calibration: ``(mean |Y - (s E + b)|, s, b)`` with ``E = E(n_a; c_scene)``."""
    e = irradiance(normals_avatar, c_scene)
    y = np.asarray(y_avatar, np.float64).reshape(-1)
    s, b = fit_affine(e, y, trim)
    return float(np.mean(np.abs(y - (s * e + b)))), s, b


def _subsample(x: np.ndarray, max_points: int, seed: int) -> np.ndarray:
    if x.shape[0] <= max_points:
        return x
    return x[np.sort(np.random.default_rng(seed).choice(x.shape[0], max_points, replace=False))]


def emd_2d(p, q, max_points: int = 2000, seed: int = 0) -> float:
    """1-Wasserstein distance between two point clouds (n, 2) and (m, 2) with uniform weights.

    Euclidean ground cost, exact network-simplex LP (POT ``ot.emd2``). Clouds larger than
    ``max_points`` are subsampled without replacement (``numpy`` generator seeded ``seed``).
    """
    import ot

    p = _subsample(np.asarray(p, np.float64).reshape(-1, 2), int(max_points), seed)
    q = _subsample(np.asarray(q, np.float64).reshape(-1, 2), int(max_points), seed + 1)
    if len(p) == 0 or len(q) == 0:
        raise UserError("NCM-ab: an empty point cloud has no distance")
    cost = ot.dist(p, q, metric="euclidean")
    return float(ot.emd2(np.full(len(p), 1.0 / len(p)), np.full(len(q), 1.0 / len(q)), cost, numItermax=10_000_000))


def ncm_ab(rgb_avatar, rgb_scene, max_points: int = 2000, seed: int = 0) -> float:
    """EMD between the (a*, b*) chromaticities of two sets of linear RGB colours (n, 3), (m, 3)."""
    return emd_2d(rgb_to_lab(rgb_avatar)[:, 1:], rgb_to_lab(rgb_scene)[:, 1:], max_points, seed)


# ----------------------------------------------------------------------------- per frame
@dataclass
class SceneLighting:
    """What the metrics need from the scene neighbourhood of one avatar at one frame."""

    centre: np.ndarray  # (3,) avatar centroid
    index: np.ndarray  # (M,) indices of the neighbourhood Gaussians in the scene set
    rgb: np.ndarray  # (M, 3)
    normals: np.ndarray  # (M, 3)
    fit: FactorizationFit
    identified: np.ndarray  # (16, 16) :func:`identified_subspace` of the neighbourhood's normals
    mean_basis: np.ndarray  # (16,) their mean SH basis (PAA-Y's level normalisation)
    hidden: int  # Gaussians within the radius but hidden from the centre (left out of N)

    @property
    def sh_rank(self) -> int:
        """:func:`sh_rank` of the neighbourhood's normals (16: PAA-Y is the paper's plain L1)."""
        return int(round(float(np.trace(self.identified))))


def scene_lighting(scene: GaussianSet, centre, radius_m: float = 1.5, meters_per_unit: float = 1.0,
                   view_from=None, normal_radius: float | None = None, alpha_prior: float = 1.0,
                   visible_only: bool = True) -> SceneLighting:
    """Neighbourhood ``N`` of ``centre`` (scene units): the scene Gaussians within ``radius_m``
    metres that the centre sees (``visible_only``: ``usd_gs.evaluation.point_visibility.visible_from``,
    3 cm tolerance), their colours, pseudo-normals (PCA over all Gaussians within the radius,
    signed to face ``centre``) and the fitted ``c_scene``."""

    if not 1.0 <= radius_m <= 2.0:
        raise UserError(f"neighbourhood radius {radius_m} m is outside the paper's range [1, 2] m")
    centre = np.asarray(centre, np.float64).reshape(3)
    r = radius_m / float(meters_per_unit)
    d = np.linalg.norm(scene.positions.astype(np.float64) - centre, axis=1)
    index = np.flatnonzero(d <= r)
    if index.size < 16:
        raise UserError(f"{scene.label}: only {index.size} scene Gaussians within {radius_m} m of the avatar "
                        f"centroid {np.round(centre, 3).tolist()}; the metrics need at least 16")
    nb = scene.subset(index)
    normals = pseudo_normals(nb, normal_radius, toward=centre)
    seen = visible_from(nb, centre, abs_tol=0.03 / float(meters_per_unit)) if visible_only \
        else np.ones(index.size, bool)
    if seen.sum() < 16:
        raise UserError(f"{scene.label}: the avatar centroid {np.round(centre, 3).tolist()} sees only "
                        f"{int(seen.sum())} of the {index.size} scene Gaussians within {radius_m} m; "
                        "the metrics need at least 16")
    index, normals = index[seen], normals[seen]
    rgb = gaussian_colors(scene.subset(index), view_from)
    fit = fit_factorization(luminance(rgb), normals, alpha_prior, label=f"{scene.label} neighbourhood")
    return SceneLighting(centre, index, rgb, normals, fit, identified_subspace(normals),
                         sh_basis(normals).mean(axis=0), int((~seen).sum()))


def avatar_metrics(rgb_avatar, normals_avatar, scene: SceneLighting, alpha_prior: float = 1.0,
                   max_points: int = 2000, seed: int = 0, label: str = "avatar") -> dict:
    """PAA-Y, APF-Y, NCM-ab of one avatar colouring against a scene neighbourhood.

    Returns ``{'paa_y', 'apf_y', 'ncm_ab', 'c_avatar' (16,), 'apf_scale', 'apf_offset'}``;
    ``paa_y`` is NaN when the neighbourhood's SH rank is below :data:`PAA_MIN_RANK`.
    """
    y = luminance(rgb_avatar)
    fit = fit_factorization(y, normals_avatar, alpha_prior, label=label)
    apf, s, b = apf_y(y, normals_avatar, scene.fit.coeffs)
    paa = (_paa_restricted(fit.coeffs, scene.fit.coeffs, scene.identified, scene.mean_basis)
           if scene.sh_rank >= PAA_MIN_RANK else float("nan"))
    return {"paa_y": paa, "apf_y": apf,
            "ncm_ab": ncm_ab(rgb_avatar, scene.rgb, max_points, seed), "c_avatar": fit.coeffs,
            "apf_scale": s, "apf_offset": b}


def lighting_consistency(orig: GaussianSet, relit: GaussianSet, scene: GaussianSet, radius_m: float = 1.5,
                         meters_per_unit: float = 1.0, view_from=None, alpha_prior: float = 1.0,
                         max_points: int = 2000, seed: int = 0, avatar_normals=None,
                         visible_only: bool = True) -> dict:
    """All three 4.1 metrics for the original and the relit colouring of one avatar at one frame.

    orig / relit: the same avatar Gaussians (same positions) with original and relit SH;
    scene: the scene Gaussians (world space). ``avatar_normals`` (N, 3) overrides the pseudo-
    normals of the avatar; ``visible_only``: see :func:`scene_lighting`. Returns ``{'orig': {...},
    'relit': {...}, 'delta': {m: relit - orig}, 'improvement': {m: orig - relit}, 'c_scene' (16,),
    'centre' (3,), 'n_avatar', 'n_scene'}``
    with ``m`` in :data:`METRICS`, ``'scene_sh_rank'`` (:func:`sh_rank`) and ``'n_hidden'`` (scene
    Gaussians within the radius hidden from the centroid, not in ``N``); lower metric values
    are better.
    """

    if orig.count != relit.count:
        raise UserError(f"{relit.label}: relit avatar has {relit.count} Gaussians, the original {orig.count}")
    centre = alpha_weighted_centroid(orig)
    sc = scene_lighting(scene, centre, radius_m, meters_per_unit, view_from, alpha_prior=alpha_prior,
                        visible_only=visible_only)
    nrm = pseudo_normals(orig) if avatar_normals is None else np.asarray(avatar_normals, np.float64)
    out = {k: avatar_metrics(gaussian_colors(g, view_from), nrm, sc, alpha_prior, max_points, seed,
                             label=f"{g.label} ({k})") for k, g in (("orig", orig), ("relit", relit))}
    out["delta"] = {m: out["relit"][m] - out["orig"][m] for m in METRICS}
    out["improvement"] = {m: out["orig"][m] - out["relit"][m] for m in METRICS}
    out.update(c_scene=sc.fit.coeffs, centre=centre, n_avatar=int(orig.count), n_scene=int(sc.index.size),
               scene_sh_rank=sc.sh_rank, n_hidden=sc.hidden)
    return out


def summarize(results: list[dict]) -> dict:
    """Mean over a list of :func:`lighting_consistency` results: ``{'orig', 'relit', 'delta',
    'improvement'}`` each ``{metric: mean}`` over the frames where the metric is determined
    (NaN if none), plus ``'count'`` (frames) and ``'determined'`` ``{metric: frames}``."""
    out = {"count": len(results)}
    for part in ("orig", "relit", "delta", "improvement"):
        out[part] = {}
        for m in METRICS:
            v = np.array([r[part][m] for r in results], np.float64)
            out[part][m] = float(v[np.isfinite(v)].mean()) if np.isfinite(v).any() else float("nan")
    out["determined"] = {m: int(sum(np.isfinite(r["relit"][m]) for r in results)) for m in METRICS}
    return out



__all__ = ["METRICS", "FactorizationFit", "SceneLighting", "apf_y", "avatar_metrics", "emd_2d", "fit_affine",
           "fit_factorization", "gaussian_colors", "identified_subspace", "irradiance", "lighting_consistency",
           "ncm_ab", "paa_y", "pseudo_normals", "scene_lighting", "sh_basis",
           "sh_rank", "summarize", "weighted_local_pca"]
