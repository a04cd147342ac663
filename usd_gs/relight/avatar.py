"""The main job's relighting of one avatar or object: probe render, probe fit, direct lights, colour factor.

Irradiance at Gaussian i (position x_i, unit outward normal n_i), per channel, linear units:

    E_i = sum_l E_l(x_i, n_i) V_l(x_i) + E_ind(x_i, n_i)

- ``E_l``: the direct term of every modelled light that is not a dome (``usd_gs.relight.direct``),
  ``V_l`` its visibility in [0, 1] from the project's DGSMs (the static scene's, the other prims',
  and the prim's own for self-shadowing, from distant lights by default: ``ShotProcessor._shadow_pass``
  and ``_self_points``). A light the scene
  blocks completely removes only its own share: the indirect term stays.
- ``E_ind = pi s(n)``: eq. 7-10 on the probe render of everything but the prim (and but the
  Gaussians that make up a modelled light: the caller's ``mask``, no double counting), at the
  prim's alpha-weighted centroid ``c`` and, with ``probe_points`` > 1, at parallax-corrected probe
  points (``usd_gs.relight.parallax``). The render is decoded to linear radiance first
  (``usd_gs.colorspace``: texels un-premultiplied, decoded, re-premultiplied).
- **Unobserved directions** (texel coverage alpha < :data:`OBSERVED_ALPHA`) are filled, never
  black: a texel's unobserved share ``u = clip((OBSERVED_ALPHA - alpha) / OBSERVED_ALPHA, 0, 1)``
  (1 where nothing was drawn, 0 from ``OBSERVED_ALPHA`` up: a surface's own coverage deficit,
  0.95-0.999 on dense captures, is not a hole) takes the radiance of the shot's dome lights in that direction
  (``DomeLight`` / ``DomeLight_1``: their texture or uniform colour times intensity; the scene
  in front of the dome occludes it as the probe sees it) when there is one; otherwise (a closed
  capture, or one without an estimated sky) the coverage-weighted mean linear radiance of the
  texels the probe did observe, in every direction (a uniform ambient fill). The fill lies at
  infinity: its SH is added unchanged to every parallax probe.

Relit colour (``E_ref``, the paper's gamma made explicit): captured colours are taken to be lit by
``E_ref = pi / gamma`` (``gamma`` = ``relight_gamma``, default 1): a capture's colour is its albedo
under a uniform environment of radiance 1, the same rule by which a capture's own Lambertian
surfaces show ``albedo E / pi``. So an avatar placed in the capture's light shows ``albedo E /
pi``, as bright as a scene surface of the same albedo in that light:

    linear relit = linear captured x E / E_ref      (per channel, clipped to [0, t_max])

A prim with an albedo (``appearance['albedo']`` (N, 3) linear, from ``primvars:usdgs:albedo``)
is relit as ``gamma albedo E / pi``; one with RGCA ZH appearance (``appearance['zh_albedo']``,
``'zh_color'``, optional ``'zh_mono'``) through the ZH transfer (``numba_kernels.zh_transfer``)
under the probe plus each light as a delta of radiance ``E_l V_l`` from its direction (from ``c``).
Colours are decoded with ``opts.color_space`` ('srgb' default, 'linear') and re-encoded; the
result is returned as a per-channel factor on the prim's displayed DC colour
(``usd_gs.colorspace.display_factor``), which the main job multiplies into every SH band.

**A shot without any light** (none on the stage, none estimated, no dome): the light that lit the
capture is not in it (a daylight capture of a closed set, lit from behind the camera), so the
probe alone sees only what that light left on the surfaces, often a dark backdrop, and the
absolute rule above would turn an avatar nearly black. The main job then keeps each relit prim's
captured mean brightness (``keep_level``: the relit linear colours scaled to the captured ones'
opacity-weighted mean luminance) and the probe shades it by direction and colour only.

Both ``ShotProcessor`` and the ground truths (``usd_gs.evaluation.relight_groundtruth``,
``usd_gs.evaluation.outdoor_groundtruth``) call :func:`relight_factors`, so the measured accuracy
is the main job's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from numba_kernels.cubemap_dirs import cube_face_directions, cube_face_solid_angles
from numba_kernels.sh_real import eval_basis_rh_numpy
from numba_kernels.zh_transfer import zh_diffuse_color
from usd_gs import sh3dgs
from usd_gs.colorspace import LUMA, display_factor, from_linear, to_linear
from usd_gs.io import envmap
from usd_gs.relight.direct import direct_factors, direct_irradiance, light_direction
from usd_gs.relight.parallax import cube_texels, reprojected_probes
from usd_gs.relight.probe import PROBE_DILATION, SHProbe, fit_probe, render_probe_faces
from usd_gs.relight.transfer import relight_scale

OBSERVED_ALPHA = 0.9
"""Texel coverage from which a probe direction counts as observed (module docstring). Measured on the
known-light ground truth (lamp, no props, default size): filling the whole ``1 - alpha`` of texels
with alpha 0.95-1 (the rendered dome's gaps) with the observed mean costs 1.5 dB (30.4 against
31.9 dB)."""


def unobserved_share(alpha: np.ndarray) -> np.ndarray:
    """(6, S, S) share of each texel that the probe did not observe (module docstring)."""
    a = np.clip(np.asarray(alpha, np.float64), 0.0, 1.0)
    return np.clip((OBSERVED_ALPHA - a) / OBSERVED_ALPHA, 0.0, 1.0)


def linear_faces(rgb: np.ndarray, alpha: np.ndarray, space: str) -> np.ndarray:
    """Premultiplied cube faces (6, S, S, 3) with their un-premultiplied colours decoded to
    linear radiance (``space``), premultiplied again: what the scene contributes per texel."""
    a = np.clip(np.asarray(alpha, np.float64), 0.0, 1.0)[..., None]
    if space == "linear":
        return np.asarray(rgb, np.float64)
    col = np.where(a > 1e-6, np.asarray(rgb, np.float64) / np.maximum(a, 1e-6), 0.0)
    return to_linear(col, space) * a


def dome_radiance(domes, dirs: np.ndarray) -> np.ndarray:
    """(..., 3) summed linear radiance of dome lights (``ShotLight`` kind 'dome') from world
    directions ``dirs`` (..., 3): ``color * intensity * texture(axes^T dir)`` (uniform without a
    texture)."""

    d = np.asarray(dirs, np.float64)
    out = np.zeros(d.shape[:-1] + (3,))
    for lt in domes:
        scale = np.asarray(lt.color, np.float64) * float(lt.intensity)
        if lt.env is None:
            out += scale
        else:
            local = d @ np.asarray(lt.axes, np.float64)  # rows: axes^T d
            out += envmap.latlong_lookup(lt.env, local) * scale
    return out


def fill_radiance(faces_lin: np.ndarray, alpha: np.ndarray, domes) -> np.ndarray:
    """(6, S, S, 3) linear radiance for the unobserved share of each texel (module docstring):
    the domes', or the coverage-weighted mean of what was observed."""

    size = faces_lin.shape[1]
    if domes:
        return dome_radiance(domes, cube_face_directions(size))
    a = np.clip(np.asarray(alpha, np.float64), 0.0, 1.0)
    w = cube_face_solid_angles(size) * a
    tot = float(w.sum())
    # faces_lin is premultiplied: the coverage-weighted mean of the un-premultiplied radiance
    mean = (faces_lin * cube_face_solid_angles(size)[..., None]).reshape(-1, 3).sum(axis=0) / tot if tot > 0 else \
        np.zeros(3)
    return np.broadcast_to(mean, faces_lin.shape).copy()


