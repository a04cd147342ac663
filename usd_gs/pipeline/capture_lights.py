"""The main job's light step for a capture without authored lights (``--lights auto|indoor|outdoor|N``).

``estimate_for_shot`` decides per shot whether the capture is open or closed
(``usd_gs.relight.sun_estimation.classify_capture``; ``--lights outdoor`` / ``indoor`` force
it, ``N`` means closed with N lights) and returns its lights as ``ShotLight`` values:

- open: a sun (``kind='directional'``, ``shape='distant'``, UsdLux ``angle`` 0.53, ``normalize``
  so that ``sun_irradiance()`` is the estimated irradiance at normal incidence) when the
  estimate is confident, and always the sky (``kind='dome'`` with its lat-long ``env``). A
  low-confidence sun is not used: it is reported (and kept in the sky's customData evidence).
- closed: paper 3.1's point lights (as before), each candidate first tested by
  ``plausible_emitters`` (visible from the avatars' region through the scene, not below the
  floor); rejected candidates are reported with their reason and the next one takes their place;
  plus the capture's plausible bright planar emitters (windows, panels) as RectLights
  (``closed_capture_lights``), which replace the point candidates found on them.

``CaptureLights.lines`` is what ``usdgs process`` and ``usdgs lights`` print; ``direct_share``
maps a light name to the darkening a full shadow of it causes on the display colours of lit
receivers (the sun's ``darkening``: its measured share of the lit ground's light, expressed in
display luminance because the shadow factor multiplies display-referred colours).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid
from usd_gs.io.atomic import atomic_output
from usd_gs.io.envmap import latlong_directions, latlong_solid_angles, write_exr
from usd_gs.relight import sun_estimation as se
from usd_gs.relight.avatar import dome_radiance
from usd_gs.relight.light_estimation import EstimatedRectLight, RectLightConfig, estimate_rect_lights
from usd_gs.usd.lux import ShotLight, write_capture_lights, write_estimated_lights

OPEN_MODES = ("auto", "outdoor", "indoor")
MAX_RECT_LIGHTS = 4  # planar emitters kept per shot (in addition to the k point lights)
RECT_SLAB = 0.1  # metres: a point candidate this close to a kept planar emitter's plane (and on it) is part of it


@dataclass
class CaptureLights:
    """The shot's estimated lights and what the estimate found (see the module docstring)."""

    lights: list
    decision: se.CaptureDecision | None = None
    sun: se.SunEstimate | None = None
    sky: se.SkyEstimate | None = None
    rejected: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    direct_share: dict = field(default_factory=dict)
    rects: dict = field(default_factory=dict)  # RectLight name -> its EstimatedRectLight (evidence)


def _dome_axes(up_axis: str) -> np.ndarray:
    """Columns: world images of the dome's local axes (texture +Y onto the stage's up axis)."""
    if up_axis.upper() == "Z":
        return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    return np.eye(3)


def sun_light(sun: se.SunEstimate, angle: float = 0.53) -> ShotLight:
    e = np.asarray(sun.irradiance, np.float64)
    lum = float(se.LUMA @ e)
    color = e / lum if lum > 0 else np.ones(3)
    return ShotLight("Sun", "directional", np.zeros(3), np.asarray(sun.propagation, np.float64), color, lum,
                     score=float(sun.score), shape="distant", angle=angle, normalize=True)


def sky_light(sky: se.SkyEstimate, up_axis: str, h: int = 32, w: int = 64) -> ShotLight:
    return ShotLight("Sky", "dome", np.zeros(3), np.array([0.0, -1.0, 0.0]), np.ones(3), 1.0, shape="dome",
                     axes=_dome_axes(up_axis), env=sky.latlong(h, w))


