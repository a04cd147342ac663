"""Read and write ``UsdVol.ParticleField3DGaussianSplat`` prims (shared/DESIGN.md section 1).

USD conventions used here:

- ``positions`` point3f[] prim-local, ``scales`` float3[] linear sigma, ``orientations``
  quatf[] (``Gf.Quatf(w, x, y, z)``; the numpy view of a ``Vt.QuatfArray`` is (x, y, z, w),
  :class:`~usd_gs.gaussians.GaussianSet` uses (w, x, y, z)), ``opacities`` float[] linear.
- ``radiance:sphericalHarmonicsCoefficients`` float3[] of N*(d+1)^2 entries, particle-major,
  3DGS basis, coefficient 0 is the raw ``f_dc``; marked as a primvar (``interpolation``
  ``vertex``, ``elementSize`` (d+1)^2). ``radiance:sphericalHarmonicsDegree`` uniform int,
  fallback 3, always authored by :func:`write_gaussian_prim`.
- Half variants (``positionsh`` ...): a reader uses the float attribute when its value at
  ``Usd.TimeCode.EarliestTime()`` is a non-empty array, else the half one.
- Lossless side data (custom attributes): ``usdgs:rawLogScales`` float3[] (PLY ``scale_*``),
  ``usdgs:rawLogitOpacities`` float[] (PLY ``opacity``), ``usdgs:ply:<field>`` (other PLY
  fields; nested ``customData`` key ``usdgs:dtype`` keeps a numpy dtype that USD widened,
  e.g. int16 stored as int[]).

All bulk data moves through ``Vt.*Array.FromNumpy`` / ``np.asarray`` (zero-copy views) and
``Sdf.ChangeBlock``; there are no per-element USD calls. This module must not import numba.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdVol

from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError, InputFormatError, UserError, first_bad_index
from usd_gs.gaussians import GaussianSet
from usd_gs.usd import skel as _skel
from usd_gs.usd.attr_types import require_types
from usd_gs.usd.frames import as_time
from usd_gs.usd.gaussian_layer import (  # noqa: F401 - the write side's names, re-exported here
    DATA_ATTRS,
    DTYPE_KEY,
    EXTENT,
    GS_TYPE,
    HALF_SUFFIX,
    OPACITIES,
    ORIENTATIONS,
    PLY_PREFIX,
    POSITIONS,
    RAW_LOG_SCALES,
    RAW_LOGIT_OPACITIES,
    SCALES,
    SH_COEFFS,
    SH_DEGREE,
    SH_DEGREE_FALLBACK,
    _check_finite,
    all_finite,
    author_gaussian_spec,
    check_gaussians,
    check_precision,
    file_format_args,
    gaussian_prim_path,
    gaussian_values,
    new_layer,
    save_stage_atomic,
)
from usd_gs.usd.schema import RoleInfo, read_role, register_plugins

register_plugins()


# --------------------------------------------------------------------------- helpers
def _time_str(time: Usd.TimeCode) -> str:
    """'time 12', or 'default time' for the Default and EarliestTime codes (not -1.79769e+308)."""
    return "default time" if time.IsDefault() or time.IsEarliestTime() else f"time {time.GetValue():g}"


def uses_float(prim: Usd.Prim, name: str) -> bool:
    """The C++ ``UsesFloat*`` rule: the float attribute ``name`` has a non-empty array value
    at ``Usd.TimeCode.EarliestTime()`` (else the half attribute ``name + 'h'`` is used)."""
    attr = prim.GetAttribute(name)
    if not attr:
        return False
    value = attr.Get(Usd.TimeCode.EarliestTime())
    return value is not None and len(value) > 0


def data_attribute(prim: Usd.Prim, name: str) -> tuple[Usd.Attribute | None, str]:
    """(attribute to read, precision 'float'|'half') for the float attribute name ``name``.

    The attribute is None when neither variant has a value.
    """
    if uses_float(prim, name):
        return prim.GetAttribute(name), "float"
    half = prim.GetAttribute(name + HALF_SUFFIX)
    if half and half.HasValue():
        return half, "half"
    flt = prim.GetAttribute(name)
    if flt and flt.HasAuthoredValue():  # authored but empty at EarliestTime
        return flt, "float"
    return None, "float"


def _data_array(prim: Usd.Prim, name: str, time: Usd.TimeCode) -> tuple[Usd.Attribute | None, np.ndarray | None]:
    """``(data_attribute(prim, name)[0], read_array(that, time))``, the float attribute's value at
    ``Usd.TimeCode.EarliestTime()`` (which :func:`uses_float` reads) not read twice."""
    attr = prim.GetAttribute(name)
    if attr:
        first = attr.Get(Usd.TimeCode.EarliestTime())
        if first is not None and len(first) > 0:  # uses_float
            value = first if time.IsEarliestTime() else attr.Get(time)
            return attr, None if value is None else np.asarray(value)
    attr, _ = data_attribute(prim, name)
    return attr, read_array(attr, time)


def read_array(attr: Usd.Attribute | None, time: Usd.TimeCode) -> np.ndarray | None:
    """Zero-copy read-only numpy view of an array attribute at ``time`` (None if no value)."""
    if attr is None:
        return None
    value = attr.Get(time)
    if value is None:
        return None
    return np.asarray(value)


def similarity_error(matrix) -> str | None:
    """Why a USD 4x4 (row-vector) matrix is not a finite similarity transform, or None.

    Same tolerances as ``GaussianSet.transformed`` (|Q^T Q - I| <= 1e-5 after removing the
    uniform scale ``|det|^(1/3)``).
    """
    m = np.asarray(matrix, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        return "is not finite"
    if np.max(np.abs(m[:3, 3])) > 1e-9 or abs(m[3, 3] - 1.0) > 1e-9:
        return "is projective, not a similarity transform"
    lin = m[:3, :3]
    det = np.linalg.det(lin)
    if det == 0:
        return "is singular (determinant 0)"
    q = lin / abs(det) ** (1.0 / 3.0)
    err = float(np.max(np.abs(q.T @ q - np.eye(3))))
    if err > 1e-5:
        return f"has a non-uniform scale or shear (|Q^T Q - I| = {err:.3g})"
    return None


def is_gaussian_prim(prim: Usd.Prim) -> bool:
    """True for a ``ParticleField3DGaussianSplat`` prim (by type name, or a derived type)."""
    return prim.GetTypeName() == GS_TYPE or prim.IsA(UsdVol.ParticleField3DGaussianSplat)


def find_gaussian_prims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every active, defined, non-abstract Gaussian splat prim, sorted by path.

    Prims written by older tools are found by their type name alone. Instanced hierarchies are
    read through their instance proxies (one prim per instance, at the instance's path, its
    prototype's values with the instance's transform); prototypes themselves are not listed.
    """
    prims = [p for p in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)) if is_gaussian_prim(p)]
    prims.sort(key=lambda p: p.GetPath().pathString)
    return prims


