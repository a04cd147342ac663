"""Writing a ``ParticleField3DGaussianSplat`` prim's specs with ``Sdf`` and ``Vt`` alone (no
``pxr.Usd``): the attribute authoring that :func:`usd_gs.usd.gaussian_prim.write_gaussian_prim`
does in a stage's edit target, and :func:`write_gaussian_layer`, the same prim in a layer of its
own (``usdgs import`` of one capture: it skips importing ``pxr.Usd``/``UsdGeom``/``UsdVol``,
about 0.1 s of a 0.7 s import). Attribute names and conventions: :mod:`usd_gs.usd.gaussian_prim`,
which re-exports the names defined here. This module must not import ``pxr.Usd`` or numba.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Sdf, Vt

from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError, UserError, first_bad_index
from usd_gs.extent import gaussian_extent
from usd_gs.gaussians import GaussianSet, all_finite
from usd_gs.io.atomic import atomic_output
from usd_gs.usd.bulk import vt_from_numpy, vt_writable

GS_TYPE = "ParticleField3DGaussianSplat"

POSITIONS = "positions"
ORIENTATIONS = "orientations"
SCALES = "scales"
OPACITIES = "opacities"
SH_COEFFS = "radiance:sphericalHarmonicsCoefficients"
SH_DEGREE = "radiance:sphericalHarmonicsDegree"
EXTENT = "extent"
HALF_SUFFIX = "h"
SH_DEGREE_FALLBACK = 3

RAW_LOG_SCALES = "usdgs:rawLogScales"
RAW_LOGIT_OPACITIES = "usdgs:rawLogitOpacities"
PLY_PREFIX = "usdgs:ply:"
DTYPE_KEY = "usdgs:dtype"

#: per-particle data attributes (float names); the half name is name + "h"
DATA_ATTRS = (POSITIONS, ORIENTATIONS, SCALES, OPACITIES, SH_COEFFS)

_T = Sdf.ValueTypeNames
_FLOAT_TYPES = {POSITIONS: (_T.Point3fArray, Vt.Vec3fArray), ORIENTATIONS: (_T.QuatfArray, Vt.QuatfArray),
                SCALES: (_T.Float3Array, Vt.Vec3fArray), OPACITIES: (_T.FloatArray, Vt.FloatArray),
                SH_COEFFS: (_T.Float3Array, Vt.Vec3fArray)}
_HALF_TYPES = {POSITIONS: (_T.Point3hArray, Vt.Vec3hArray), ORIENTATIONS: (_T.QuathArray, Vt.QuathArray),
               SCALES: (_T.Half3Array, Vt.Vec3hArray), OPACITIES: (_T.HalfArray, Vt.HalfArray),
               SH_COEFFS: (_T.Half3Array, Vt.Vec3hArray)}
#: numpy dtype -> (Sdf scalar array type, Vt array class) for usdgs:ply:* extras
_EXTRA_TYPES = {
    np.dtype(np.float32): (_T.FloatArray, Vt.FloatArray), np.dtype(np.float64): (_T.DoubleArray, Vt.DoubleArray),
    np.dtype(np.float16): (_T.HalfArray, Vt.HalfArray), np.dtype(np.int32): (_T.IntArray, Vt.IntArray),
    np.dtype(np.uint32): (_T.UIntArray, Vt.UIntArray), np.dtype(np.int64): (_T.Int64Array, Vt.Int64Array),
    np.dtype(np.uint64): (_T.UInt64Array, Vt.UInt64Array), np.dtype(np.uint8): (_T.UCharArray, Vt.UCharArray),
    # no 8/16-bit signed or 16-bit unsigned USD arrays: widen to int, dtype kept in customData
    np.dtype(np.int8): (_T.IntArray, Vt.IntArray), np.dtype(np.int16): (_T.IntArray, Vt.IntArray),
    np.dtype(np.uint16): (_T.IntArray, Vt.IntArray),
}


# --------------------------------------------------------------------------- checks
def _check_finite(arr: np.ndarray, where: str, name: str) -> None:
    if all_finite(arr):  # fast path
        return
    bad = ~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1)
    if bad.any():
        i = first_bad_index(bad)
        raise GaussianDataError(f"{where}: attribute '{name}' element {i} is not finite "
                                f"(value {np.array2string(arr[i], precision=6)}; {int(bad.sum())} bad elements)")


def _check_half(halves: dict, floats: dict, label: str) -> None:
    """``UserError`` naming the attribute and first element whose value does not survive the cast
    to half: beyond +/-65504 (it would be stored as inf) or a positive scale that becomes 0."""
    for name, h in halves.items():
        f = floats[name]
        bad = ~np.isfinite(h) if name != SCALES else ~np.isfinite(h) | ((h <= 0) & (f > 0))
        if bad.any():
            i = first_bad_index(bad.reshape(len(bad), -1))
            raise UserError(f"{label}: attribute '{name}{HALF_SUFFIX}' element {i} is "
                            f"{np.array2string(np.asarray(f[i]), precision=6)}, which half precision cannot hold "
                            f"(|value| <= 65504, scales >= 6e-8; {int(bad.reshape(len(bad), -1).any(axis=1).sum())} "
                            "such elements); use --precision float")



# --------------------------------------------------------------------------- specs
def _attr_spec(prim_spec: Sdf.PrimSpec, name: str, type_name, custom: bool,
               variability=Sdf.VariabilityVarying) -> Sdf.AttributeSpec:
    spec = prim_spec.layer.GetAttributeAtPath(prim_spec.path.AppendProperty(name))
    if spec is None:
        spec = Sdf.AttributeSpec(prim_spec, name, type_name, variability, custom)
    elif spec.typeName != type_name:
        raise UserError(f"{prim_spec.path}: attribute '{name}' already has type {spec.typeName}, "
                        f"cannot write {type_name}")
    return spec


def _put(layer: Sdf.Layer, spec: Sdf.AttributeSpec, value, time) -> None:
    if time is None or time.IsDefault():
        spec.default = value
    else:
        layer.SetTimeSample(spec.path, time.GetValue(), value)


@dataclass
class GaussianValues:
    """The Vt arrays of one :class:`GaussianSet` as :func:`author_gaussian_spec` writes them
    (:func:`gaussian_values`): ``data`` name -> Vt array of the float (or half) attributes,
    ``extent``, ``raw`` ``(name, Sdf type, Vt array, widened dtype or None)`` of the custom ones."""

    precision: str
    degree: int
    data: dict
    extent: object
    raw: list


def gaussian_values(g: GaussianSet, path, keep_raw: bool = True, precision: str = "float",
                    extent: np.ndarray | None = None) -> GaussianValues:
    """The arrays :func:`author_gaussian_spec` writes for ``g`` at prim ``path``; ``UserError``
    (or ``GaussianDataError``) naming the attribute and element for a value USD cannot take.
    Bulk arrays are converted here, before any change block (``vt_from_numpy`` copies once).
    ``extent``: ``g``'s 3-sigma extent when the caller has it (:class:`~usd_gs.usd.bulk.ExtentOfParts`)."""
    n = g.count
    k = sh3dgs.num_coeffs(g.sh_degree)
    label = str(path)
    types = _FLOAT_TYPES if precision == "float" else _HALF_TYPES
    dt = np.float32 if precision == "float" else np.float16
    fresh = vt_writable(types[ORIENTATIONS][1], n, dt)  # reordered straight into USD's storage
    quat_xyzw = fresh[1] if fresh is not None and fresh[1].shape == (n, 4) else np.empty((n, 4), dt)
    quat_xyzw[:, :3] = g.orientations[:, 1:]
    quat_xyzw[:, 3] = g.orientations[:, 0]
    values = {
        POSITIONS: g.positions.astype(dt, copy=False),
        ORIENTATIONS: quat_xyzw,
        SCALES: g.scales.astype(dt, copy=False),
        OPACITIES: g.opacities.astype(dt, copy=False),
        SH_COEFFS: g.sh.astype(dt, copy=False).reshape(n * k, 3),
    }
    if precision == "half":
        _check_half(values, {POSITIONS: g.positions, ORIENTATIONS: g.orientations[:, [1, 2, 3, 0]],
                             SCALES: g.scales, OPACITIES: g.opacities, SH_COEFFS: g.sh.reshape(n * k, 3)}, label)
    vt_values = {name: vt_from_numpy(types[name][1], arr) for name, arr in values.items()}
    extent = Vt.Vec3fArray.FromNumpy(gaussian_extent(g, 3.0) if extent is None else extent)  # == g.extent(3.0)
    raw = []
    if keep_raw:
        if g.log_scales is not None:
            raw.append((RAW_LOG_SCALES, _T.Float3Array, vt_from_numpy(Vt.Vec3fArray, g.log_scales), None))
        if g.logit_opacities is not None:
            raw.append((RAW_LOGIT_OPACITIES, _T.FloatArray, Vt.FloatArray.FromNumpy(g.logit_opacities), None))
        for field, arr in g.extras.items():
            name = PLY_PREFIX + field
            if not Sdf.Path.IsValidNamespacedIdentifier(name):
                raise UserError(f"{path}: extra field '{field}' is not a valid USD attribute name")
            a = np.asarray(arr)
            if a.dtype not in _EXTRA_TYPES:
                raise UserError(f"{path}: extra field '{field}' has dtype {a.dtype}, which has no USD array type")
            sdf_type, vt_cls = _EXTRA_TYPES[a.dtype]
            store = a.reshape(-1)
            if vt_cls is Vt.IntArray and a.dtype != np.int32:
                store = store.astype(np.int32)
            widened = str(a.dtype) if store.dtype != a.dtype else None
            raw.append((name, sdf_type, vt_cls.FromNumpy(np.ascontiguousarray(store)), widened))
    return GaussianValues(precision, g.sh_degree, vt_values, extent, raw)


