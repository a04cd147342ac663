"""numba_kernels.similarity (GaussianSet.transformed's pass over positions, orientations and scales)
against its numpy reference: orientations and scales bit for bit, positions to the last bit of
float32 but where numpy's matrix product rounds its float64 dot product another way; zero and
unnormalised quaternions, reflections, uniform scales, large offsets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from numba_kernels.reference import similarity as ref
from numba_kernels.similarity import similarity_transform
from usd_gs.gaussians import GaussianSet, matrix_to_quaternion


def _inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    pos = (rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 50.0, 1e4], size=(n, 1))).astype(np.float32)
    quat = (rng.normal(size=(n, 4)) * rng.choice([1e-20, 1e-3, 1.0, 1e3], size=(n, 1))).astype(np.float32)
    quat[::97] = 0.0  # zero quaternions: the identity
    scales = np.exp(rng.uniform(-12.0, 3.0, (n, 3))).astype(np.float32)
    return pos, quat, scales


@pytest.mark.parametrize("reflect", [False, True])
@pytest.mark.parametrize("n", [1, 7, 50_000])
def test_similarity_transform_equals_the_numpy_formulas(n, reflect):
    pos, quat, scales = _inputs(n, seed=n + int(reflect))
    q = Rotation.from_euler("xyz", [25.0, -140.0, 73.0], degrees=True).as_matrix()
    if reflect:
        q = q @ np.diag([-1.0, 1.0, 1.0])
    s, t = 2.75, np.array([1e3, -2.5, 0.125])
    proper = q @ np.diag([-1.0, 1.0, 1.0]) if reflect else q
    rq = matrix_to_quaternion(proper[None])[0]
    got = similarity_transform(pos, quat, scales, s * q, t, s, rq, reflect)
    want = ref.similarity_transform(pos, quat, scales, s * q, t, s, rq, reflect)
    assert all(a.dtype == np.float32 and a.shape == b.shape for a, b in zip(got, want, strict=True))
    assert np.array_equal(got[1].view(np.uint32), want[1].view(np.uint32))  # orientations
    assert np.array_equal(got[2].view(np.uint32), want[2].view(np.uint32))  # scales
    ulp = np.spacing(np.abs(want[0]))
    assert np.all(np.abs(got[0] - want[0]) <= ulp)  # positions: at most one float32 ulp
    assert np.mean(got[0] != want[0]) < 1e-3
    assert np.all(np.isfinite(got[0])) and np.all(np.isfinite(got[1]))
    zero = np.flatnonzero(~quat.any(axis=1))
    np.testing.assert_allclose(got[1][zero], np.broadcast_to(rq, (zero.size, 4)), atol=1e-7)  # identity turned by rq


def test_transformed_sets_keep_their_shape_and_norms():
    """GaussianSet.transformed through the kernel: unit quaternions, scales times s, the same
    covariances as rotating the old ones (s^2 Q C Q^T)."""
    rng = np.random.default_rng(3)
    n = 2000
    g = GaussianSet(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                    np.exp(rng.uniform(-5, -1, (n, 3))).astype(np.float32), rng.uniform(0.1, 1, n).astype(np.float32),
                    np.zeros((n, 1, 3), np.float32), label="/W/P")
    q = Rotation.from_euler("zyx", [10.0, 20.0, -30.0], degrees=True).as_matrix() @ np.diag([1.0, 1.0, -1.0])
    m = np.eye(4)
    m[:3, :3] = (1.5 * q).T
    m[3, :3] = [0.5, -1.0, 2.0]
    out = g.transformed(m)
    np.testing.assert_allclose(np.linalg.norm(out.orientations.astype(np.float64), axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(out.scales, 1.5 * g.scales.astype(np.float64), rtol=2e-7)  # (s = |det|^(1/3))
    np.testing.assert_allclose(out.covariances(), 2.25 * np.einsum("ij,njk,lk->nil", q, g.covariances(), q),
                               rtol=2e-5, atol=1e-8)
