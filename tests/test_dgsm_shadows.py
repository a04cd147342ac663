"""usd_gs.shadows.dgsm wrapper: ROI selection, end-to-end accuracy, directional, errors."""

import numpy as np
import pytest

from usd_gs.errors import GaussianDataError, UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import (
    DGSMConfig,
    build_dgsm,
    exact_transmittance,
    exact_transmittance_directional,
    roi_indices,
    sample_dgsm,
    shadow_transmittance,
)


def _avatar(rng, n=150):
    pos = np.stack([rng.normal(0, 0.1, n), rng.uniform(0.1, 1.7, n), rng.normal(0, 0.1, n)], 1)
    q = rng.normal(size=(n, 4))
    return GaussianSet(pos, q / np.linalg.norm(q, axis=1, keepdims=True), np.exp(rng.uniform(-3.5, -2.5, (n, 3))),
                       rng.uniform(0.3, 0.95, n), np.zeros((n, 1, 3)), label="avatar")


def _floor(rng, n=4000, half=3.0):
    pos = np.stack([rng.uniform(-half, half, n), np.zeros(n), rng.uniform(-half, half, n)], 1)
    q = np.tile([np.sqrt(0.5), -np.sqrt(0.5), 0, 0], (n, 1))
    s = np.tile([0.02, 0.02, 0.002], (n, 1))
    return GaussianSet(pos, q, s, np.full(n, 0.9), np.zeros((n, 1, 3)), label="floor")


def test_roi_box_y_and_z_up():
    rng = np.random.default_rng(0)
    av = _avatar(rng)
    fl = _floor(rng)
    cfg = DGSMConfig(roi_radius=1.0)
    idx = roi_indices(av, fl.positions, cfg)
    p = fl.positions
    c = (av.opacities.astype(float) @ av.positions) / av.opacities.sum()
    expect = np.flatnonzero((np.abs(p[:, 0] - c[0]) <= 1) & (np.abs(p[:, 2] - c[2]) <= 1))
    np.testing.assert_array_equal(idx, expect)
    # Z-up: swap axes of both sets; the same receivers are selected
    swap = [0, 2, 1]
    av_z = GaussianSet(av.positions[:, swap], av.orientations, av.scales, av.opacities, av.sh)
    idx_z = roi_indices(av_z, fl.positions[:, swap], DGSMConfig(roi_radius=1.0, up_axis="Z"))
    np.testing.assert_array_equal(idx_z, expect)
    # receivers far above the avatar's robust height range are excluded
    high = fl.positions.copy()
    high[:, 1] = 5.0
    assert len(roi_indices(av, high, cfg)) == 0
    assert len(roi_indices(av, fl.positions, DGSMConfig(use_roi=False))) == fl.count


@pytest.mark.parametrize("sampling,n", [("center", 1), ("stencil7", 7), ("mc", 8)])
def test_end_to_end_matches_exact_at_same_points(sampling, n):
    rng = np.random.default_rng(1)
    av, fl = _avatar(rng), _floor(rng)
    light = np.array([1.0, 2.5, 0.0])
    cfg = DGSMConfig(atlas_size=256, K=64, sampling=sampling, n_samples=n, seed=3)
    d = build_dgsm(av, fl, light, cfg)
    got = sample_dgsm(d)
    ex = exact_transmittance(av, d.points, light).reshape(len(d.roi), -1) @ d.weights
    assert (ex < 0.9).mean() > 0.01
    err = np.abs(got - ex)
    assert err.mean() < 0.01 and err.max() < 0.1
    full = shadow_transmittance(av, fl, light, cfg)
    np.testing.assert_allclose(full[d.roi], got)
    outside = np.setdiff1d(np.arange(fl.count), d.roi)
    assert np.all(full[outside] == 1.0)


def test_mc_is_deterministic_for_a_seed():
    rng = np.random.default_rng(2)
    av, fl = _avatar(rng), _floor(rng)
    light = np.array([1.0, 2.5, 0.0])
    a = shadow_transmittance(av, fl, light, DGSMConfig(atlas_size=64, K=16, sampling="mc", seed=5))
    b = shadow_transmittance(av, fl, light, DGSMConfig(atlas_size=64, K=16, sampling="mc", seed=5))
    c = shadow_transmittance(av, fl, light, DGSMConfig(atlas_size=64, K=16, sampling="mc", seed=6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_directional_end_to_end():
    rng = np.random.default_rng(3)
    av, fl = _avatar(rng), _floor(rng)
    ldir = np.array([-0.4, -1.0, 0.1])
    cfg = DGSMConfig(atlas_size=256, K=32, sampling="center")
    t = shadow_transmittance(av, fl, None, cfg, direction=ldir)
    ex = exact_transmittance_directional(av, fl.positions, ldir)
    idx = roi_indices(av, fl.positions, cfg)
    err = np.abs(t[idx] - ex[idx])
    assert (ex[idx] < 0.9).mean() > 0.01
    assert err.mean() < 0.01 and err.max() < 0.1


def test_errors_name_set_field_and_element():
    rng = np.random.default_rng(4)
    av, fl = _avatar(rng, 10), _floor(rng, 50)
    light = np.array([1.0, 2.5, 0.0])
    bad = GaussianSet(av.positions, av.orientations, av.scales.copy(), av.opacities, av.sh, label="avatar")
    bad.scales[7, 1] = np.nan
    with pytest.raises(GaussianDataError, match="avatar: 'scales' element 7"):
        build_dgsm(bad, fl, light)
    bad_fl = GaussianSet(fl.positions.copy(), fl.orientations, fl.scales, fl.opacities, fl.sh, label="floor")
    bad_fl.positions[33, 2] = np.inf
    with pytest.raises(GaussianDataError, match="floor: 'positions' element 33"):
        build_dgsm(av, bad_fl, light)
    with pytest.raises(GaussianDataError, match="light position"):
        build_dgsm(av, fl, [0, np.nan, 0])
    with pytest.raises(UserError, match="up_axis"):
        build_dgsm(av, fl, light, DGSMConfig(up_axis="X"))
    with pytest.raises(UserError, match="exactly one"):
        shadow_transmittance(av, fl, light, direction=[0, -1, 0])