def check_gaussians(g: GaussianSet, path) -> None:
    """``GaussianDataError`` naming the attribute and element of a non-finite value."""
    for name, arr in (("positions", g.positions), ("orientations", g.orientations), ("scales", g.scales),
                      ("opacities", g.opacities), ("sh", g.sh)):
        _check_finite(arr, f"{path}: cannot write Gaussians", name)


def author_gaussian_spec(layer: Sdf.Layer, spec_path, values: GaussianValues, tc=None) -> None:
    """Author ``values`` (:func:`gaussian_values`) on the prim spec at ``spec_path`` of ``layer``
    (created as an ``over`` when missing): defaults, or time samples at ``tc`` (a time code that
    is not Default; degree, elementSize and interpolation are never time-sampled)."""
    types = _FLOAT_TYPES if values.precision == "float" else _HALF_TYPES
    with Sdf.ChangeBlock():
        prim_spec = layer.GetPrimAtPath(spec_path) or Sdf.CreatePrimInLayer(layer, spec_path)
        for name in DATA_ATTRS:
            attr_name = name if values.precision == "float" else name + HALF_SUFFIX
            spec = _attr_spec(prim_spec, attr_name, types[name][0], custom=False)
            _put(layer, spec, values.data[name], tc)
            if name == SH_COEFFS:
                spec.SetInfo("interpolation", "vertex")  # UsdGeom.Tokens.vertex
                spec.SetInfo("elementSize", sh3dgs.num_coeffs(values.degree))
        d_spec = _attr_spec(prim_spec, SH_DEGREE, _T.Int, custom=False, variability=Sdf.VariabilityUniform)
        d_spec.default = values.degree
        _put(layer, _attr_spec(prim_spec, EXTENT, _T.Float3Array, custom=False), values.extent, tc)
        for name, sdf_type, value, dtype in values.raw:
            spec = _attr_spec(prim_spec, name, sdf_type, custom=True)
            if dtype is not None:
                spec.customData = {"usdgs": {"dtype": dtype}}  # read back as 'usdgs:dtype'
            _put(layer, spec, value, tc)


