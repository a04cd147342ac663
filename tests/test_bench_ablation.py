"""Ablation runner, Pareto front and the bench report (on the analytic sphere-over-floor case)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from usd_gs.evaluation.ablation import Variant, pareto_front, run_variants, variants
from usd_gs.shadows.dgsm import DGSMConfig


def test_pareto_front_against_brute_force():
    rng = np.random.default_rng(3)
    t, e = rng.uniform(0, 1, 60), rng.uniform(0, 1, 60)
    t[5], e[5] = t[7], e[7]  # a duplicate point: neither dominates the other
    front = set(pareto_front(t, e).tolist())
    for i in range(60):
        dominated = any(t[j] <= t[i] and e[j] <= e[i] and (t[j] < t[i] or e[j] < e[i]) for j in range(60))
        assert (i in front) == (not dominated)
    f = pareto_front(t, e)
    assert np.all(np.diff(t[f]) >= 0) and np.all(np.diff(e[f]) <= 0)


def test_variant_list_covers_the_ablations():
    v = variants(quick=True)
    groups = {x.group for x in v}
    assert {"A sampling", "B mapping", "C atlas", "D culling", "sweep", "diagnostics"} <= groups
    assert {x.cfg.mapping for x in v if x.group == "B mapping"} == {"avg", "simple", "mass", "diag"}
    assert {x.atlas for x in v if x.group == "C atlas"} == {"octahedral", "cube"}
    full = variants(quick=False)
    sizes = {x.cfg.atlas_size for x in full if x.group == "sweep"}
    ks = {x.cfg.K for x in full if x.group == "sweep"}
    ns = {x.cfg.n_samples for x in full if x.group == "sweep"}
    assert sizes == {128, 256, 512, 1024} and ks == {16, 32, 64, 128} and ns == {1, 7, 8, 16, 32}


@pytest.fixture(scope="module")
def sphere_frame():
    import test_metrics_shadow as tm

    from usd_gs.evaluation.shadow_stage import FrameInputs
    from usd_gs.render.camera import Camera
    from usd_gs.shadows.shot import Receivers

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=tm.R_SPHERE)
    cam = Camera.look_at((0.0, 3.0, 0.01), (0.0, 0.0, 0.0), width=96, height=96, fov_y_deg=40.0)
    caster = tm._gaussian_sphere(1500)
    return FrameInputs(1.0, Receivers.build([("/floor", tm._floor(120))]), caster,
                       mesh.vertices + [0.0, tm.H_SPHERE, 0.0], mesh.faces, [tm._light()], cam,
                       np.array([0.0, tm.H_SPHERE, 0.0]))


def test_run_variants_and_report(sphere_frame, tmp_path):
    from usd_gs.evaluation.ablation import culling_timings
    from usd_gs.evaluation.report import write_report

    base = DGSMConfig()
    var = [Variant("default", "default", base),
           Variant("A sampling", "centre sample", replace(base, sampling="center")),
           Variant("B mapping", "simple", replace(base, mapping="simple")),
           Variant("C atlas", "cube", replace(base, refine_contrast=None), atlas="cube"),
           Variant("diagnostics", "oracle", base, oracle=True)]
    rows = run_variants([sphere_frame], var, radius=2.0, up_axis="Y")
    by = {r["name"]: r for r in rows}
    # the oracle (the mesh's own shadow at each receiver) only loses at the receivers' edge blur
    assert by["oracle"]["iou"] > 0.85 and by["oracle"]["sae"] < 0.1
    assert by["default"]["iou"] > 0.8 and by["cube"]["iou"] > 0.8
    # 'simple' (beta = tau*, no 1/sigma scale) is far too weak for centimetre Gaussians
    assert by["simple"]["sae"] > by["default"]["sae"] + 0.1 and by["simple"]["iou"] < by["default"]["iou"]
    assert all(r["seconds"] > 0 for r in rows)
    cull = culling_timings(sphere_frame)
    assert cull["roi_pixels"] > 0 and cull["no_roi_pixels"] >= cull["roi_pixels"]
    res = {"command": "test", "machine": {"cpus": 2, "numba_threads": 1, "load_start": 0.0, "load_end": 0.0,
                                          "platform": "test"}, "roi_radius": 2.0, "seconds": 1.0,
           "stages": [{"label": "sphere", "key": "sphere", "stage": "-", "frames": [1.0], "camera": "look-at",
                       "image": [96, 96], "caster_count": 1500, "receiver_count": 14400, "lights": "L",
                       "variants": rows, "culling": cull}]}
    report = write_report(res, tmp_path)
    text = report.read_text()
    assert "| centre sample |" in text and "0.203 / 0.622 / 0.585" in text
    for name in ("sphere_time_vs_error_sae.png", "sphere_time_vs_error_iou.png"):
        png = tmp_path / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"]({name})" in text
    assert math.isfinite(by["default"]["seconds"])