def _fill_sh(fill: np.ndarray, alpha: np.ndarray, degree: int) -> np.ndarray:
    """(K, 3) RH SH projection of ``unobserved_share(alpha) * fill`` over the cube's texels."""

    size = fill.shape[1]
    w = (cube_face_solid_angles(size) * unobserved_share(alpha)).reshape(-1)
    live = w > 0
    if not live.any():
        return np.zeros(((degree + 1) ** 2, 3))
    d = cube_face_directions(size).reshape(-1, 3)[live]
    return eval_basis_rh_numpy(d, degree).T @ (fill.reshape(-1, 3)[live] * w[live, None])


def dc_colors(g) -> np.ndarray:
    """(N, 3) float64 displayed DC colour ``0.5 + C0 sh0`` (view-independent part)."""
    return 0.5 + sh3dgs.C0 * np.asarray(g.sh[:, 0, :], np.float64)


@dataclass
class ProbeTransfer:
    """What :func:`relight_factors` needs that no shadow map changes (:func:`probe_transfer`):
    ``probe`` the stored probe (linear radiance, fill included, degree ``probe_degree``),
    ``transfer`` the probe the ZH transfer reads (degree ``transfer_degree``; None unless the prim
    carries ZH fields), ``scale`` the per-Gaussian indirect factor (N, 3) (None for a ZH prim),
    ``irradiance`` each light's unshadowed direct irradiance (N, 3) float64
    (``usd_gs.relight.direct.direct_irradiance``; None for a dome, and the whole list None for a
    ZH prim) and ``captured_linear`` the displayed DC colours in linear units (N, 3) float64
    (``colorspace.to_linear``; None for a ZH prim)."""

    probe: SHProbe
    transfer: SHProbe | None
    scale: np.ndarray | None
    irradiance: list | None = None
    captured_linear: np.ndarray | None = None