def retyped_gaussian_prims(stage: Usd.Stage) -> list[tuple[str, str]]:
    """``(path, type name)`` of each prim whose composed type is not a Gaussian splat although a
    weaker opinion on it (e.g. the prim a reference brings in) is ``ParticleField3DGaussianSplat``:
    a stronger ``def Xform "Seal" (references = ...)`` types the referenced splat prim as an Xform,
    which every tool then skips. Sorted by path."""
    out = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if is_gaussian_prim(prim) or len(prim.GetPrimStack()) < 2:
            continue
        if any(spec.typeName == GS_TYPE for spec in prim.GetPrimStack()):
            out.append((prim.GetPath().pathString, prim.GetTypeName() or "a typeless prim"))
    return sorted(out)


def retyped_message(path: str, type_name: str) -> str:
    """One line on a :func:`retyped_gaussian_prims` prim and how to write it instead."""
    name = path.rsplit("/", 1)[-1]
    return (f"{path}: a ParticleField3DGaussianSplat prim typed {type_name} by a stronger opinion (e.g. "
            f"'def {type_name} \"{name}\" (references = ...)'), so it is not read as Gaussians; write 'def "
            f"\"{name}\" (references = ...)' (no type) or 'over'")


def _degree(prim: Usd.Prim) -> tuple[int, bool]:
    """(SH degree, authored?) from ``radiance:sphericalHarmonicsDegree`` (fallback 3)."""
    attr = prim.GetAttribute(SH_DEGREE)
    value = attr.Get() if attr else None
    if value is None:
        return SH_DEGREE_FALLBACK, False
    return int(value), bool(attr.HasAuthoredValue())


