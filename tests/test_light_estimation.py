"""Light estimation (paper 3.1): numba kernels vs the numpy reference, recovery of known emitters,
edge cases, and smoke runs on the real captures."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lights_scene import LUMA, make_emitter_test_scene, read_capture  # noqa: E402

from numba_kernels.light_estimation import (  # noqa: E402
    base_scores,
    estimate_lights_arrays,
    score_cues,
    select_tail,
)
from numba_kernels.reference import light_estimation as reference  # noqa: E402
from usd_gs import sh3dgs  # noqa: E402
from usd_gs.errors import GaussianDataError, UserError  # noqa: E402
from usd_gs.gaussians import GaussianSet, alpha_weighted_centroid  # noqa: E402
from usd_gs.relight.light_estimation import (  # noqa: E402
    LightEstimationConfig,
    estimate_lights,
    make_viewpoints,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="module")
def scene_deg0():
    return make_emitter_test_scene(seed=0, degree=0, window_luminance=6.0)


def _random_set(n, degree, seed):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-3, 3, (n, 3))
    sh = rng.normal(0.0, 0.8, (n, sh3dgs.num_coeffs(degree), 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    opac = rng.uniform(0, 1, n)
    opac[:5] = 0.0
    return GaussianSet(pos, q, rng.uniform(0.01, 0.3, (n, 3)), opac, sh)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_cues_match_reference(degree):
    """Per-Gaussian cues from the numba SH evaluation equal the sh3dgs-based numpy reference."""
    g = _random_set(600, degree, seed=degree)
    cfg = replace(LightEstimationConfig(), roi_radius=4.0)
    c = np.array([0.2, -0.1, 0.3])
    vp = make_viewpoints(c, cfg)
    vp[0] = g.positions[7]  # a Gaussian exactly at a viewpoint (zero direction) must stay finite
    status, *got = score_cues(g.positions, g.opacities, g.sh, c, vp, cfg.roi_radius, cfg.min_opacity, cfg.max_weight)
    in_roi, *want = reference.score_cues(g.positions, g.opacities, g.sh, c, vp, cfg)
    np.testing.assert_array_equal(status == 1, in_roi)
    assert 0 < in_roi.sum() < 600
    for name, a, b in zip(("mean_y", "max_y", "stability", "dominance", "lum"), got, want, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, err_msg=name)
    if degree == 0:
        assert np.all(got[2][in_roi] == 1.0) and np.all(got[3][in_roi] == 1.0)
    else:
        assert got[2][in_roi].min() < 0.9 and got[3][in_roi].min() < 0.9


def test_cue_values_analytic():
    """One Gaussian, degree 1, with only the z-band coefficient: colours and cues by hand."""
    sh = np.zeros((1, 4, 3), np.float32)
    sh[0, 0, :] = (1.5 - 0.5) / sh3dgs.C0  # DC colour 1.5 in every channel
    sh[0, 2, :] = 1.0  # + C1 * z
    pos = np.array([[0.0, 0.0, 2.0]], np.float32)
    views = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 4.0]])  # directions +z and -z
    status, mean_y, max_y, stab, dom, lum = score_cues(pos, np.ones(1, np.float32), sh, np.zeros(3), views,
                                                       10.0, 0.0, 0.25)
    c_up, c_down = 1.5 + sh3dgs.C1, 1.5 - sh3dgs.C1
    assert status[0] == 1
    assert mean_y[0] == pytest.approx((c_up + c_down) / 2, abs=1e-6)
    assert max_y[0] == pytest.approx(c_up, abs=1e-6)
    assert stab[0] == pytest.approx(1 - sh3dgs.C1 / 1.5, abs=1e-6)
    assert dom[0] == pytest.approx(3 * 1.5 ** 2 / (3 * 1.5 ** 2 + 3 / (4 * math.pi)), abs=1e-7)
    assert lum[0] == pytest.approx(0.75 * 1.5 + 0.25 * c_up, abs=1e-6)


def test_soft_clip_is_continuous_monotone_identity_below_knee():
    lum = np.linspace(0.0, 50.0, 5001)
    n = lum.size
    ones = np.ones(n)
    out, raw = base_scores(np.ones(n, np.int8), lum, ones, ones, np.ones(n, np.float32), 2.0, 1.0, 1.0)
    np.testing.assert_array_equal(raw, lum)
    below = lum <= 2.0
    np.testing.assert_array_equal(out[below], lum[below])
    assert np.all(np.diff(out) > 0)
    assert np.max(np.abs(np.diff(out))) <= 0.01 + 1e-12  # slope <= 1 everywhere: continuous, no jump
    assert out[-1] == pytest.approx(2.0 * (1 + math.log(1 + 48.0 / 2.0)))


def test_select_tail_ties_and_positivity():
    s = np.array([0.0, 3.0, 1.0, 3.0, 2.0, 3.0, -1.0, 2.0])
    np.testing.assert_array_equal(select_tail(s, 2), [1, 3])  # ties at the threshold: lower index first
    np.testing.assert_array_equal(select_tail(s, 4), [1, 3, 4, 5])
    np.testing.assert_array_equal(select_tail(s, 100), [1, 2, 3, 4, 5, 7])  # only positive scores
    assert select_tail(np.zeros(5), 3).size == 0


def test_full_pipeline_matches_reference():
    sc = make_emitter_test_scene(seed=3, degree=3, spacing=0.25, window_luminance=6.0, rest_amplitude=0.3)
    g = sc.gaussians
    cfg = replace(LightEstimationConfig(), min_candidates=300, clip_percentile=98.0)
    vp = make_viewpoints(sc.centroid, cfg)
    got = estimate_lights_arrays(g.positions, g.opacities, g.sh, sc.centroid, vp, 3, cfg, peak_batch=8)
    want = reference.estimate_lights_arrays(g.positions, g.opacities, g.sh, sc.centroid, vp, 3, cfg)
    assert got["n_roi"] == want["n_roi"] and got["n_tail"] == want["n_tail"] == 300
    np.testing.assert_array_equal(got["index"], want["index"])
    assert got["index"].size == 3
    for key in ("position", "color", "intensity", "score", "base", "raw"):
        np.testing.assert_allclose(got[key], want[key], rtol=1e-9, atol=1e-12, err_msg=key)
    assert got["knee"] == pytest.approx(want["knee"], rel=1e-12)
    assert np.sum(got["base"] < got["raw"]) > 50  # the soft clip is active in this scene


@pytest.mark.parametrize("k", [1, 3, 6])
def test_lazy_peakness_equals_full_evaluation(scene_deg0, k):
    g, c = scene_deg0.gaussians, scene_deg0.centroid
    cfg = LightEstimationConfig()
    vp = make_viewpoints(c, cfg)
    lazy = estimate_lights_arrays(g.positions, g.opacities, g.sh, c, vp, k, cfg, peak_batch=64)
    full = estimate_lights_arrays(g.positions, g.opacities, g.sh, c, vp, k, cfg, lazy=False)
    assert full["n_peak_evaluated"] == full["n_tail"] == 1000
    # the 720 window Gaussians can beat the 3rd emitter before peakness, so they are evaluated
    assert lazy["n_peak_evaluated"] < (65 if k == 1 else 1000)  # it skipped the dim candidates...
    assert lazy["index"].size == k
    for key in ("index", "position", "color", "intensity", "score"):  # ...without changing the result
        np.testing.assert_array_equal(lazy[key], full[key], err_msg=key)


@pytest.mark.parametrize("degree, up, window", [(0, "Y", 6.0), (3, "Y", 1.5), (1, "Z", 6.0), (2, "Z", None)])
def test_recovers_known_emitters(degree, up, window):
    """k lights within 5 cm of the true emitters, ordered by intensity, hue of the emitter colour.

    The window (1.5 x 1.2 m of Gaussians with luminance 6) is brighter per Gaussian than two of
    the three compact emitters (5 and 3), so only peakness keeps it out."""
    sc = make_emitter_test_scene(seed=1, degree=degree, up_axis=up, window_luminance=window)
    lights = estimate_lights(sc.gaussians, sc.centroid, k=3, config=LightEstimationConfig(up_axis=up))
    assert len(lights) == 3
    for light, centre, rgb in zip(lights, sc.emitter_centres, sc.emitter_rgb, strict=True):
        assert np.linalg.norm(light.position - centre) < 0.05
        chroma = light.color / np.linalg.norm(light.color)
        assert chroma @ (rgb / np.linalg.norm(rgb)) > 0.999
        # colour seen from the character ~ emitter colour (+-2 % jitter, small SH rest terms)
        assert light.color @ LUMA == pytest.approx(rgb @ LUMA, rel=0.06)
        assert light.index not in set(sc.window_index.tolist())
    intens = [light.intensity for light in lights]
    assert intens == sorted(intens, reverse=True)
    # degree 0: intensity = opacity (0.9) * luminance, no clipping below the knee except the brightest
    if degree == 0:
        assert intens[1] == pytest.approx(0.9 * 5.0, rel=0.03) and intens[2] == pytest.approx(0.9 * 3.0, rel=0.03)


def test_intensity_unclipped_when_knee_is_low(scene_deg0):
    """A knee far below the emitters changes neither the chosen lights nor their intensities."""
    sc = scene_deg0
    low = LightEstimationConfig(clip_percentile=50.0)
    a = estimate_lights(sc.gaussians, sc.centroid, k=3)
    b = estimate_lights(sc.gaussians, sc.centroid, k=3, config=low)
    for x, y, rgb in zip(a, b, sc.emitter_rgb, strict=True):
        assert np.linalg.norm(x.position - y.position) < 0.01
        assert y.intensity == pytest.approx(x.intensity, rel=0.02)
        assert y.intensity == pytest.approx(0.9 * (rgb @ LUMA), rel=0.03)


@pytest.mark.parametrize("change", [{"peak_power": 0.0}, {"peak_inner_radius": 0.0}])
def test_window_wins_without_peakness_or_shell(scene_deg0, change):
    """Controls for the test above: with peakness off (power 0), or with the full ball as the
    neighbourhood (inner radius 0: each lamp is its own neighbourhood), the window beats an emitter."""
    cfg = LightEstimationConfig(**change)
    lights = estimate_lights(scene_deg0.gaussians, scene_deg0.centroid, k=3, config=cfg)
    assert any(light.index in set(scene_deg0.window_index.tolist()) for light in lights)


def test_no_bias_toward_large_gaussians(scene_deg0):
    g = scene_deg0.gaussians
    a = estimate_lights(g, scene_deg0.centroid, k=3)
    big = replace(g, scales=g.scales * 25.0)
    b = estimate_lights(big, scene_deg0.centroid, k=3)
    assert [x.index for x in a] == [x.index for x in b]
    assert [x.intensity for x in a] == [x.intensity for x in b]


def test_deterministic_and_metres(scene_deg0):
    g, c = scene_deg0.gaussians, scene_deg0.centroid
    a = estimate_lights(g, c, k=3)
    b = estimate_lights(g, c, k=3)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.position, y.position) and np.array_equal(x.color, y.color)
        assert x.score == y.score and x.intensity == y.intensity
    # the same scene in centimetres (metersPerUnit 0.01) gives the same lights, scaled
    cm = g.transformed(np.diag([100.0, 100.0, 100.0, 1.0]))
    d = estimate_lights(cm, c * 100.0, k=3, meters_per_unit=0.01)
    assert [x.index for x in a] == [x.index for x in d]
    for x, y in zip(a, d, strict=True):
        np.testing.assert_allclose(y.position, 100.0 * x.position, rtol=1e-5)


def test_nms_separates_and_limits(scene_deg0):
    g, c = scene_deg0.gaussians, scene_deg0.centroid
    one = estimate_lights(g, c, k=1)
    assert len(one) == 1 and np.linalg.norm(one[0].position - scene_deg0.emitter_centres[0]) < 0.05
    many = estimate_lights(g, c, k=8)
    pos = np.array([x.position for x in many])
    assert len(many) == 8
    d = np.linalg.norm(g.positions[[x.index for x in many]][:, None] - g.positions[[x.index for x in many]][None],
                       axis=-1)
    assert d[~np.eye(8, dtype=bool)].min() >= 1.0
    assert np.all(np.isfinite(pos))
    # a huge NMS distance leaves a single light
    assert len(estimate_lights(g, c, k=3, config=LightEstimationConfig(nms_distance=100.0))) == 1


def test_edge_cases(scene_deg0):
    g, c = scene_deg0.gaussians, scene_deg0.centroid
    assert estimate_lights(GaussianSet.empty(), c, k=2) == []
    assert estimate_lights(g, c, k=0) == []
    assert estimate_lights(g, c + 1000.0, k=2) == []  # nothing in the ROI
    bad = replace(g, sh=g.sh.copy(), label="scene.ply")
    bad.sh[123, 0, 1] = np.nan
    with pytest.raises(GaussianDataError, match=r"scene\.ply.*'sh' element 123"):
        estimate_lights(bad, c, k=2)
    with pytest.raises(UserError, match="nms_distance"):
        estimate_lights(g, c, k=2, config=LightEstimationConfig(nms_distance=-1.0))
    with pytest.raises(UserError, match="centroid"):
        estimate_lights(g, [0.0, np.nan, 0.0], k=2)


def test_far_gaussians_change_nothing_and_are_not_scanned(scene_deg0, monkeypatch):
    """A scene with three times its Gaussians in a block 40 m away (outside the 6 m ROI): the
    lights and planar emitters are those of the whole-scene path bit for bit (the kernel on the
    ROI's Gaussians only, indices mapped back), and the ROI path was the one taken."""
    import usd_gs.relight.light_estimation as le

    g, c = scene_deg0.gaussians, scene_deg0.centroid
    far = GaussianSet.concatenate([g, g, g])
    far.positions[:] += np.float32([40.0, 0.0, 0.0])
    both = GaussianSet.concatenate([far, g])  # (the near part last: mapped indices must move)
    taken = []
    roi_scene = le._roi_scene

    def spy(*args):
        out = roi_scene(*args)
        taken.append(out[1] is not None)
        return out

    monkeypatch.setattr(le, "_roi_scene", spy)
    new = estimate_lights(both, c, k=3)
    new_rect = le.estimate_rect_lights(both, c)
    assert taken == [True, True]
    monkeypatch.setattr(le, "_roi_scene", lambda s, centre, r, *_: (s, None))
    old = estimate_lights(both, c, k=3)
    old_rect = le.estimate_rect_lights(both, c)
    assert len(new) == len(old) == 3 and len(new_rect) == len(old_rect) >= 1
    for a, b in zip(new, old, strict=True):
        assert a.index == b.index and a.index >= far.count
        assert np.array_equal(a.position, b.position) and np.array_equal(a.color, b.color)
        assert (a.intensity, a.score) == (b.intensity, b.score)
    assert repr(new_rect) == repr(old_rect)
    # values the caller checked (the pipeline's, read through usd_gs.usd): no pass over them, the same lights
    import usd_gs.usd.gaussian_layer as gl

    monkeypatch.setattr(le, "_roi_scene", spy)
    scanned = []
    all_finite = gl.all_finite
    monkeypatch.setattr(gl, "all_finite", lambda a: scanned.append(a.size) or all_finite(a))
    taken.clear()
    checked = estimate_lights(both, c, k=3, values_checked=True)
    checked_rect = le.estimate_rect_lights(both, c, values_checked=True)
    assert taken == [True, True] and scanned == []
    assert [(a.index, a.position.tolist(), a.color.tolist(), a.intensity, a.score) for a in checked] == \
        [(a.index, a.position.tolist(), a.color.tolist(), a.intensity, a.score) for a in new]
    assert repr(checked_rect) == repr(new_rect)
    estimate_lights(both, c, k=3)
    assert scanned == [both.positions.size, both.opacities.size, both.sh.size]  # (the spy sees the default's pass)
    # a non-finite value anywhere (here far outside the ROI) is still named
    bad = replace(both, sh=both.sh.copy(), label="big.ply")
    bad.sh[5, 0, 2] = np.inf
    with pytest.raises(GaussianDataError, match=r"big\.ply.*'sh' element 5"):
        estimate_lights(bad, c, k=2)


def test_point_and_planar_estimates_share_one_roi_through_the_blocks(scene_deg0, monkeypatch):
    """With the scene's rows as ``PointBlocks`` (the pipeline's static bricks), the point and the
    planar estimates select and copy the ROI once (``PointBlocks.memo``), with the lights of the
    row-by-row path bit for bit; another scene object with the same centre selects its own."""
    import usd_gs.relight.light_estimation as le
    from usd_gs.gaussians import GaussianSet as GS
    from usd_gs.point_blocks import PointBlocks, block_starts

    g, c = scene_deg0.gaussians, scene_deg0.centroid
    far = GaussianSet.concatenate([g, g, g])
    far.positions[:] += np.float32([40.0, 0.0, 0.0])
    both = GaussianSet.concatenate([far, g])
    blocks = PointBlocks(block_starts([(0, far.count), (far.count, both.count)]))
    copies = []
    subset = GS.subset
    monkeypatch.setattr(GS, "subset", lambda self, index: copies.append(self.count) or subset(self, index))
    lights = estimate_lights(both, c, k=3, values_checked=True, blocks=blocks)
    rects = le.estimate_rect_lights(both, c, values_checked=True, blocks=blocks)
    assert copies == [both.count]  # one ROI copy for the two estimates
    plain = estimate_lights(both, c, k=3, values_checked=True)
    plain_rects = le.estimate_rect_lights(both, c, values_checked=True)
    assert len(copies) == 3  # (without blocks: one each)
    assert [(a.index, a.position.tolist(), a.color.tolist(), a.intensity, a.score) for a in lights] == \
        [(a.index, a.position.tolist(), a.color.tolist(), a.intensity, a.score) for a in plain]
    assert len(lights) == 3 and lights[0].index >= far.count
    assert repr(rects) == repr(plain_rects)
    other = replace(both, positions=both.positions.copy())
    estimate_lights(other, c, k=3, values_checked=True, blocks=blocks)
    assert len(copies) == 4  # (another owner: its own ROI, not the first scene's)
    estimate_lights(both, c + np.array([0.5, 0.0, 0.0]), k=3, values_checked=True, blocks=blocks)
    estimate_lights(both, c, k=3, values_checked=True, blocks=blocks)
    assert len(copies) == 6  # (only the last region is kept: a per-frame estimate keeps one copy)


def test_alpha_weighted_centroid():
    g = _random_set(50, 0, seed=9)
    a = g.opacities.astype(np.float64)
    np.testing.assert_allclose(alpha_weighted_centroid(g), (a[:, None] * g.positions).sum(0) / a.sum(), rtol=1e-12)


def test_ring_viewpoints_use_up_axis():
    vz = make_viewpoints([1.0, 2.0, 3.0], LightEstimationConfig(view_layout="ring", num_views=4, up_axis="Z"))
    np.testing.assert_allclose(vz[:, 2], 3.0)
    np.testing.assert_allclose(np.linalg.norm(vz[:, :2] - [1.0, 2.0], axis=1), 0.5)
    vy = make_viewpoints([1.0, 2.0, 3.0], LightEstimationConfig(view_layout="ring", num_views=4, up_axis="Y"))
    np.testing.assert_allclose(vy[:, 1], 2.0)


@pytest.mark.parametrize("name", ["biker.ply", "guitar.ply"])
def test_real_captures_run(name):
    path = DATA / "splats" / name
    g = read_capture(path)
    c = alpha_weighted_centroid(g)
    lights = estimate_lights(g, c, k=2)
    assert len(lights) == 2
    for light in lights:
        assert np.all(np.isfinite(light.position)) and np.all(np.isfinite(light.color))
        assert np.isfinite(light.intensity) and light.intensity > 0 and light.score > 0
        assert np.all(light.color >= 0)
        assert np.linalg.norm(light.position - c) <= 6.0 + 1e-6
    assert np.linalg.norm(lights[0].position - lights[1].position) >= 1.0 - 0.2  # refined positions
