"""pack_gaussians into caller buffers (the main job's per-frame reuse for moving casters): the
values of a fresh packing, written into the given arrays; buffers of the wrong shape or dtype
are not used."""

import numpy as np
from dgsm_testutil import random_occluders

from numba_kernels.dgsm_model import pack_gaussians


def test_packing_into_buffers_equals_a_fresh_packing():
    rng = np.random.default_rng(3)
    mu, q, s, a, *_ = random_occluders(rng, 500, centre=(0.0, 0.0, 0.0), spread=0.5, log_s=(-4.0, -2.0),
                                       alpha=(0.05, 0.99))
    occ, dep, cov6 = pack_gaussians(mu, q, s, a, 0.5)
    buf = (np.full((500, 16), np.nan), np.full((500, 6), np.nan))
    occ2, dep2, cov2 = pack_gaussians(mu, q, s, a, 0.5, out=buf)
    assert occ2 is buf[0] and cov2 is buf[1] and dep2 == dep
    np.testing.assert_array_equal(occ2, occ)
    np.testing.assert_array_equal(cov2, cov6)
    # a second caster state into the same buffers: its own values, nothing of the first left
    occ3, _, cov3 = pack_gaussians(mu + 1.0, q, s * 2.0, a, 0.5, out=buf)
    fresh, _, fresh_cov = pack_gaussians(mu + 1.0, q, s * 2.0, a, 0.5)
    np.testing.assert_array_equal(occ3, fresh)
    np.testing.assert_array_equal(cov3, fresh_cov)
    for wrong in ((np.empty((499, 16)), np.empty((499, 6))), (np.empty((500, 16), np.float32), np.empty((500, 6)))):
        occ4, _, _ = pack_gaussians(mu, q, s, a, 0.5, out=wrong)
        assert occ4 is not wrong[0]
        np.testing.assert_array_equal(occ4, occ)