# --------------------------------------------------------------------------- reading
def read_gaussian_prim(prim: Usd.Prim, time=None, world: bool = True, skin: bool = True, *,
                       check_types: bool = True, defer_finite: list | None = None) -> GaussianSet:
    """Read one Gaussian splat prim as a :class:`GaussianSet` labelled with the prim path.

    ``time``: ``Usd.TimeCode``/number/None (``Default``); time-sampled attributes are read
    at it. ``world``: apply the prim's local-to-world transform at ``time`` (must be a
    similarity transform; positions in world units, SH rotated). Raw ``usdgs:rawLogScales``/
    ``usdgs:rawLogitOpacities`` fill ``log_scales``/``logit_opacities`` when their lengths
    match and they agree with ``scales``/``opacities`` (stale raw data is dropped with a
    warning); ``usdgs:ply:<field>`` fill ``extras[field]``.

    A prim with a UsdSkel binding (``usd_gs.usd.skel``: ``UsdSkel.BindingAPI``, a skeleton with a
    SkelAnimation) holds its bind pose; it is returned skinned at ``time`` (world space, or
    prim-local with ``world=False``) unless ``skin=False`` (the authored bind pose, read as if
    unbound). Raw log-scales are dropped from skinned sets. ``check_types=False`` skips the check of
    the authored value types (``usd_gs.usd.attr_types.require_types``), for a caller that made it on
    this prim of this stage already (:func:`describe_gaussian_prim` makes it). ``defer_finite``: None,
    or a list: where the values are returned as authored (no transform, no skinning), the check
    that they are finite is not made here but appended to it, for :func:`check_deferred` (or a
    pass that proves every value finite, e.g. ``GaussianSet.concatenate(finite=...)``) to make
    before they are used.

    Unauthored ``opacities`` read as 1 (the schema rule); the arrays of a prim without a
    transform are read-only zero-copy views of USD memory (copy before editing in place).

    Raises ``GaussianDataError``/``InputFormatError`` (``UserError``) naming the prim, the
    attribute and the lengths or first bad element: missing attributes, wrong lengths, SH
    count or ``elementSize`` inconsistent with the degree, degree outside 0..3, NaN/Inf,
    non-similarity transforms.
    """
    tc = as_time(time)
    path = prim.GetPath().pathString
    where = f"{path} ({_time_str(tc)})" if not tc.IsDefault() else path
    if not is_gaussian_prim(prim):
        raise InputFormatError(f"{path}: prim type '{prim.GetTypeName()}' is not {GS_TYPE}")
    if check_types:
        require_types(prim)  # wrongly typed attributes (float[] orientations, a token degree) before any read

    arrays: dict[str, np.ndarray | None] = {}
    names: dict[str, str] = {}
    for name in DATA_ATTRS:
        attr, arr = _data_array(prim, name, tc)
        names[name] = attr.GetName() if attr is not None else name
        if arr is not None and arr.dtype == np.float16:
            arr = arr.astype(np.float32)  # once, so every later check runs on float32
        arrays[name] = arr

    pos = arrays[POSITIONS]
    if pos is None:
        raise InputFormatError(f"{where}: attribute '{POSITIONS}' (or '{POSITIONS}h') has no value")
    n = len(pos)
    for name in (ORIENTATIONS, SCALES, SH_COEFFS):
        if arrays[name] is None:
            raise InputFormatError(f"{where}: attribute '{name}' (or '{name}{HALF_SUFFIX}') has no value")
    if arrays[OPACITIES] is None:
        arrays[OPACITIES] = np.ones(n, np.float32)
    for name in (ORIENTATIONS, SCALES, OPACITIES):
        m = len(arrays[name])
        if m != n:
            raise GaussianDataError(f"{where}: attribute '{names[name]}' has {m} elements but "
                                    f"'{names[POSITIONS]}' has {n}")

    degree, _ = _degree(prim)
    if not 0 <= degree <= sh3dgs.MAX_DEGREE:
        raise GaussianDataError(f"{where}: attribute '{SH_DEGREE}' is {degree}, not in 0..{sh3dgs.MAX_DEGREE}")
    k = sh3dgs.num_coeffs(degree)
    sh_attr = prim.GetAttribute(names[SH_COEFFS])
    elem = sh_attr.GetMetadata("elementSize")
    if elem is not None and int(elem) != k:
        raise GaussianDataError(f"{where}: attribute '{names[SH_COEFFS]}' has elementSize {elem} but "
                                f"'{SH_DEGREE}' {degree} needs (d+1)^2 = {k}")
    interp = sh_attr.GetMetadata("interpolation")
    if interp is not None and interp != UsdGeom.Tokens.vertex:
        raise GaussianDataError(f"{where}: attribute '{names[SH_COEFFS]}' has interpolation '{interp}', "
                                "only 'vertex' (one set of coefficients per particle) is supported")
    sh_flat = arrays[SH_COEFFS]
    if len(sh_flat) != n * k:
        raise GaussianDataError(f"{where}: attribute '{names[SH_COEFFS]}' has {len(sh_flat)} elements but "
                                f"{n} particles with '{SH_DEGREE}' {degree} need {n} * {k} = {n * k}")

    skinned = bool(skin and n and _skel.has_skel_binding(prim))
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc)) if world and not skinned else None
    checks = [(arrays[name], where, names[name]) for name in DATA_ATTRS]
    if defer_finite is not None and not skinned and (m is None or np.array_equal(m, np.eye(4))):
        defer_finite.append(checks)  # (values used as authored: the caller checks them)
    else:
        check_deferred([checks])

    quat_xyzw = arrays[ORIENTATIONS]
    # a row of four False bytes is a zero uint32: a zero-length quaternion
    zero = (np.ascontiguousarray(quat_xyzw != 0).view(np.uint32).reshape(n) == 0) if n else np.zeros(0, bool)
    if zero.any():  # no rotation at all: every reader and writer would have to invent one
        raise GaussianDataError(f"{where}: attribute '{names[ORIENTATIONS]}' element {first_bad_index(zero)} is a "
                                f"zero-length quaternion ({int(zero.sum())} such elements)")
    orientations = np.empty((n, 4), np.float32)
    orientations[:, 0] = quat_xyzw[:, 3]
    orientations[:, 1:] = quat_xyzw[:, :3]
    scales = arrays[SCALES]
    opac = arrays[OPACITIES]

    log_scales, logit_opacities = _read_raw(prim, tc, where, n, scales, opac, precision_half=names[SCALES] != SCALES)
    extras = _read_extras(prim, tc, where, n)

    gs = GaussianSet(pos, orientations, scales, opac, sh_flat.reshape(n, k, 3), log_scales, logit_opacities,
                     extras, label=path)
    if skinned:
        # UsdSkel binding: the authored values are the bind pose; skin them (the prim's own transform
        # is ignored, the skeleton's applies: usd_gs.usd.skel).
        return _check_transformed(_skel.read_skinned(prim, gs, tc, world=world), path, tc)
    if m is not None:
        if not np.array_equal(m, np.eye(4)):
            why = similarity_error(m)
            if why is not None:
                raise GaussianDataError(f"{where}: local-to-world transform {why}; only rotations, translations, "
                                        "reflections and uniform scales are supported")
            with np.errstate(over="ignore", invalid="ignore"):
                gs = gs.transformed(m, label=path)
            _check_transformed(gs, path, tc)
    return gs


