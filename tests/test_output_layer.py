"""OutputLayer: sublayers the input, copies root-layer metadata, holds only overs plus new
prims, never touches the input, saves atomically (or not at all on failure)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, Vt

from usd_gs.errors import InputFormatError, UserError
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic, write_gaussian_prim
from usd_gs.usd.output_layer import OutputLayer

META = {"upAxis": "Z", "metersPerUnit": 0.01, "timeCodesPerSecond": 48.0, "framesPerSecond": 24.0,
        "startTimeCode": 1001.0, "endTimeCode": 1100.0, "documentation": "captured scene"}


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _make_input(path: Path) -> Path:
    stage = new_stage(up_axis="Z", meters_per_unit=0.01, default_prim="World")
    write_gaussian_prim(stage, "/World/Scene", random_gaussians(20, 1, seed=1))
    write_gaussian_prim(stage, "/World/Avatar", random_gaussians(10, 1, seed=2))
    layer = stage.GetRootLayer()
    layer.timeCodesPerSecond = 48
    layer.framesPerSecond = 24
    layer.startTimeCode = 1001
    layer.endTimeCode = 1100
    layer.documentation = "captured scene"
    return save_stage_atomic(stage, path)


@pytest.fixture()
def scene(tmp_path) -> Path:
    return _make_input(tmp_path / "scene.usda")


def test_output_layer_structure_and_metadata(scene, tmp_path):
    before = _digest(scene)
    out_path = tmp_path / "relit.usdc"
    out = OutputLayer.create(scene, out_path)
    relit = random_gaussians(10, 1, seed=3)
    write_gaussian_prim(out.stage, "/World/Avatar", relit)  # existing prim -> over
    out.stage.DefinePrim("/World/Lights/Key", "DistantLight")  # new prims -> def
    assert out.save() == out_path
    assert _digest(scene) == before

    layer = Sdf.Layer.OpenAsAnonymous(str(out_path))
    assert out_path.read_bytes()[:8] == b"PXR-USDC"
    assert list(layer.subLayerPaths) == ["./scene.usda"]
    for key, value in META.items():
        assert layer.pseudoRoot.GetInfo(key) == value, key
    assert layer.defaultPrim == "World"
    assert layer.GetPrimAtPath("/World").specifier == Sdf.SpecifierOver
    assert layer.GetPrimAtPath("/World/Avatar").specifier == Sdf.SpecifierOver
    assert layer.GetPrimAtPath("/World/Avatar").typeName == ""
    assert layer.GetPrimAtPath("/World/Scene") is None
    assert layer.GetPrimAtPath("/World/Lights").specifier == Sdf.SpecifierDef
    assert layer.GetPrimAtPath("/World/Lights/Key").typeName == "DistantLight"

    composed = Usd.Stage.Open(str(out_path))
    assert np.array_equal(read_gaussian_prim(composed.GetPrimAtPath("/World/Avatar")).sh, relit.sh)
    original = Usd.Stage.Open(str(scene))
    assert np.array_equal(read_gaussian_prim(composed.GetPrimAtPath("/World/Scene")).positions,
                          read_gaussian_prim(original.GetPrimAtPath("/World/Scene")).positions)
    assert composed.GetStartTimeCode() == 1001 and composed.GetTimeCodesPerSecond() == 48


def test_usda_output_and_relative_parent_directory(scene, tmp_path):
    sub = tmp_path / "out" / "deep"
    sub.mkdir(parents=True)
    out = OutputLayer.create(scene, sub / "o.usda")
    prim = out.stage.OverridePrim("/World/Scene")
    prim.CreateAttribute("usdgs:role", Sdf.ValueTypeNames.Token).Set("scene")
    out.save()
    text = (sub / "o.usda").read_text()
    assert text.startswith("#usda 1.0")
    assert "@../../scene.usda@" in text
    assert "over \"World\"" in text and "def " not in text
    cwd = os.getcwd()
    try:
        os.chdir(sub.parent)  # resolution must not depend on the working directory
        st = Usd.Stage.Open(str(sub / "o.usda"))
        assert st.GetPrimAtPath("/World/Scene").GetAttribute("usdgs:role").Get() == "scene"
        assert st.GetPrimAtPath("/World/Scene").GetTypeName() == "ParticleField3DGaussianSplat"
    finally:
        os.chdir(cwd)


def test_in_memory_stage_composes_input_regardless_of_cwd(scene, tmp_path):
    cwd = os.getcwd()
    try:
        os.chdir("/")
        out = OutputLayer.create(scene, tmp_path / "x.usd")
        assert out.layer.anonymous
        assert out.stage.GetPrimAtPath("/World/Scene").GetTypeName() == "ParticleField3DGaussianSplat"
        assert out.stage.GetEditTarget().GetLayer() == out.layer
    finally:
        os.chdir(cwd)
    assert not (tmp_path / "x.usd").exists()  # nothing written before save()


def test_dot_usd_extension_writes_crate(scene, tmp_path):
    OutputLayer.create(scene, tmp_path / "o.usd").save()
    assert (tmp_path / "o.usd").read_bytes()[:8] == b"PXR-USDC"


def test_refuses_to_overwrite_inputs(scene, tmp_path):
    with pytest.raises(UserError, match="must not be the input"):
        OutputLayer.create(scene, scene)
    with pytest.raises(UserError, match="must not be the input"):
        OutputLayer.create(scene, tmp_path / "." / ".." / tmp_path.name / "scene.usda")
    link = tmp_path / "link.usda"
    link.symlink_to(scene)
    with pytest.raises(UserError, match="must not be the input"):
        OutputLayer.create(link, scene)
    # an output that is a sublayer of the input stage
    base = _make_input(tmp_path / "base.usda")
    top = Sdf.Layer.CreateNew(str(tmp_path / "top.usda"))
    top.subLayerPaths.append("./base.usda")
    top.Save()
    with pytest.raises(UserError, match="layer used by the input stage"):
        OutputLayer.create(tmp_path / "top.usda", base)


def test_bad_input_and_output_paths(tmp_path):
    with pytest.raises(UserError, match="input file does not exist"):
        OutputLayer.create(tmp_path / "missing.usda", tmp_path / "o.usda")
    junk = tmp_path / "junk.usda"
    junk.write_text("this is not usd")
    with pytest.raises(InputFormatError, match="junk.usda: cannot be read as USD"):
        OutputLayer.create(junk, tmp_path / "o.usda")
    with pytest.raises(UserError, match=r"\.usd, \.usdc or \.usda"):
        OutputLayer.create(junk, tmp_path / "o.abc")


def test_context_manager_saves_only_on_success(scene, tmp_path):
    ok = tmp_path / "ok.usdc"
    with OutputLayer.create(scene, ok) as out:
        out.stage.OverridePrim("/World/Avatar").CreateAttribute(
            "usdgs:relight", Sdf.ValueTypeNames.Bool).Set(False)
    assert ok.exists() and out.saved
    bad = tmp_path / "bad.usdc"
    with pytest.raises(ValueError, match="boom"):
        with OutputLayer.create(scene, bad):
            raise ValueError("boom")
    assert not bad.exists()
    assert sorted(os.listdir(tmp_path)) == ["ok.usdc", "scene.usda"]


def test_atomic_save_failure(scene, tmp_path):
    out_path = tmp_path / "o.usdc"
    OutputLayer.create(scene, out_path).save()
    good = _digest(out_path)

    def crash(layer, tmp, args):
        layer.Export(tmp, args=args)
        with open(tmp, "r+b") as fh:  # half-written file, then the process "dies"
            fh.truncate(100)
        raise KeyboardInterrupt

    out = OutputLayer.create(scene, out_path)
    out.stage.OverridePrim("/World/Scene").CreateAttribute("opacities", Sdf.ValueTypeNames.FloatArray).Set(
        Vt.FloatArray(20, 0.5))
    with pytest.raises(KeyboardInterrupt):
        out.save(_export=crash)
    assert _digest(out_path) == good
    assert sorted(os.listdir(tmp_path)) == ["o.usdc", "scene.usda"]
    fresh = tmp_path / "fresh.usda"
    with pytest.raises(KeyboardInterrupt):
        OutputLayer.create(scene, fresh).save(_export=crash)
    assert not fresh.exists() and sorted(os.listdir(tmp_path)) == ["o.usdc", "scene.usda"]
