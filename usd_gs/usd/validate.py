"""Stage validation for Gaussian splat prims: NVIDIA's asset rule VG.035 and more.

VG.035 (shared/DESIGN.md section 1): the five data attributes (positions, orientations,
scales, opacities, SH coefficients; float or half per the ``UsesFloat*`` rule), the SH
degree and ``extent`` are authored; scales/orientations/opacities have length N; opacities
in [0, 1]; every scale > 0; |q| within 1 +/- 1e-3; degree in 0..3; the SH attribute has
``interpolation`` vertex, ``elementSize`` (d+1)^2 and length N*(d+1)^2.

Added here: NaN/Inf in every data attribute and the extent, NaN in the raw ``usdgs:``
attributes (where +-inf is a valid saturated PLY value);
an extent that is not a finite ordered box or does not contain the positions; local-to-world
transforms that are not finite similarity transforms (naming the prim whose own transform
is at fault); UsdSkel bindings (``usd_gs.usd.skel``: SkelRoot, skeleton with an animation,
influence lengths, joint indices in range, weights summing to 1 within 1e-4). With
``time=None`` every time sample of the prim's Gaussian attributes and
transforms is checked (each sample vectorised); a problem repeated at several samples is
reported once, at its first time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom

from usd_gs import sh3dgs
from usd_gs.errors import first_bad_index
from usd_gs.usd.attr_types import type_problems
from usd_gs.usd.gaussian_prim import (
    DATA_ATTRS,
    EXTENT,
    HALF_SUFFIX,
    OPACITIES,
    ORIENTATIONS,
    POSITIONS,
    RAW_LOG_SCALES,
    RAW_LOGIT_OPACITIES,
    SCALES,
    SH_COEFFS,
    SH_DEGREE,
    as_time,
    data_attribute,
    find_gaussian_prims,
    read_array,
    retyped_gaussian_prims,
    retyped_message,
    similarity_error,
)

QUAT_TOLERANCE = 1e-3
TRANSFORM_ATTR = "xformOpOrder"


@dataclass(frozen=True)
class Problem:
    """One rule violation. ``element`` is the first bad element index (None when the
    problem is not about one element); ``time`` the time code (None = default time)."""

    prim_path: str
    attribute: str
    message: str
    element: int | None = None
    time: float | None = None

    def __str__(self) -> str:
        where = f"{self.prim_path}.{self.attribute}"
        el = f" element {self.element}" if self.element is not None else ""
        at = f" at time {self.time:g}" if self.time is not None else " at default time"
        return f"{where}{el}{at}: {self.message}"


def validate_stage(stage: Usd.Stage, time=None) -> list[Problem]:
    """Problems of every Gaussian prim on ``stage`` (see module docstring), sorted by prim."""
    out: list[Problem] = []
    for prim in find_gaussian_prims(stage):
        out.extend(validate_prim(prim, time))
    for path, type_name in retyped_gaussian_prims(stage):
        msg = retyped_message(path, type_name).split(": ", 1)[1]
        out.append(Problem(path, "typeName", msg))
    return sorted(out, key=lambda p: p.prim_path)


def _times(prim: Usd.Prim, time) -> list[Usd.TimeCode]:
    if time is not None:
        return [as_time(time)]
    samples: set[float] = set()
    for name in (*DATA_ATTRS, EXTENT, RAW_LOG_SCALES, RAW_LOGIT_OPACITIES):
        for nm in (name, name + HALF_SUFFIX) if name in DATA_ATTRS else (name,):
            attr = prim.GetAttribute(nm)
            if attr:
                samples.update(attr.GetTimeSamples())
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable):
            samples.update(UsdGeom.Xformable(p).GetTimeSamples())
        p = p.GetParent()
    if not samples:
        return [Usd.TimeCode.Default()]
    return [Usd.TimeCode(t) for t in sorted(samples)]


def _first(mask: np.ndarray) -> int:
    return first_bad_index(mask) if len(mask) else -1


class _Collector:
    def __init__(self, path: str):
        self.path = path
        self.items: list[Problem] = []
        self._seen: set[tuple[str, str]] = set()

    def add(self, rule: str, attribute: str, message: str, element: int | None, tc: Usd.TimeCode) -> None:
        key = (attribute, rule)
        if key in self._seen:
            return
        self._seen.add(key)
        t = None if tc.IsDefault() or tc.IsEarliestTime() else float(tc.GetValue())
        self.items.append(Problem(self.path, attribute, message, element, t))


def validate_prim(prim: Usd.Prim, time=None) -> list[Problem]:
    """Problems of one Gaussian prim at ``time`` (every time sample when None)."""
    col = _Collector(prim.GetPath().pathString)
    wrong = type_problems(prim)
    if wrong:  # values of another type than the schema's: the value checks below cannot run
        for name, msg in wrong:
            col.add("type", name, msg, None, Usd.TimeCode.Default())
        return col.items
    attrs = {name: data_attribute(prim, name)[0] for name in DATA_ATTRS}
    names = {name: (a.GetName() if a is not None else name) for name, a in attrs.items()}

    deg_attr = prim.GetAttribute(SH_DEGREE)
    degree = None
    if not (deg_attr and deg_attr.HasAuthoredValue()):
        col.add("missing", SH_DEGREE, "is not authored (VG.035 requires it; readers fall back to degree 3)",
                None, Usd.TimeCode.Default())
    raw_degree = deg_attr.Get() if deg_attr else None
    if raw_degree is not None:
        degree = int(raw_degree)
        if not 0 <= degree <= sh3dgs.MAX_DEGREE:
            col.add("range", SH_DEGREE, f"is {degree}, not in 0..{sh3dgs.MAX_DEGREE}", None, Usd.TimeCode.Default())
            degree = None

    sh_attr = attrs[SH_COEFFS]
    if sh_attr is not None:
        interp = sh_attr.GetMetadata("interpolation")
        if interp != UsdGeom.Tokens.vertex:
            col.add("interpolation", names[SH_COEFFS],
                    f"interpolation is {repr(str(interp)) if interp else 'not authored'}, must be 'vertex'",
                    None, Usd.TimeCode.Default())
        elem = sh_attr.GetMetadata("elementSize")
        elem = 1 if elem is None else int(elem)
        if degree is not None and elem != sh3dgs.num_coeffs(degree):
            col.add("elementSize", names[SH_COEFFS],
                    f"elementSize is {elem}, must be (d+1)^2 = {sh3dgs.num_coeffs(degree)} for degree {degree}",
                    None, Usd.TimeCode.Default())

    for tc in _times(prim, time):
        _check_at(prim, tc, attrs, names, degree, col)
    _check_binding(prim, time, attrs, col)
    return col.items


def _check_binding(prim: Usd.Prim, time, attrs, col: _Collector) -> None:
    """UsdSkel binding (usd_gs.usd.skel): SkelRoot, skeleton, animation, influence lengths, joint
    indices in range, weights >= 0 summing to 1 within ``skel.WEIGHT_SUM_TOL``; checked at
    ``time``, else at the animation's first and last samples (default time without samples)."""
    from usd_gs.usd import skel

    if not skel.has_skel_binding(prim):
        return
    pos = read_array(attrs[POSITIONS], Usd.TimeCode.EarliestTime()) if attrs[POSITIONS] is not None else None
    if pos is None:
        return
    if time is not None:
        times = [as_time(time)]
    else:
        try:
            rng = skel.animation_range(prim)
        except skel.BindingError:
            rng = None
        times = [Usd.TimeCode(t) for t in sorted(set(rng))] if rng else [Usd.TimeCode.Default()]
    for attribute, message, element, t in skel.binding_problems(prim, len(pos), times):
        col.add("skel", attribute, message, element, Usd.TimeCode.Default() if t is None else Usd.TimeCode(t))


