"""The parallax reprojection kernel (numba_kernels.probe_reprojection) against its numpy
reference, on a real cube render's texels: probe points at the centre, inside the avatar's
range, next to a patch (the 1e-9 guard), with and without the occlusion test."""

import numpy as np
import pytest

from numba_kernels.probe_reprojection import reproject_probes
from numba_kernels.reference.probe_reprojection import reproject_probes as reference
from usd_gs.gaussians import GaussianSet
from usd_gs.relight import parallax
from usd_gs.relight.probe import render_probe_faces


def _texels():
    rng = np.random.default_rng(7)
    n = 4000  # a room-like shell of Gaussians around the origin plus a prop
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.concatenate([d * rng.uniform(2.0, 3.0, (n, 1)), rng.normal([0.6, 0.0, 0.3], 0.1, (300, 3))])
    m = len(pos)
    q = rng.normal(size=(m, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    g = GaussianSet(pos, q, rng.uniform(0.05, 0.2, (m, 3)), rng.uniform(0.3, 0.99, m),
                    rng.uniform(0.0, 1.0, (m, 4, 3)) * np.array([1.0, 0.2, 0.2, 0.2])[None, :, None])
    c = np.zeros(3)
    rgb, alpha, depth = render_probe_faces(g, c, 16)
    return parallax.cube_texels(rgb, alpha, depth, c)


@pytest.mark.parametrize("occlusion", [16, 0])
def test_kernel_equals_reference(occlusion):
    tex = _texels()
    live = tex.weight > 0
    args = (tex.points[live], tex.normals[live], tex.dirs[live], tex.dist[live], tex.weight[live], tex.cos_c[live],
            tex.radiance[live])
    patch = tex.points[live][17]
    pts = np.array([[0.0, 0.0, 0.0], [0.4, -0.3, 0.2], [-0.5, 0.6, 0.1], patch, patch + 1e-12])
    consts = (parallax._MIN_COS, parallax._MAX_RATIO, parallax._DISC, parallax._MIN_SPLAT_COS, parallax._SAME_LAYER)
    got = reproject_probes(pts, *args, 4, occlusion, *consts)
    want = reference(pts, *args, 4, occlusion, *consts)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
    if occlusion:  # the test hides something away from the centre, nothing at it
        plain = reference(pts, *args, 4, 0, *consts)
        np.testing.assert_allclose(got[0], plain[0], rtol=1e-12, atol=1e-15)
        assert np.abs(got[1:3] - plain[1:3]).max() > 1e-3 * np.abs(plain).max()