def gaussian_prim_path(path) -> Sdf.Path:
    """``Sdf.Path(path)``, or ``UserError`` when it is not a prim path."""
    path = Sdf.Path(str(path))
    if not path.IsPrimPath():
        raise UserError(f"'{path}' is not a valid absolute prim path")
    return path


def check_precision(precision: str) -> None:
    if precision not in ("float", "half"):
        raise UserError(f"precision must be 'float' or 'half', not '{precision}'")


def new_layer(up_axis: str = "Y", meters_per_unit: float = 1.0, default_prim: str | None = None) -> Sdf.Layer:
    """A new anonymous layer (nothing is written until :func:`save_stage_atomic`) with the stage
    metadata ``upAxis`` ('Y' or 'Z'), ``metersPerUnit`` (> 0) and ``defaultPrim`` (a root prim
    name; the prim may be defined later): what ``UsdGeom.SetStageUpAxis`` and
    ``SetStageMetersPerUnit`` author on a stage's root layer."""
    if up_axis not in ("Y", "Z"):
        raise UserError(f"up axis must be 'Y' or 'Z', not '{up_axis}'")
    if not (meters_per_unit > 0 and np.isfinite(meters_per_unit)):
        raise UserError(f"metersPerUnit must be a positive number, not {meters_per_unit}")
    layer = Sdf.Layer.CreateAnonymous("tmp.usda")
    layer.pseudoRoot.SetInfo("upAxis", up_axis)
    layer.pseudoRoot.SetInfo("metersPerUnit", float(meters_per_unit))
    if default_prim:
        layer.defaultPrim = default_prim.lstrip("/")
    return layer


