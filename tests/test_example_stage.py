"""The shipped example stage is what its generator makes, and it is valid."""

import importlib.util
from pathlib import Path

import numpy as np

from usd_gs.usd.gaussian_prim import find_gaussian_prims, read_gaussian_prim
from usd_gs.usd.stage import open_stage
from usd_gs.usd.validate import validate_stage

STAGES = Path(__file__).resolve().parents[1] / "stages"


def _generator():
    spec = importlib.util.spec_from_file_location("make_example", STAGES / "make_example.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_example_stage_is_reproducible(tmp_path):
    out = _generator().make_example(tmp_path / "example.usda")
    assert out.read_bytes() == (STAGES / "example.usda").read_bytes()
    assert (out.stat().st_mode & 0o777) != 0o600  # normal permissions, not mkstemp's


def test_example_stage_contents():
    from pxr import Usd

    stage = open_stage(str(STAGES / "example.usda"))
    assert validate_stage(stage) == []
    prims = {str(p.GetPath()): p for p in find_gaussian_prims(stage)}
    assert sorted(prims) == ["/World/Ball", "/World/Floor", "/World/Walker"]
    walker1 = read_gaussian_prim(prims["/World/Walker"], Usd.TimeCode(1))
    walker24 = read_gaussian_prim(prims["/World/Walker"], Usd.TimeCode(24))
    np.testing.assert_allclose(walker24.positions - walker1.positions, np.tile([3.0, 0, 0], (200, 1)), atol=1e-5)
    ball = read_gaussian_prim(prims["/World/Ball"], Usd.TimeCode(6))
    assert ball.count == 60 and abs(ball.positions[:, 1].mean() - 1.3) < 0.05