def _region(proc, frames):
    """(centroid (3,), ground hint or None, scene GaussianSet or None, its rows as ``PointBlocks``
    or None) of the shot's avatars."""
    paths = [r.path for r in proc.roles if r.role == "scene" and not r.per_frame]
    scene = [proc.static[p] for p in paths]
    if not scene:
        return None, None, None, None
    movers = [r.path for r in proc.roles if r.role == "avatar"] or [r.path for r in proc.roles if r.per_frame]
    picks = sorted({frames[0], frames[len(frames) // 2], frames[-1]})
    sets = [proc._read(p, f) for p in movers for f in picks]
    sets = [g for g in sets if g.count]
    recv = proc._static_receivers(paths)  # (shared with the shadows where the prims are the same)
    whole = recv.gaussians
    # its prims as blocks: the estimate's ball and capsule tests skip the bricks far from the avatars
    blocks = proc._point_blocks(recv.ranges)
    if not sets:
        return alpha_weighted_centroid(whole), None, whole, blocks
    up = se.up_vector(proc.dgsm.up_axis)
    centroid = np.mean([alpha_weighted_centroid(g) for g in sets], axis=0)
    hint = float(np.min([np.percentile(g.positions.astype(np.float64) @ up, 1.0) for g in sets]))
    return centroid, hint, whole, blocks


def estimate_for_shot(proc, frames: list, k: int) -> CaptureLights:
    """The lights of the capture ``proc`` (a ``ShotProcessor`` after ``_open`` and
    ``_read_static``) for ``frames``, by ``proc.opts.lights`` (module docstring). ``UserError``
    for ``--lights outdoor`` on a capture whose sky is covered."""
    mode = proc.opts.lights
    centroid, hint, scene, blocks = _region(proc, frames)
    if scene is None:
        return CaptureLights([], lines=["capture: no static scene prim: no lights can be estimated"])
    up_axis = proc.dgsm.up_axis
    cfg = se.CaptureConfig()
    # (the static prims' values were checked finite when they were read)
    cands = se.emitter_candidates(scene, centroid, max(k + 4, cfg.emitter_candidates), proc.mpu, values_checked=True,
                                  blocks=blocks)
    decision = None
    if mode in OPEN_MODES:
        decision = se.classify_capture(scene, centroid, up_axis, proc.mpu, cfg, cands, blocks=blocks)
        if mode != "auto":
            want = mode == "outdoor"
            if want and decision.empty_share < cfg.open_share:
                raise UserError(f"{proc.input_path}: --lights outdoor but the capture is closed: only "
                                f"{decision.empty_share:.0%} of the sky above the horizon is empty around the "
                                f"avatars (a ceiling or roof; need {cfg.open_share:.0%}); use --lights auto or indoor")
            if want != decision.is_open:
                decision.forced = True
            decision.is_open = want
            decision.mode = mode
    if decision is not None and decision.is_open:
        return _open_lights(proc, scene, centroid, hint, decision, up_axis)
    return _closed_lights(proc, scene, centroid, hint, cands, k, decision, up_axis, blocks)


def _open_lights(proc, scene, centroid, hint, decision, up_axis) -> CaptureLights:
    out = CaptureLights([], decision, lines=[decision.line()])
    if decision.forced and decision.compact:
        out.lines.append(f"warning: --lights outdoor although {len(decision.compact)} compact emitter(s) were found")
    sun = se.estimate_sun(scene, centroid, up_axis, proc.mpu, ground_hint=hint)
    if sun is None:
        out.sky = se.overcast_sky(scene, centroid, up_axis, proc.mpu)
        out.lines.append("sun: no flat ground near the avatars to read the capture's shadows from: sky only")
    else:
        out.sun, out.sky = sun, sun.sky
        out.lines.append(sun.line())
        out.lines.append(f"  ({sun.timings.get('builds', 0)} candidate shadow maps in "
                         f"{sun.timings.get('total', 0.0):.1f} s)")
        if sun.confident:
            lt = sun_light(sun)
            lt.direct_share = float(sun.darkening)  # travels with the light (farm chunks get the lights only)
            out.lights.append(lt)
            out.direct_share[lt.name] = float(sun.darkening)
        else:
            out.sky = se.SkyEstimate(np.ones(3), sun.sky.ground, up_axis)  # all the light from the sky
            out.lines.append("sun: none (overcast or no consistent shadow): the sky alone lights the shot")
    sky = sky_light(out.sky, up_axis)
    if out.sun is not None and out.sun.confident:
        sky.sky_occlusion = (float(out.sun.direct_share), float(out.sun.sky_visibility), float(out.sun.lit_luminance))
    else:  # the sky alone: every receiver's light is sky
        sky.sky_occlusion = (0.0, 1.0, float(se.LUMA @ np.asarray(out.sky.ground, np.float64)))
    out.lights.append(sky)
    return out


def _closed_lights(proc, scene, centroid, hint, cands, k, decision, up_axis, blocks=None) -> CaptureLights:
    cfg = se.CaptureConfig()
    up = se.up_vector(up_axis)
    floor = None
    if hint is not None:
        floor = se.ground_height(scene, up, centroid, cfg.receiver_radius / proc.mpu, hint,
                                 cfg.ground_search / proc.mpu, cfg.flat_cos, cfg.ground_band / 3 / proc.mpu, blocks)
        floor = hint if floor is None else floor
    return closed_capture_lights(scene, centroid, cands, k, up_axis, proc.mpu, floor, decision, values_checked=True,
                                 blocks=blocks)


def rect_light(r: EstimatedRectLight, name: str) -> ShotLight:
    """The ``ShotLight`` of an estimated planar emitter: ``kind='point'`` (one DGSM from its
    centre for the shadows), ``shape='rect'`` with its sides and axes (area samples for the
    relighting); ``color`` the chromaticity (luminance 1) and ``intensity`` the Rec.709
    luminance of the colour the character sees, so that ``radiance() = color * intensity`` is
    that colour (UsdLux RectLight, ``normalize`` off)."""
    col = np.asarray(r.color, np.float64)
    lum = float(se.LUMA @ col)
    return ShotLight(name, "point", np.asarray(r.position, np.float64), color=col / lum if lum > 0 else np.ones(3),
                     intensity=lum, score=float(r.score), shape="rect", width=float(r.width),
                     height=float(r.height), axes=np.asarray(r.axes, np.float64))


def closed_capture_lights(scene: GaussianSet, centroid, cands: list, k: int, up_axis: str = "Y",
                          meters_per_unit: float = 1.0, floor: float | None = None, decision=None,
                          rect_config: RectLightConfig | None = None, values_checked: bool = False,
                          blocks=None) -> CaptureLights:
    """The lights of a closed capture: its plausible planar emitters as RectLights
    (``usd_gs.relight.light_estimation.estimate_rect_lights``, at most ``MAX_RECT_LIGHTS``,
    named ``Rect_<i>`` by decreasing score), plus the first ``k`` plausible point candidates
    ``cands`` (``sun_estimation.emitter_candidates``, visited in score order, the NMS order of
    paper 3.1) that do not lie on a kept planar emitter (those are reported as part of it),
    named ``Light_<i>`` by decreasing intensity. Plausibility as
    ``sun_estimation.plausible_emitters`` (visible from the avatars' region, not below
    ``floor``); every rejected candidate is kept in ``rejected`` and in ``lines``.
    ``values_checked``: as ``estimate_rect_lights``' (the caller checked ``scene``'s values finite);
    ``blocks``: None, or ``scene``'s rows as ``usd_gs.point_blocks.PointBlocks`` where its values are
    finite (the ball and capsule tests block by block: the same lights)."""
    out = CaptureLights([], decision, lines=[decision.line()] if decision else [])
    cfg = se.CaptureConfig()
    mpu = float(meters_per_unit)
    pts = se.region_points(centroid, up_axis, cfg.visibility_offset / mpu)
    rect_config = rect_config or RectLightConfig()
    rects = []
    def sort_out(cand, kept: list) -> None:  # plausible: kept; else rejected with its reason
        se.plausible_emitters(scene, [cand], pts, up_axis, mpu, cfg, floor, blocks=blocks)
        (out.rejected if cand.rejected else kept).append(cand)

    for r in estimate_rect_lights(scene, centroid, rect_config, meters_per_unit=mpu, values_checked=values_checked,
                                  blocks=blocks):
        if len(rects) >= MAX_RECT_LIGHTS:
            break
        sort_out(r, rects)
    names = [f"Rect_{i}" for i in range(len(rects))]
    slab, margin = RECT_SLAB / mpu, rect_config.link_distance / mpu
    # candidates in score order (the NMS order of paper 3.1): the first k plausible ones win
    order = sorted(cands, key=lambda c: -c.score)
    kept = []
    for c in order:
        if len(kept) >= k:
            break
        on = [n for r, n in zip(rects, names, strict=True) if r.contains(c.position, slab, margin)[0]]
        if on:
            c.rejected = f"part of the planar emitter {on[0]} (written as a RectLight, not as point lights)"
            out.rejected.append(c)
            continue
        sort_out(c, kept)
    kept.sort(key=lambda c: -c.intensity)
    out.lights = [ShotLight(f"Light_{i}", "point", np.asarray(c.position, np.float64), color=np.asarray(c.color),
                            intensity=float(c.intensity), score=float(c.score)) for i, c in enumerate(kept)]
    for r, name in zip(rects, names, strict=True):
        lt = rect_light(r, name)
        out.lights.append(lt)
        out.rects[name] = r
        p, n = r.position, r.normal
        out.lines.append(f"rect light {name}: {r.width * mpu:.2f} x {r.height * mpu:.2f} m at ({p[0]:.2f}, "
                         f"{p[1]:.2f}, {p[2]:.2f}) emitting along ({n[0]:.2f}, {n[1]:.2f}, {n[2]:.2f}), radiance "
                         f"{lt.intensity:.3g}, score {r.score:.3g} ({r.evidence['count']} Gaussians, flatness "
                         f"{r.evidence['flatness']:.3f}, variation {r.evidence['variation']:.2f}, visibility "
                         f"{r.visibility:.2f})")
    for c in out.rejected:
        p = c.position
        what = "planar emitter" if isinstance(c, EstimatedRectLight) else "light candidate"
        out.lines.append(f"rejected {what} at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}), score {c.score:.3g}: "
                         f"{c.rejected}")
    return out


def _horizontal_irradiance(lt, up: np.ndarray) -> float:
    """Luminance of the irradiance a light gives an unshadowed horizontal receiver (distant
    lights and domes only; point lights: None)."""
    if lt.kind == "directional":
        return float(se.LUMA @ np.asarray(lt.sun_irradiance(), np.float64)) * max(0.0, float(-np.asarray(
            lt.direction, np.float64) @ up))
    if lt.kind == "dome":

        d = latlong_directions(32, 64)
        cos = np.maximum(d @ up, 0.0)
        return float(np.sum(dome_radiance([lt], d) @ se.LUMA * cos * latlong_solid_angles(32, 64)))
    return None


def direct_fraction(proc, lights) -> float:
    """The darkening ``f`` a full shadow of the shadowing lights causes on a lit receiver's
    display colour (``usd_gs.shadows.shading``: ``c' = c (1 - f + f T)``), when
    ``--direct-fraction`` is not given: per light, the measured darkening of an estimated sun
    (``CaptureLights.direct_share``) or an authored light's ``customData`` ``usdgs:directShare``
    (what ``usdgs lights`` writes); else, for authored DistantLights with a DomeLight, their
    linear share ``s = E_direct / (E_direct + E_dome)`` on a horizontal receiver from the
    intensities, in display terms ``1 - (1 - s)^(1/2.2)``; else 1 (the captured colour taken as
    all direct light: the estimated point lights of a closed capture, as before). Several
    lights: the mean weighted by their ``luminous_weight``."""
    key = tuple((lt.name, lt.kind, lt.source, getattr(lt, "direct_share", None)) for lt in lights)
    cache = proc.__dict__.setdefault("_direct_fraction_cache", {})
    if key in cache:
        return cache[key]
    shares = dict(proc.capture.direct_share) if proc.capture is not None else {}
    up = se.up_vector(proc.dgsm.up_axis)
    domes = [lt for lt in lights if lt.kind == "dome"]
    e_dome = sum(_horizontal_irradiance(d, up) for d in domes)
    num = den = 0.0
    for lt in lights:
        if lt.kind == "dome":
            continue
        share = getattr(lt, "direct_share", None)
        if share is None and lt.source == "estimated":
            share = shares.get(lt.name)
        if share is None and lt.source != "estimated":
            prim = proc.stage.GetPrimAtPath(lt.source)
            v = prim.GetCustomDataByKey("usdgs:directShare") if prim else None
            share = float(v) if v is not None else None
            if share is None and lt.kind == "directional" and domes:
                e = _horizontal_irradiance(lt, up)
                share = 1.0 - (e_dome / (e + e_dome)) ** (1 / 2.2) if e + e_dome > 0 else 1.0
        w = max(lt.luminous_weight, 0.0)
        num += w * (1.0 if share is None else float(np.clip(share, 0.0, 1.0)))
        den += w
    f = num / den if den > 0 else 1.0
    cache[key] = f
    return f


def sky_occlusion_params(proc, lights) -> tuple[float, float, float] | None:
    """``(D, V, L)`` of the sky the moving casters hide from the static receivers around them
    (``usd_gs.shadows.sky_occlusion.sky_factor``), or None when the shot's lights hold no dome
    (closed captures, authored lights without a DomeLight: the sky is no light of the shot).
    A dome's own ``sky_occlusion`` (an estimated sky) or ``customData`` ``usdgs:skyOcclusion``
    (what ``usdgs lights`` writes) first; else, for authored lights, ``D`` = the DistantLights'
    share of a horizontal receiver's irradiance against the domes' (from the intensities),
    ``V = 1`` and ``L = 0.18`` (a mid-grey receiver)."""
    domes = [lt for lt in lights if lt.kind == "dome"]
    if not domes:
        return None
    key = tuple((lt.name, lt.kind, lt.source, lt.intensity, tuple(np.asarray(lt.direction, np.float64)),
                 tuple(np.asarray(lt.color, np.float64)), getattr(lt, "sky_occlusion", None)) for lt in lights)
    cache = proc.__dict__.setdefault("_sky_occlusion_cache", {})
    if key not in cache:
        cache[key] = _sky_occlusion_params(proc, lights, domes)
    return cache[key]


def _sky_occlusion_params(proc, lights, domes) -> tuple[float, float, float]:
    for d in domes:
        got = getattr(d, "sky_occlusion", None)
        if got is None and d.source != "estimated":
            prim = proc.stage.GetPrimAtPath(d.source)
            v = prim.GetCustomDataByKey("usdgs:skyOcclusion") if prim else None
            got = tuple(float(x) for x in v) if v is not None and len(v) == 3 else None
        if got is not None:
            return tuple(float(x) for x in got)
    up = se.up_vector(proc.dgsm.up_axis)
    e_dome = sum(_horizontal_irradiance(d, up) for d in domes)
    e_dir = sum(_horizontal_irradiance(lt, up) for lt in lights if lt.kind == "directional")
    return (e_dir / (e_dir + e_dome) if e_dir + e_dome > 0 else 0.0, 1.0, 0.18)


def lights_evidence(cap: CaptureLights) -> dict:
    """``{light name: {key: value}}`` for :func:`usd_gs.usd.lux.write_capture_lights`."""
    ev = {}
    root = {}
    if cap.decision is not None:
        root.update({f"capture:{k}": v for k, v in cap.decision.as_dict().items()})
    if cap.rejected:
        root["rejected"] = "; ".join(f"({c.position[0]:.2f}, {c.position[1]:.2f}, {c.position[2]:.2f}): "
                                     f"{c.rejected}" for c in cap.rejected)
    ev[""] = root
    for name, r in cap.rects.items():
        ev[name] = dict(r.evidence, visibility=round(float(r.visibility), 4),
                        normal=np.asarray(r.normal, np.float64), radiance=np.asarray(r.color, np.float64))
    if cap.sun is not None:
        sun = {k: v for k, v in cap.sun.evidence().items()}
        sun["directShare"] = float(cap.sun.darkening)  # what direct_fraction reads back (display darkening)
        sun["irradiance"] = np.asarray(cap.sun.irradiance, np.float64)
        ev["Sun"] = sun
        if not cap.sun.confident:  # not used as a light: the sky keeps the rejected candidate's figures
            ev["Sky"] = {f"rejectedSun:{k}": v for k, v in cap.sun.evidence().items()}
            ev["Sky"]["rejectedSun:direction"] = np.asarray(cap.sun.direction, np.float64)
    if cap.sky is not None:
        sky = ev.setdefault("Sky", {})
        sky["sh"] = cap.sky.sh_rh(2)
        sky["shBasis"] = ("real SH (Ramamoorthi-Hanrahan), degree 2, radiance, texture frame (+Y pole), "
                          "flattened [coeff][rgb]")
        sky["radiance"] = np.asarray(cap.sky.radiance, np.float64)
    return ev


def write_lights(proc, stage, lights, texture_path, texture_ref: str) -> int:
    """Author ``lights`` (the estimated ones) under /UsdGs/Lights: paper 3.1 point lights of a
    run without a capture decision -> the SphereLights of ``write_estimated_lights`` as before;
    else ``write_capture_lights`` with the decision, rejected candidates and estimates as
    customData, the sky's lat-long EXR written atomically to ``texture_path`` and referenced
    as ``texture_ref``. Returns the number of texture files written."""

    cap = proc.capture
    points_only = all(lt.kind == "point" and lt.form != "rect" for lt in lights)
    if points_only and (cap is None or (not cap.rejected and cap.decision is None)):
        write_estimated_lights(stage, lights)
        return 0
    if cap is None:  # a farm chunk: the shot's lights without the estimate's evidence
        cap = CaptureLights(list(lights))
    textures, n = {}, 0
    for lt in lights:
        if lt.kind == "dome" and lt.env is not None:

            with atomic_output(texture_path) as tmp:
                write_exr(tmp, lt.env)
            textures[lt.name] = texture_ref
            n += 1
    evidence = lights_evidence(cap)
    for lt in lights:
        if getattr(lt, "direct_share", None) is not None:
            evidence.setdefault(lt.name, {})["directShare"] = float(lt.direct_share)
        if getattr(lt, "sky_occlusion", None) is not None:
            evidence.setdefault(lt.name, {})["skyOcclusion"] = np.asarray(lt.sky_occlusion, np.float64)
    write_capture_lights(stage, lights, evidence, textures, up_axis=proc.dgsm.up_axis)
    return n
