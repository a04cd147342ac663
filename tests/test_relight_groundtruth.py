"""Known-light ground truth for relighting (usd_gs.evaluation.relight_groundtruth).

Thresholds are measured values (small sizes: 1500 avatar and 6000 scene Gaussians, 16 x 32
environment, 32^2 probe faces) minus a margin; see README "Relighting ground truth" for the
full-size figures and why the project's relighting misses 30 dB.
"""

import numpy as np
import pytest

from usd_gs import sh3dgs
from usd_gs.evaluation.relight_groundtruth import (
    avatar_ground_truth,
    make_avatar,
    make_scene,
    psnr,
    relight_ground_truth,
)


def test_bake_matches_the_analytic_lamp_on_the_floor():
    """Environment off (zero image), lamp only: a floor Gaussian's colour is albedo * I cos / (pi r^2)."""
    sc = make_scene(3000, props=False, lamp_rgb=(30.0, 25.0, 18.0))
    sc_env = make_scene(3000, props=False, lamp_rgb=(0.0, 0.0, 0.0))
    col = 0.5 + sh3dgs.C0 * sc.surfaces.sh[:, 0].astype(np.float64)
    env_only = 0.5 + sh3dgs.C0 * sc_env.surfaces.sh[:, 0].astype(np.float64)
    p = sc.surfaces.positions.astype(np.float64)
    floor = (np.abs(p[:, 1]) < 1e-6) & (np.abs(p[:, 0]) < 0.8) & (np.abs(p[:, 2]) < 0.8)  # unshadowed patch
    d = sc.lamp_pos - p[floor]
    r2 = np.sum(d * d, axis=1)
    lamp = sc.albedo[floor] * (sc.lamp_rgb * (d[:, 1] / np.sqrt(r2) / r2)[:, None]) / np.pi
    assert floor.sum() > 10
    assert np.allclose(col[floor] - env_only[floor], lamp, rtol=1e-4, atol=1e-5)


def test_ground_truth_of_a_flat_avatar_patch_equals_the_floor_bake():
    """An avatar Gaussian lying on the floor, facing up, gets the floor's own (direct) irradiance
    plus the light the wall and the box reflect onto it (the bake has no interreflection; the
    avatar's ground truth sees the baked scene): more than the floor, by less than a quarter."""
    sc = make_scene(3000, props=False)
    av = make_avatar(200)
    av.positions[:] = [0.3, 0.001, 0.2]
    av.orientations[:] = [1.0, 0.0, 0.0, 0.0]
    av.orientations[:, [0, 1]] = [np.sqrt(0.5), -np.sqrt(0.5)]  # local z -> +y
    albedo = np.full((av.count, 3), 0.5)
    truth = avatar_ground_truth(sc, av, albedo)
    i = np.argmin(np.linalg.norm(sc.surfaces.positions - [0.3, 0.0, 0.2], axis=1))
    floor = (0.5 + sh3dgs.C0 * sc.surfaces.sh[i, 0].astype(np.float64)) / sc.albedo[i] * 0.5
    assert np.all(truth >= 0.995 * floor) and np.all(truth <= 1.25 * floor)
    assert np.ptp(truth, axis=0).max() < 1e-9  # same point, same normal


@pytest.fixture(scope="module")
def env_only():
    return relight_ground_truth(n_avatar=1500, n_surface=6000, lamp=False, props=False, metrics=False)


def test_environment_only(env_only):
    r = env_only
    assert psnr(r["truth"], r["truth"]) == float("inf")
    # measured 28.8 / 28.8 / 8.3 dB (relit / relit with the mesh normals / unrelit); no
    # gaussian_normals point into the body (1.1 % before the orientation propagation: 22.4 dB)
    assert r["psnr_relit"] > r["psnr_orig"] + 17.0
    assert r["psnr_relit"] > 26.0
    assert r["psnr_relit"] > r["psnr_relit_true_normals"] - 1.0
    assert r["psnr_relit_true_normals"] > 26.0
    assert r["flipped_normals"] < 0.005


def test_lamp_and_rasteriser_dilation():
    """With the lamp: probes are rendered without the display dilation (measured 26.1 dB with
    the mesh normals); the 3DGS 0.3 px^2 dilation, even opacity-compensated, loses the small
    emitter's tails (19.3 dB). Relit beats unrelit on PSNR and on NCM-ab; APF-Y does not
    improve here (see README), PAA-Y is undetermined (floor, wall and box: SH rank 3)."""
    r = relight_ground_truth(n_avatar=1500, n_surface=6000, lamp=True, props=False, metrics=True)
    r3 = relight_ground_truth(n_avatar=1500, n_surface=6000, lamp=True, props=False, metrics=False, dilation=0.3)
    assert r["psnr_relit"] > r["psnr_orig"] + 15.0  # measured 26.0 / 6.9 dB (19.7 dB with 1.1 % flipped normals)
    assert r["psnr_relit_true_normals"] > 24.0
    assert r["psnr_relit_true_normals"] > r3["psnr_relit_true_normals"] + 4.0
    assert r["metrics"]["improvement"]["ncm_ab"] > 2.0
    assert r["metrics_gt"]["improvement"]["ncm_ab"] > 2.0
    assert r["metrics"]["scene_sh_rank"] == 3 and np.isnan(r["metrics"]["relit"]["paa_y"])


def test_props_scene_paa_improves_for_relit_and_exact_colours():
    """With the two spheres the neighbourhood's normals determine the lighting (SH rank >= 12);
    the spheres' undersides are hidden from the avatar and left out (with them, their flipped
    pseudo-normals made the exact colours score no better than the unlit avatar). Measured at
    this size: PAA-Y 1.92 unlit, 1.34 relit, 1.33 exact. The relit PSNR needs the parallax probes'
    occlusion test (a leg saw both a sphere and the sky behind it): measured 28.7 dB."""
    r = relight_ground_truth(n_avatar=1500, n_surface=6000, lamp=True, props=True, metrics=True)
    assert r["psnr_relit"] > 27.5
    for key in ("metrics", "metrics_gt"):
        m = r[key]
        assert m["scene_sh_rank"] >= 12 and m["n_hidden"] > 0
        assert m["improvement"]["paa_y"] > 0.3 and m["improvement"]["ncm_ab"] > 2.0