def check_deferred(deferred: list) -> None:
    """The finite checks :func:`read_gaussian_prim` left in ``deferred`` (its ``defer_finite``), in
    the order the prims were read: ``GaussianDataError`` naming the first prim, attribute and
    element whose value is not finite."""
    for checks in deferred:
        for arr, where, name in checks:
            _check_finite(arr, where, name)


def _check_transformed(gs: GaussianSet, path: str, tc: Usd.TimeCode) -> GaussianSet:
    """``GaussianDataError`` naming ``prim.attribute[element]`` (as validate does) when the world
    (or skinned) values are not finite although the authored ones are (a transform that
    overflows float32); returns ``gs``."""
    at = "" if tc.IsDefault() or tc.IsEarliestTime() else f" at time {tc.GetValue():g}"
    for name in ("positions", "scales", "orientations"):
        arr = getattr(gs, name)
        if all_finite(arr):
            continue
        bad = ~np.isfinite(arr).all(axis=1) if len(arr) else np.zeros(0, bool)
        if bad.any():
            i = first_bad_index(bad)
            raise GaussianDataError(f"{path}.{name}[{i}]{at}: is not finite in world space (value "
                                    f"{np.array2string(arr[i], precision=6)}; {int(bad.sum())} bad elements): the "
                                    "prim's transform overflows float32")
    return gs