def probe_transfer(g, everything, mask: np.ndarray, centre, normals: np.ndarray, blend, opts,
                   dilation: float = PROBE_DILATION, lights=(), appearance: dict | None = None,
                   far=None) -> ProbeTransfer:
    """What :func:`relight_factors` (its arguments, without ``visibility``) computes that no shadow
    map changes: the probe render of ``everything`` where ``mask`` at ``centre``, its fill from the
    domes among ``lights``, the fitted probe and the transfer to every Gaussian, and the direct
    lights' unshadowed irradiance and the captured colours in linear units (:class:`ProbeTransfer`).
    It does not depend on any shadow map, so a caller may run it while the frame's shadows are computed.
    ``far``: the prim's ``usd_gs.relight.far_field.FarField`` (the far static scene from its cached
    layer), or None."""
    space = getattr(opts, "color_space", "srgb")
    domes = [lt for lt in (lights or ()) if lt.kind == "dome"]
    render = render_probe_faces if far is None else far.render
    rgb, alpha, depth = render(everything, centre, opts.probe_size, mask, dilation, opts.probe_supersample)
    lin = linear_faces(rgb, alpha, space)
    fill = fill_radiance(lin, alpha, domes)
    full = lin + unobserved_share(alpha)[..., None] * fill
    probe = fit_probe(full, degree=opts.probe_degree, center=centre)
    q, t_max = opts.relight_q, opts.relight_t_max
    zh = appearance is not None and "zh_color" in appearance
    if blend is None or blend.k == 1 or zh:
        tp = probe if opts.transfer_degree == opts.probe_degree else fit_probe(full, degree=opts.transfer_degree,
                                                                              center=centre)
        if zh:
            return ProbeTransfer(probe, tp, None)
        scale = relight_scale(normals, tp, q=q, t_max=t_max)
    else:
        tex = cube_texels(lin.astype(np.float32), alpha, depth, centre)
        probes = reprojected_probes(tex, blend.centres(g.positions), opts.transfer_degree)
        probes = probes + _fill_sh(fill, alpha, opts.transfer_degree)[None]
        scale = relight_scale(normals, probes, q=q, t_max=t_max, probe_basis="rh", blend=blend.weights)
    irradiance = [None if lt.kind == "dome" else direct_irradiance(lt, g.positions, normals) for lt in lights or ()]
    return ProbeTransfer(probe, None, scale, irradiance, to_linear(dc_colors(g), space))


