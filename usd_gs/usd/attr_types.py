"""Authored value types of a Gaussian prim's attributes, checked before any value is read.

A layer can author a schema attribute with another type than the schema's (``float[]``
orientations, a ``token`` SH degree): USD then returns values of the authored type, which the
readers would misread or crash on. :func:`type_problems` lists every such attribute (the type
of its strongest spec that declares one against the expected value type, roles ignored:
``point3f[]`` and ``float3[]`` hold the same values); :func:`require_types` raises the first as a
``GaussianDataError`` naming the prim and attribute.
"""

from __future__ import annotations

from pxr import Sdf, Usd

from usd_gs.errors import GaussianDataError

_T = Sdf.ValueTypeNames
#: attribute name -> the value type it must hold (Sdf.ValueTypeName; role ignored)
EXPECTED = {
    "positions": _T.Float3Array, "positionsh": _T.Half3Array,
    "orientations": _T.QuatfArray, "orientationsh": _T.QuathArray,
    "scales": _T.Float3Array, "scalesh": _T.Half3Array,
    "opacities": _T.FloatArray, "opacitiesh": _T.HalfArray,
    "radiance:sphericalHarmonicsCoefficients": _T.Float3Array,
    "radiance:sphericalHarmonicsCoefficientsh": _T.Half3Array,
    "radiance:sphericalHarmonicsDegree": _T.Int,
    "extent": _T.Float3Array,
    "usdgs:rawLogScales": _T.Float3Array,
    "usdgs:rawLogitOpacities": _T.FloatArray,
}
PLY_PREFIX = "usdgs:ply:"


def _authored_type(attr: Usd.Attribute):
    for spec in attr.GetPropertyStack(Usd.TimeCode.EarliestTime()):
        tn = getattr(spec, "typeName", None)
        if tn:
            return tn
    return None


def type_problems(prim: Usd.Prim) -> list[tuple[str, str]]:
    """(attribute name, message) for every Gaussian attribute of ``prim`` authored with the wrong
    value type (``usdgs:ply:*`` must be arrays of any type)."""
    out = []
    for attr in prim.GetAuthoredAttributes():
        name = attr.GetName()
        want = EXPECTED.get(name)
        if want is None and not name.startswith(PLY_PREFIX):
            continue
        tn = _authored_type(attr)
        if tn is None:
            continue
        if want is None:
            if not tn.isArray:
                out.append((name, f"is authored as {tn}, a scalar; PLY fields must be arrays (one value per Gaussian)"))
        elif tn.type != want.type:
            out.append((name, f"is authored as {tn}, expected {want}"))
    return out


def require_types(prim: Usd.Prim) -> None:
    """``GaussianDataError`` naming the prim and attribute of the first :func:`type_problems` entry."""
    problems = type_problems(prim)
    if problems:
        name, msg = problems[0]
        more = f" (and {len(problems) - 1} more wrongly typed attribute(s))" if len(problems) > 1 else ""
        raise GaussianDataError(f"{prim.GetPath()}: attribute '{name}' {msg}{more}")