def _check_at(prim, tc, attrs, names, degree, col: _Collector) -> None:
    vals = {}
    for name in DATA_ATTRS:
        arr = read_array(attrs[name], tc)
        if arr is None:
            col.add("missing", names[name], "has no value (VG.035 requires it)", None, tc)
        vals[name] = arr
    ext_attr = prim.GetAttribute(EXTENT)
    extent = read_array(ext_attr, tc) if ext_attr else None
    if extent is None:
        col.add("missing", EXTENT, "has no value (VG.035 requires it; no extent plugin computes it)", None, tc)

    # NaN/Inf in every attribute (first bad element). The raw PLY values may be +-inf
    # (a saturated logit or log-scale is valid PLY data), so only NaN is an error there.
    checked = [(names[n], vals[n], False) for n in DATA_ATTRS if vals[n] is not None]
    for raw in (RAW_LOG_SCALES, RAW_LOGIT_OPACITIES):
        a = prim.GetAttribute(raw)
        if a:
            arr = read_array(a, tc)
            if arr is not None:
                checked.append((raw, arr, True))
    if extent is not None:
        checked.append((EXTENT, extent, False))
    for attr_name, arr, allow_inf in checked:
        ok = ~np.isnan(arr) if allow_inf else np.isfinite(arr)
        if arr.size and not ok.all():
            bad = ~ok.reshape(len(arr), -1).all(axis=1)
            i = _first(bad)
            what = "is NaN" if allow_inf else "is not finite"
            col.add("finite", attr_name, f"{what} (value {np.array2string(arr[i], precision=6)}; "
                    f"{int(bad.sum())} bad elements)", i, tc)

    pos = vals[POSITIONS]
    n = None if pos is None else len(pos)
    if n is not None:
        for name in (ORIENTATIONS, SCALES, OPACITIES):
            arr = vals[name]
            if arr is not None and len(arr) != n:
                col.add("length", names[name], f"has {len(arr)} elements but '{names[POSITIONS]}' has {n}", None, tc)
        sh = vals[SH_COEFFS]
        if sh is not None and degree is not None:
            k = sh3dgs.num_coeffs(degree)
            if len(sh) != n * k:
                col.add("length", names[SH_COEFFS], f"has {len(sh)} elements but {n} particles with degree "
                        f"{degree} need N*(d+1)^2 = {n * k}", None, tc)

    op = vals[OPACITIES]
    if op is not None and len(op):
        o = op.astype(np.float32)
        bad = ~((o >= 0) & (o <= 1)) & np.isfinite(o)
        i = _first(bad)
        if i >= 0:
            col.add("range", names[OPACITIES], f"value {float(o[i]):.6g} is outside [0, 1] "
                    f"({int(bad.sum())} bad elements)", i, tc)
    sc = vals[SCALES]
    if sc is not None and len(sc):
        s = sc.astype(np.float32)
        bad = (s <= 0).any(axis=1)
        i = _first(bad)
        if i >= 0:
            col.add("range", names[SCALES], f"value {np.array2string(s[i], precision=6)} is not > 0 "
                    f"({int(bad.sum())} bad elements)", i, tc)
    qv = vals[ORIENTATIONS]
    if qv is not None and len(qv):
        q = qv.astype(np.float64)
        norm = np.sqrt(np.einsum("ij,ij->i", q, q))
        bad = (np.abs(norm - 1.0) > QUAT_TOLERANCE) & np.isfinite(norm)
        i = _first(bad)
        if i >= 0:
            col.add("unit", names[ORIENTATIONS], f"|q| = {norm[i]:.6g} is outside 1 +/- {QUAT_TOLERANCE:g} "
                    f"({int(bad.sum())} bad elements)", i, tc)

    if extent is not None:
        if extent.shape != (2, 3):
            col.add("extent", EXTENT, f"has {len(extent)} elements, must be 2 (min, max)", None, tc)
        elif np.isfinite(extent).all():
            if (extent[0] > extent[1]).any():
                col.add("extent", EXTENT, f"min {extent[0]} exceeds max {extent[1]}", None, tc)
            elif pos is not None and len(pos):
                p = pos.astype(np.float64)
                tol = 1e-5 * max(1.0, float(np.max(np.abs(extent))))
                bad = ((p < extent[0] - tol) | (p > extent[1] + tol)).any(axis=1)
                i = _first(bad)
                if i >= 0:
                    col.add("contains", EXTENT, f"does not contain position {names[POSITIONS]}[{i}] = "
                            f"{np.array2string(pos[i], precision=6)} ({int(bad.sum())} outside)", i, tc)

    _check_transform(prim, tc, col)


def _check_transform(prim: Usd.Prim, tc: Usd.TimeCode, col: _Collector) -> None:
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc))
    why = similarity_error(m)
    if why is None:
        return
    culprit = prim
    p = prim
    while p and not p.IsPseudoRoot():  # the prim whose own local transform is at fault
        if p.IsA(UsdGeom.Xformable) and similarity_error(np.array(UsdGeom.Xformable(p).GetLocalTransformation(tc))):
            culprit = p
            break
        p = p.GetParent()
    where = "" if culprit == prim else f" (from the transform of {culprit.GetPath()})"
    col.add("transform", TRANSFORM_ATTR, f"local-to-world transform {why}{where}", None, tc)