_TINY32 = float(np.finfo(np.float32).tiny)  # ply_io's floor for exp(log-scale)


def _sigmoid64(x: np.ndarray) -> np.ndarray:
    """Overflow-free float64 sigmoid (logits of +-inf give exactly 1 / 0)."""
    x = x.astype(np.float64)
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e))


def _read_raw(prim, tc, where, n, scales, opac, precision_half):
    """Raw PLY log-scales / logits if present, well-formed and consistent with the linear
    values (exp, clamped at the smallest normal float32 like ``ply_io``; sigmoid)."""
    attr_ls = prim.GetAttribute(RAW_LOG_SCALES)
    attr_lo = prim.GetAttribute(RAW_LOGIT_OPACITIES)
    log_scales = read_array(attr_ls, tc) if attr_ls else None
    logit = read_array(attr_lo, tc) if attr_lo else None
    rtol = 2e-3 if precision_half else 1e-5
    if log_scales is not None:
        if log_scales.shape != (n, 3) or not np.all(np.isfinite(log_scales)):
            warnings.warn(f"{where}: '{RAW_LOG_SCALES}' has shape {log_scales.shape} or non-finite values, "
                          f"expected ({n}, 3); ignored", stacklevel=3)
            log_scales = None
        elif not np.allclose(np.maximum(np.exp(log_scales.astype(np.float64)), _TINY32), scales, rtol=rtol, atol=0):
            warnings.warn(f"{where}: '{RAW_LOG_SCALES}' does not match exp -> '{SCALES}' (stale raw data); ignored",
                          stacklevel=3)
            log_scales = None
    if logit is not None:
        if logit.shape != (n,) or np.isnan(logit).any():
            warnings.warn(f"{where}: '{RAW_LOGIT_OPACITIES}' has shape {logit.shape} or NaN values, "
                          f"expected ({n},); ignored", stacklevel=3)
            logit = None
        else:
            sig = _sigmoid64(logit)
            if not np.allclose(sig, opac, rtol=0, atol=2e-3 if precision_half else 1e-5):
                warnings.warn(f"{where}: '{RAW_LOGIT_OPACITIES}' does not match sigmoid -> '{OPACITIES}' "
                              "(stale raw data); ignored", stacklevel=3)
                logit = None
    return log_scales, logit


def _read_extras(prim, tc, where, n) -> dict[str, np.ndarray]:
    extras = {}
    for attr in prim.GetAuthoredPropertiesInNamespace(PLY_PREFIX.rstrip(":")):
        if not isinstance(attr, Usd.Attribute):
            continue
        field = attr.GetName()[len(PLY_PREFIX):]
        arr = read_array(attr, tc)
        if arr is None:
            continue
        dtype = attr.GetCustomDataByKey(DTYPE_KEY)
        if dtype:
            arr = arr.astype(np.dtype(dtype), copy=False)
        if len(arr) % max(n, 1) or (n == 0 and len(arr)):
            raise GaussianDataError(f"{where}: attribute '{attr.GetName()}' has {len(arr)} elements, not a "
                                    f"multiple of the particle count {n}")
        extras[field] = arr.reshape(n, -1) if (n and len(arr) != n) else arr
    return extras