def relight_factors(g, everything, mask: np.ndarray, centre, normals: np.ndarray, blend, opts,
                    dilation: float = PROBE_DILATION, lights=(), visibility=None,
                    appearance: dict | None = None, transfer: ProbeTransfer | None = None, far=None,
                    keep_level: bool = False) -> tuple[np.ndarray, SHProbe]:
    """``(factor (N, 3) float32, probe)`` for the Gaussians ``g`` (world space) with unit outward
    ``normals`` (N, 3), lit by the scene ``everything`` where ``mask`` (bool, len
    ``everything.count``) is True (the caller leaves out the prim itself and the Gaussians of
    modelled lights) and by ``lights`` (``ShotLight`` list: direct terms, domes as the fill) with
    ``visibility`` (list of (N,) per light, None entries / None for 1). ``centre`` (3,) metres;
    ``blend`` the prim's ``parallax.ProbeBlend`` for the shot (None: one probe); ``opts`` a
    ``ProcessOptions`` (probe_size, probe_supersample, probe_degree, transfer_degree, relight_q,
    relight_t_max, relight_gamma, color_space); ``appearance``: None, or the prim's albedo / ZH
    fields (module docstring); ``transfer``: :func:`probe_transfer` of the same arguments when
    already computed (else it is computed here); ``far``: as for :func:`probe_transfer`.
    ``keep_level``: scale the relit linear colours so that their opacity-weighted mean luminance
    over the prim is the captured colours' (the main job's rule for a shot without any light, where
    the capture's absolute light level is unknown: the probe then shades by direction only).

    ``factor``: per Gaussian and channel, the relit displayed colour over the captured one,
    gamma included (multiply it into every SH band). ``probe``: the fitted probe (linear radiance,
    fill included, degree ``probe_degree``), what the output stores."""

    space = getattr(opts, "color_space", "srgb")
    gamma = float(opts.relight_gamma)
    lights = list(lights or ())
    if transfer is None:
        transfer = probe_transfer(g, everything, mask, centre, normals, blend, opts, dilation, lights, appearance,
                                  far)
    probe, t_max = transfer.probe, opts.relight_t_max
    c = dc_colors(g)
    if transfer.transfer is not None:  # ZH appearance
        col_lin = _zh_linear(g, appearance, transfer.transfer, lights, visibility, centre, gamma)
        if keep_level:
            col_lin = col_lin * _level_scale(g, to_linear(c, space), col_lin)
        out = from_linear(np.minimum(col_lin, t_max), space)
        return _ratio(out, c), probe
    k = np.asarray(transfer.scale, np.float64)
    if any(lt.kind != "dome" for lt in lights):
        k = k + direct_factors(lights, g.positions, normals, visibility, transfer.irradiance) / np.pi
    k = gamma * k
    albedo = None if appearance is None or "albedo" not in appearance else np.asarray(appearance["albedo"], np.float64)
    captured = transfer.captured_linear if transfer.captured_linear is not None else to_linear(c, space)
    if keep_level:
        k = k * _level_scale(g, captured, k * (captured if albedo is None else albedo))
    k = np.clip(k, 0.0, t_max)
    if albedo is not None:
        out = from_linear(albedo * k, space)
        return _ratio(out, c), probe
    return display_factor(c, k, space, linear=captured).astype(np.float32), probe


def _level_scale(g, captured_lin: np.ndarray, relit_lin: np.ndarray) -> float:
    """The factor that gives ``relit_lin`` (N, 3) the opacity-weighted mean luminance of
    ``captured_lin`` (N, 3) over the Gaussians ``g`` (1 when the relit colours are black)."""
    w = np.clip(np.asarray(g.opacities, np.float64), 0.0, 1.0)
    a = float(w @ (np.clip(captured_lin, 0.0, None) @ LUMA))
    b = float(w @ (np.clip(relit_lin, 0.0, None) @ LUMA))
    return a / b if b > 1e-12 and a > 0.0 else 1.0


def _ratio(out: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``out / c`` per channel with the captured colour ``c`` floored at 1e-3 (a black channel
    cannot be scaled into a colour)."""
    return (out / np.maximum(c, 1e-3)).astype(np.float32)


def _zh_linear(g, appearance: dict, probe: SHProbe, lights, visibility, centre, gamma: float) -> np.ndarray:
    """(N, 3) linear ZH colours: the probe's transfer plus each light as a radiance delta."""

    args = (g.orientations, appearance["zh_albedo"], appearance["zh_color"], appearance.get("zh_mono"))
    rh = probe.rh()
    col = zh_diffuse_color(*args, rh, gamma).astype(np.float64)
    deg = probe.degree
    for i, lt in enumerate(lights):
        if lt.kind == "dome":
            continue
        w = light_direction(lt, centre)
        # irradiance at normal incidence toward the light, per Gaussian (inverse square for point lights)
        e = direct_irradiance(lt, g.positions, np.broadcast_to(w, (g.count, 3)))
        v = None if visibility is None else visibility[i]
        if v is not None:
            e = e * np.clip(np.asarray(v, np.float64), 0.0, 1.0)[:, None]
        delta = eval_basis_rh_numpy(w[None, :], deg)[0][:, None] * np.ones((1, 3))  # unit delta from w
        resp = zh_diffuse_color(*args, delta, gamma).astype(np.float64)
        col += resp * e
    return col
