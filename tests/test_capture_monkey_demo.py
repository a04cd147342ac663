"""`usdgs demo make --monkey`: the SOG flipbook as a time-sampled avatar prim in the demo."""

from __future__ import annotations

import numpy as np
import pytest
from capture_testutil import DATA
from pxr import Usd

from usd_gs.cli import main
from usd_gs.demo import monkey as mk
from usd_gs.io.formats import read_capture
from usd_gs.usd.gaussian_prim import read_gaussian_prim

pytestmark = pytest.mark.skipif(not (DATA / "sequences" / "monkey").exists(), reason="shared data not found")


def test_demo_with_monkey(tmp_path):
    out = tmp_path / "stages" / "demo.usda"
    assert main(["demo", "make", "--quick", "--monkey", "--frames", "3", "-o", str(out), "-q"]) == 0
    stage = Usd.Stage.Open(str(out))
    assert "./demo_data/monkey.usdc" in list(stage.GetRootLayer().subLayerPaths)
    prim = stage.GetPrimAtPath(mk.PRIM_PATH)
    assert prim.GetAttribute("usdgs:role").Get() == "avatar"
    assert prim.GetAttribute("positions").GetTimeSamples() == [1.0, 2.0, 3.0]
    first = read_capture(DATA / "sequences" / "monkey" / "monkey_0001.sog")
    m = mk.placement_matrix(first.positions)
    for f in (1, 3):
        src = read_capture(DATA / "sequences" / "monkey" / f"monkey_{mk.monkey_frame(f):04d}.sog")
        got = read_gaussian_prim(prim, Usd.TimeCode(f))
        np.testing.assert_allclose(got.positions, src.transformed(m).positions, atol=1e-6)
    g1 = read_gaussian_prim(prim, Usd.TimeCode(1))
    lo, hi = g1.bounds()
    assert abs(lo[1]) < 1e-5 and abs(hi[1] - mk.MONKEY_HEIGHT) < 1e-5  # feet on the floor, 0.45 m tall
    assert mk.monkey_frame(50) == 50 and mk.monkey_frame(51) == 1