def write_gaussian_layer(layer: Sdf.Layer, path, gaussians: GaussianSet, keep_raw: bool = True,
                         precision: str = "float", checked: bool = False,
                         extent: np.ndarray | None = None) -> Sdf.PrimSpec:
    """``write_gaussian_prim`` (default values) into a layer that holds nothing at ``path`` or
    its ancestors yet (such as a :func:`new_layer`), with ``Sdf`` alone: the same specs that
    ``write_gaussian_prim`` authors on a stage whose root layer that is. Ancestors are defined
    as ``Xform``. Returns the prim spec. ``checked``: the caller vouches that every value is
    finite (a capture reader's output: each rejects NaN and infinities naming the element), so
    :func:`check_gaussians` is not run again. ``extent``: see :func:`gaussian_values`."""
    check_precision(precision)
    path = gaussian_prim_path(path)
    if not checked:
        check_gaussians(gaussians, path)
    if any(layer.GetPrimAtPath(p) for p in path.GetPrefixes()):
        raise UserError(f"{path}: the layer already has specs at this path or an ancestor")
    values = gaussian_values(gaussians, path, keep_raw, precision, extent)
    with Sdf.ChangeBlock():
        for p in path.GetPrefixes():  # what UsdGeom.Xform.Define and UsdVol...Define author
            spec = Sdf.CreatePrimInLayer(layer, p)
            spec.specifier = Sdf.SpecifierDef
            spec.typeName = GS_TYPE if p == path else "Xform"
    author_gaussian_spec(layer, path, values)
    return layer.GetPrimAtPath(path)


# --------------------------------------------------------------------------- files
def file_format_args(path) -> tuple[Sdf.FileFormat, dict]:
    """(Sdf file format, export args) for an output path: ``.usda`` text, ``.usd``/``.usdc`` crate."""
    ext = Path(str(path)).suffix.lower().lstrip(".")
    if ext not in ("usd", "usda", "usdc"):
        raise UserError(f"{path}: output must end in .usd, .usdc or .usda")
    fmt = Sdf.FileFormat.FindByExtension(ext)
    return fmt, ({"format": "usdc"} if ext == "usd" else {})


def save_stage_atomic(stage_or_layer, path, durable: bool = False, _export=None) -> Path:
    """Write a stage's root layer (or an ``Sdf.Layer``) to ``path`` atomically.

    Format by extension (``.usd``/``.usdc`` crate, ``.usda`` text). The layer is exported to
    a temporary file in the same directory, then ``os.replace``d onto ``path``: an
    interrupted or failed write leaves no partial file and an existing ``path`` intact.
    ``durable`` also fsyncs the file before the rename (survives power loss; about 0.2 s
    per 250 MB). Returns the absolute path. (``_export`` is a test hook.)
    """
    layer = stage_or_layer.GetRootLayer() if hasattr(stage_or_layer, "GetRootLayer") else stage_or_layer
    path = Path(os.path.abspath(os.fspath(path)))
    _, args = file_format_args(path)
    if not path.parent.is_dir():
        raise UserError(f"{path}: directory {path.parent} does not exist")
    export = _export or (lambda lyr, p, a: lyr.Export(p, args=a))
    with atomic_output(path, durable=durable) as tmp:
        if not export(layer, str(tmp), args):
            raise UserError(f"{path}: USD failed to write the layer")
    return path
