"""usdgs process authors SH in each prim's own frame: for a rotated prim the output SH are the
input's local SH times the per-Gaussian colour factors (world-space SH, which the pipeline
computes with, would be rotated a second time by a renderer)."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from usd_gs.cli import main
from usd_gs.sh3dgs import C0
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import read_gaussian_prim, write_gaussian_prim
from usd_gs.usd.output_author import LIGHT_SCALE, SH_COEFFS, TRANSMITTANCE
from usd_gs.usd.schema import apply_role


def test_rotated_prim_gets_local_frame_sh(quick_demo, tmp_path):
    shot = tmp_path / "spin.usda"
    layer = Sdf.Layer.CreateNew(str(shot))
    layer.subLayerPaths.append(str(quick_demo))
    layer.Save()
    stage = Usd.Stage.Open(str(shot))
    g = random_gaussians(400, 3, seed=4)
    g.positions[:] = g.positions * 0.04  # a 0.4 m blob with view-dependent colour
    g.opacities[:] = 0.8
    write_gaussian_prim(stage, "/World/Spinner", g, keep_raw=False)
    prim = stage.GetPrimAtPath("/World/Spinner")
    xf = UsdGeom.Xformable(prim)
    xf.AddTranslateOp().Set((0.5, 1.0, 0.3))
    rot = xf.AddRotateYOp()
    for f in (1, 2):
        rot.Set(40.0 * f, f)  # moving: a dynamic prim, rotated
    apply_role(prim, "avatar")
    stage.GetRootLayer().Save()
    out = tmp_path / "spin.lit.usdc"
    assert main(["process", str(shot), "-o", str(out), "--frames", "2", "-q", "--aovs", "transmittance,lightScale",
                 "--precision", "float", "--sh-tolerance", "0"]) == 0

    local = read_gaussian_prim(prim, Usd.TimeCode(2), world=False).sh.astype(np.float64)
    world = read_gaussian_prim(prim, Usd.TimeCode(2)).sh.astype(np.float64)
    assert np.abs(local[:, 1:] - world[:, 1:]).max() > 1e-2  # the transform does rotate the SH
    lit = Usd.Stage.Open(str(out))
    o = lit.GetPrimAtPath("/World/Spinner")
    n, k = local.shape[:2]
    sh_out = np.asarray(o.GetAttribute(SH_COEFFS).Get(2), np.float64).reshape(n, k, 3)
    scale = np.asarray(o.GetAttribute(LIGHT_SCALE).Get(2), np.float64)
    t = o.GetAttribute(TRANSMITTANCE).Get(2)
    t = np.ones(n) if t is None else np.asarray(t, np.float64)
    f = scale * t[:, None]  # gamma 1, direct fraction 1
    # colour = f (0.5 + SH): sh0' = (f (0.5 + C0 sh0) - 0.5) / C0, higher bands f sh
    np.testing.assert_allclose(sh_out[:, 0], (f * (0.5 + C0 * local[:, 0]) - 0.5) / C0, atol=2e-4)
    np.testing.assert_allclose(sh_out[:, 1:], f[:, None, :] * local[:, 1:], atol=2e-4)
