"""Fuzzing stage reading through the CLI: Gaussian prims with random attribute types, lengths,
NaN placements, SH degrees, transforms and time samples. ``validate`` exits 0 or 1 (problems
listed), ``inspect`` and ``export`` exit 0 or 2 with one message line; an exported file imports
back into a stage that validates. Never exit 1 from a reader or a traceback."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import event, given
from hypothesis import strategies as st
from pxr import Sdf, Vt
from test_fuzz_readers import check_outcome

T = Sdf.ValueTypeNames
# attribute -> [(type name, Vt class, numpy dtype, width)], the first is the schema's
TYPES = {
    "positions": [(T.Point3fArray, Vt.Vec3fArray, np.float32, 3), (T.Point3hArray, Vt.Vec3hArray, np.float16, 3),
                  (T.Double3Array, Vt.Vec3dArray, np.float64, 3), (T.FloatArray, Vt.FloatArray, np.float32, 1)],
    "orientations": [(T.QuatfArray, Vt.QuatfArray, np.float32, 4), (T.QuathArray, Vt.QuathArray, np.float16, 4),
                     (T.FloatArray, Vt.FloatArray, np.float32, 1), (T.Float4Array, Vt.Vec4fArray, np.float32, 4)],
    "scales": [(T.Float3Array, Vt.Vec3fArray, np.float32, 3), (T.Half3Array, Vt.Vec3hArray, np.float16, 3),
               (T.FloatArray, Vt.FloatArray, np.float32, 1)],
    "opacities": [(T.FloatArray, Vt.FloatArray, np.float32, 1), (T.HalfArray, Vt.HalfArray, np.float16, 1),
                  (T.IntArray, Vt.IntArray, np.int32, 1)],
    "radiance:sphericalHarmonicsCoefficients": [(T.Float3Array, Vt.Vec3fArray, np.float32, 3),
                                                (T.Half3Array, Vt.Vec3hArray, np.float16, 3),
                                                (T.Color3fArray, Vt.Vec3fArray, np.float32, 3),
                                                (T.FloatArray, Vt.FloatArray, np.float32, 1)],
}
HALF_NAME = {T.Point3hArray, T.QuathArray, T.Half3Array, T.HalfArray}


def _values(name, rng, m, width, dtype, nan_at):
    if name == "orientations":
        v = rng.normal(size=(m, 4))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
    elif name == "scales":
        v = np.exp(rng.normal(-3, 1, size=(m, width)))
    elif name == "opacities":
        v = rng.uniform(0, 1, size=(m, width))
    else:
        v = rng.normal(size=(m, width))
    v = v[:, :width]
    for i, val in nan_at:
        if m:
            v[i % m, 0] = val
    v = v.astype(dtype) if np.issubdtype(dtype, np.floating) else np.round(v).astype(dtype)
    return v if width > 1 else v.reshape(m)


@st.composite
def stages(draw):
    n = draw(st.integers(0, 6))
    degree = draw(st.sampled_from([0, 1, 2, 3] * 4 + [-1, 4, None, "float"]))
    k = (int(degree) + 1) ** 2 if isinstance(degree, int) and 0 <= degree <= 3 else 4
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.startTimeCode, layer.endTimeCode = 1, 3
    world = Sdf.PrimSpec(layer, "World", Sdf.SpecifierDef, "Xform")
    prim = Sdf.PrimSpec(world, "Splat", Sdf.SpecifierDef, "ParticleField3DGaussianSplat")
    times = draw(st.sampled_from([[], [], [1.0], [1.0, 2.0, 3.0], [-1e9, 0.5], [1.0, 1e300]]))
    for name, options in TYPES.items():
        if name != "positions" and draw(st.integers(0, 9)) == 0:
            continue  # missing attribute
        tn, cls, dtype, width = options[0] if draw(st.integers(0, 11)) else draw(st.sampled_from(options))
        base = n * k if name.startswith("radiance") else n
        m = max(base + (draw(st.sampled_from([1, -1])) if draw(st.integers(0, 11)) == 0 else 0), 0)
        nan_at = [] if draw(st.integers(0, 5)) else [
            (draw(st.integers(0, 50)), draw(st.sampled_from([np.nan, np.inf, 0.0, 7e4, -1.0])))]
        attr_name = name + ("h" if tn in HALF_NAME and name != "opacities" or tn == T.HalfArray else "")
        spec = Sdf.AttributeSpec(prim, attr_name, tn)
        if name.startswith("radiance"):
            spec.SetInfo("interpolation", "vertex" if draw(st.integers(0, 11)) else "constant")
            spec.SetInfo("elementSize", k if draw(st.integers(0, 11)) else 1)
        vals = _values(name, rng, m, width, dtype, nan_at)
        if not times or draw(st.booleans()):
            spec.default = cls.FromNumpy(vals)
        for t in times:
            layer.SetTimeSample(spec.path, t, cls.FromNumpy(vals))
    if draw(st.integers(0, 11)):
        Sdf.AttributeSpec(prim, "extent", T.Float3Array).default = Vt.Vec3fArray([(-1e3, -1e3, -1e3), (1e3, 1e3, 1e3)])
    if degree == "float":
        Sdf.AttributeSpec(prim, "radiance:sphericalHarmonicsDegree", T.Float, Sdf.VariabilityUniform).default = 1.0
    elif degree is not None:
        Sdf.AttributeSpec(prim, "radiance:sphericalHarmonicsDegree", T.Int, Sdf.VariabilityUniform).default = degree
    xf = draw(st.sampled_from(["none", "none", "translate", "scale", "huge", "nonuniform"]))
    if xf != "none":
        op = "xformOp:translate" if xf == "translate" else "xformOp:scale"
        val = {"translate": (1, 2, 3), "scale": (2, 2, 2), "huge": (1e38, 1e38, 1e38), "nonuniform": (1, 2, 3)}[xf]
        Sdf.AttributeSpec(world, op, T.Double3).default = val
        Sdf.AttributeSpec(world, "xformOpOrder", T.TokenArray, Sdf.VariabilityUniform).default = Vt.TokenArray([op])
    return layer.ExportToString()


@given(text=stages())
def test_fuzz_stage_reading(capsys, text):
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "shot.usda"
        src.write_text(text)
        capsys.readouterr()
        rc = main_validate(capsys, src)
        assert rc in (0, 1)
        event(f"validate exit {rc}")
        check_outcome(capsys, ["inspect", str(src)], None)
        ply = Path(d) / "out.ply"
        rc_export = check_outcome(capsys, ["export", str(src), "-o", str(ply), "-q"], ply)
        event(f"export exit {rc_export}")
        if rc_export == 0:
            back = Path(d) / "back.usdc"
            assert check_outcome(capsys, ["import", str(ply), "-o", str(back), "-q"], back) == 0
        if rc == 0:  # a stage that validates is read by every command
            assert main_export(capsys, src, Path(d) / "again.ply") == 0


def main_validate(capsys, src) -> int:
    from usd_gs.cli import main

    rc = main(["validate", str(src), "-q"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return rc


def main_export(capsys, src, out) -> int:
    from usd_gs.cli import main

    rc = main(["export", str(src), "-o", str(out), "-q"])
    capsys.readouterr()
    return rc
