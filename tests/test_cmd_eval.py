"""``usdgs eval`` on the processed quick demo: metrics, the stored-matte mode, user errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from usd_gs.cli import main


@pytest.fixture(scope="module")
def processed(quick_demo, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "demo.lit.usdc"
    assert main(["process", str(quick_demo), "-o", str(out), "--frames", "1", "-q", "--aovs", "transmittance"]) == 0
    return out


def _eval(capsys, *argv):
    code = main(["eval", *map(str, argv)])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_eval_json_matches_the_library_and_stored_matte(processed, capsys):
    from usd_gs.evaluation.shadow_stage import caster_strength, evaluate_frame, frame_inputs, open_eval_stage
    from usd_gs.shadows.dgsm import DGSMConfig

    code, out, _ = _eval(capsys, processed, "--frames", "1", "--width", "320", "--json")
    assert code == 0
    res = json.loads(out)
    row = res["frames"][0]
    assert res["avatar"] == "/World/CesiumMan" and res["guide_mesh"] == "/World/CesiumMan_guide"
    assert res["image"] == [320, 180]
    light = res["lighting"]  # paper 4.1 metrics of the relit avatars, orig and relit
    assert light["frames"] == [1.0] and "/World/CesiumMan" in light["avatars"]
    fr = light["per_frame"]["/World/CesiumMan"]["1.0"]
    for key in ("apf_y", "ncm_ab"):
        assert np.isfinite(fr["relit"][key])
    # PAA-Y is null (undetermined, JSON null rather than a non-standard NaN) exactly when the
    # scene neighbourhood's normals determine too few SH coefficients
    from usd_gs.evaluation.lighting_metrics import PAA_MIN_RANK

    assert (fr["relit"]["paa_y"] is None) == (fr["scene_sh_rank"] < PAA_MIN_RANK)
    assert "NaN" not in out
    # the quick demo's 5,000-Gaussian CesiumMan casts a visibly wider, softer shadow than its mesh
    assert 0.4 < row["iou"] < 0.9 and 0.0 < row["sae"] < 0.2 and 0.5 < row["bf"] <= 1.0
    assert row["shadow_px"] > 100 and row["roi_px"] > 10 * row["shadow_px"]
    # --matte stage reads the stored transmittance (every caster's shadow, lights combined linearly):
    # never weaker than CesiumMan's own (the process run used the same default DGSM), equal where only
    # CesiumMan's shadow falls, and at frame 1 that is all of its ROI
    ctx = open_eval_stage(str(processed), width=320)
    fi = frame_inputs(ctx, 1.0)
    s_rec, _ = caster_strength(fi.caster, fi.receivers, fi.lights, DGSMConfig())
    s_st = ctx.stored_strength(fi.receivers, 1.0)
    assert (s_st >= s_rec - 1e-5).all()
    p = fi.receivers.gaussians.positions
    box = np.abs(p[:, [0, 2]] - fi.centre[[0, 2]]).max(axis=1) <= 2.0
    cm = (s_rec > 0) & box
    assert cm.sum() > 100 and np.abs(s_st - s_rec)[cm].max() < 1e-5
    code, out2, _ = _eval(capsys, processed, "--frames", "1", "--width", "320", "--json", "--matte", "stage")
    assert code == 0
    row2 = json.loads(out2)["frames"][0]
    assert row2["iou"] == pytest.approx(row["iou"], abs=1e-3)
    # an empty matte scores IoU 0 against the same reference
    r0 = evaluate_frame(fi, np.zeros_like(s_rec))
    assert r0["iou"] == 0.0 and r0["bf"] == 0.0 and r0["sae"] > 0.3


def test_eval_table(processed, capsys):
    code, out, _ = _eval(capsys, processed, "--frames", "1", "--width", "160")
    assert code == 0
    assert "SM-IoU" in out and "mean" in out
    assert "lighting consistency" in out and "/World/CesiumMan" in out and "paa_y orig" in out


def test_eval_user_errors(quick_demo, processed, capsys, tmp_path):
    from pxr import Sdf

    code, _, err = _eval(capsys, quick_demo)
    assert code == 2 and "not a processed stage" in err
    code, _, err = _eval(capsys, processed, "--camera", "/World/Nope", "--frames", "1")
    assert code == 2 and "/World/Nope" in err
    # a processed stage whose guide mesh is deactivated
    layer = Sdf.Layer.CreateNew(str(tmp_path / "noguide.usda"))
    layer.subLayerPaths = [str(processed)]
    spec = Sdf.CreatePrimInLayer(layer, "/World/CesiumMan_guide")
    spec.specifier = Sdf.SpecifierOver
    spec.active = False
    layer.Save()
    code, _, err = _eval(capsys, tmp_path / "noguide.usda", "--frames", "1")
    assert code == 2 and "no guide mesh" in err and "usdgs:demo:guideFor" in err
    code, _, err = _eval(capsys, processed, "--radius", "0")
    assert code == 2 and "--radius" in err