# --------------------------------------------------------------------------- describing
@dataclass
class GaussianPrimInfo:
    """Summary of one Gaussian prim (cheap: reads counts, degree, extent, transforms).

    ``time_samples`` is (first, last) over the Gaussian data attributes and the transforms
    of the prim and its ancestors, or None when nothing is time-sampled. ``animated`` is
    true when positions/orientations/scales or the local-to-world transform may vary in
    time. ``world_bounds`` is (min, max), two (3,) float64 arrays: the world-space box of
    the prim-local ``extent`` at the described time (of the positions when no extent is
    authored); None for an empty prim. A skinned prim (``usd_gs.usd.skel``) is ``animated``,
    its ``time_samples`` include the SkelAnimation's, and its bounds are those of the skinned
    centres at the described time grown by the rest extent's margin.
    """

    path: str
    count: int
    sh_degree: int
    precision: str
    time_samples: tuple[float, float] | None
    animated: bool
    role: RoleInfo
    world_bounds: tuple[np.ndarray, np.ndarray] | None


def _xform_chain(prim: Usd.Prim):
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable):
            yield UsdGeom.Xformable(p)
        p = p.GetParent()


def describe_gaussian_prim(prim: Usd.Prim, time=None, *, shared: dict | None = None) -> GaussianPrimInfo:
    """:class:`GaussianPrimInfo` of ``prim`` at ``time`` (no SH data is read). ``shared``: a dict
    that calls for prims of one stage at one ``time`` pass (the stage unchanged between them), in
    which what ancestors share is kept (their transforms' time samples, a ``UsdGeom.XformCache``)."""
    tc = as_time(time)
    path = prim.GetPath().pathString
    require_types(prim)
    pos_attr, pos = _data_array(prim, POSITIONS, tc)
    precision = "half" if pos_attr is not None and pos_attr.GetName() != POSITIONS else "float"
    count = 0 if pos is None else len(pos)
    degree, _ = _degree(prim)

    samples: list[float] = []
    animated = False
    for name in DATA_ATTRS:
        for nm in (name, name + HALF_SUFFIX):
            attr = prim.GetAttribute(nm)
            if not attr:
                continue
            ts = attr.GetTimeSamples()
            if ts:
                samples.extend((ts[0], ts[-1]))
            if name in (POSITIONS, ORIENTATIONS, SCALES) and attr.ValueMightBeTimeVarying():
                animated = True
    for xf in _xform_chain(prim):
        key = xf.GetPath() if shared is not None and xf.GetPrim() != prim else None
        got = shared.get(key) if key is not None else None
        if got is None:
            ts = xf.GetTimeSamples()
            got = ((ts[0], ts[-1]) if ts else (), xf.TransformMightBeTimeVarying())
            if key is not None:
                shared[key] = got
        samples.extend(got[0])
        if got[1]:
            animated = True
    skinned = count > 0 and _skel.has_skel_binding(prim)
    if skinned:  # moving: the animation's samples count as the prim's
        animated = True
        rng = _skel.animation_range(prim)
        if rng is not None:
            samples.extend(rng)
    time_samples = (min(samples), max(samples)) if samples else None

    bounds = None
    ext_attr = prim.GetAttribute(EXTENT)
    ext = read_array(ext_attr, tc) if ext_attr else None
    local = None
    if ext is not None and ext.shape == (2, 3):
        local = ext.astype(np.float64)
    elif count:
        p = pos.astype(np.float64)
        local = np.stack([p.min(axis=0), p.max(axis=0)])
    if skinned and local is not None:
        p = pos.astype(np.float64)
        pad = np.maximum(np.maximum(p.min(axis=0) - local[0], local[1] - p.max(axis=0)), 0.0)
        bounds = _skel.skinned_bounds(prim, p, pad, tc)
    elif local is not None and count:
        if shared is not None:  # (ComputeLocalToWorldTransform fills a fresh XformCache: the same matrix)
            m = np.array(shared.setdefault("xform cache", UsdGeom.XformCache(tc)).GetLocalToWorldTransform(prim))
        else:
            m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc))
        corners = np.array([[local[i, 0], local[j, 1], local[k, 2], 1.0]
                            for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        w = corners @ m
        w = w[:, :3] / w[:, 3:4]
        bounds = (w.min(axis=0), w.max(axis=0))
    return GaussianPrimInfo(path, count, degree, precision, time_samples, animated, read_role(prim), bounds)


# --------------------------------------------------------------------------- writing
def _define_ancestors(stage: Usd.Stage, path: Sdf.Path) -> None:
    missing = []
    parent = path.GetParentPath()
    while parent != Sdf.Path.absoluteRootPath:
        prim = stage.GetPrimAtPath(parent)
        if prim and prim.IsDefined():
            break
        missing.append(parent)
        parent = parent.GetParentPath()
    for p in reversed(missing):
        UsdGeom.Xform.Define(stage, p)


def write_gaussian_prim(stage: Usd.Stage, path, gaussians: GaussianSet, time=None, keep_raw: bool = True,
                        precision: str = "float") -> Usd.Prim:
    """Define (or update) a conformant ``ParticleField3DGaussianSplat`` at ``path``.

    ``gaussians`` are in prim-local space (the prim's own transform is left as it is).
    Authors positions, orientations ((w,x,y,z) -> ``Vt.QuatfArray``), scales, opacities,
    SH coefficients (particle-major, ``interpolation`` vertex, ``elementSize`` (d+1)^2),
    ``radiance:sphericalHarmonicsDegree`` (uniform, always) and ``extent`` (3 sigma box,
    prim-local). ``precision='half'`` authors the ``*h`` attributes instead. ``keep_raw``
    adds ``usdgs:rawLogScales``/``usdgs:rawLogitOpacities`` and ``usdgs:ply:<field>``
    (custom attributes) when the set carries them.

    ``time`` None writes default values; otherwise every per-particle attribute and the
    extent get a time sample at ``time`` (degree, elementSize and interpolation are never
    time-sampled; a degree differing from an authored one raises ``UserError``). Missing
    ancestors are defined as ``Xform``; existing ones are left (in an output layer they
    become ``over`` specs). Writes into the stage's edit target.
    """
    check_precision(precision)
    path = gaussian_prim_path(path)
    tc = None if time is None else as_time(time)
    if tc is not None and tc.IsDefault():
        tc = None
    g = gaussians
    degree = g.sh_degree
    check_gaussians(g, path)

    existing = stage.GetPrimAtPath(path)
    if existing and existing.IsDefined() and existing.GetTypeName() not in ("", GS_TYPE):
        raise UserError(f"{path}: a prim of type '{existing.GetTypeName()}' exists, cannot write {GS_TYPE} there")
    if existing:
        d_attr = existing.GetAttribute(SH_DEGREE)
        if d_attr and d_attr.HasAuthoredValue() and int(d_attr.Get()) != degree:
            raise UserError(f"{path}: attribute '{SH_DEGREE}' is {int(d_attr.Get())} but the Gaussians have "
                            f"degree {degree}; the degree cannot vary in time")
        if precision == "half":
            for name in DATA_ATTRS:
                if uses_float(existing, name):
                    raise UserError(f"{path}: attribute '{name}' has float values that readers prefer over "
                                    f"'{name}{HALF_SUFFIX}'; cannot write half precision here")

    values = gaussian_values(g, path, keep_raw, precision)
    _define_ancestors(stage, path)
    prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, path).GetPrim()
    edit_target = stage.GetEditTarget()
    author_gaussian_spec(edit_target.GetLayer(), edit_target.MapToSpecPath(path), values, tc)
    return prim


# --------------------------------------------------------------------------- stages and files
def new_stage(path=None, up_axis: str = "Y", meters_per_unit: float = 1.0,
              default_prim: str | None = None) -> Usd.Stage:
    """A new in-memory stage (root layer anonymous, :func:`~usd_gs.usd.gaussian_layer.new_layer`;
    nothing is written until :func:`save_stage_atomic`). ``path`` only selects/validates the
    output format.

    ``up_axis`` 'Y' or 'Z'; ``meters_per_unit`` > 0; ``default_prim`` a root prim name
    (the prim may be defined later).
    """
    if path is not None:
        file_format_args(path)
    return Usd.Stage.Open(new_layer(up_axis, meters_per_unit, default_prim))
