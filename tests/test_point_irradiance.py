"""numba_kernels.point_irradiance against its numpy reference and hand-checked values, and the
point form of usd_gs.relight.direct.direct_irradiance that uses it."""

import numpy as np
import pytest

from numba_kernels.point_irradiance import point_irradiance
from numba_kernels.reference.point_irradiance import point_irradiance as reference
from usd_gs.relight.direct import direct_irradiance
from usd_gs.usd.lux import ShotLight

RNG = np.random.default_rng(5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_kernel_equals_the_reference(dtype):
    x = RNG.uniform(-3, 3, (40_000, 3)).astype(dtype)
    n = RNG.normal(size=(40_000, 3))
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(dtype)
    lp, inten = np.array([0.3, 2.4, -1.0]), np.array([5.0, 4.0, 3.0])
    x[11] = lp  # at the light: r2 clamped to 1e-12, cos 0
    got = point_irradiance(x, n, lp, inten)
    # (to rounding: numpy's einsum may add the three products in another order)
    np.testing.assert_allclose(got, reference(x, n, lp, inten), rtol=1e-12, atol=1e-300)
    assert np.all(np.isfinite(got)) and np.all(got >= 0) and 0.3 < np.mean(got[:, 0] > 0) < 0.7
    np.testing.assert_array_equal(got[11], 0.0)


def test_hand_values_and_the_relighting_entry_point():
    # 2 m below the light, facing it: I / 4; tilted 60 degrees: I / 8; facing away: 0
    x = np.zeros((3, 3), np.float32)
    n = np.array([[0.0, 1.0, 0.0], [np.sin(np.pi / 3), 0.5, 0.0], [0.0, -1.0, 0.0]])
    light = ShotLight("l", "point", np.array([0.0, 2.0, 0.0]), color=np.array([1.0, 1.0, 1.0]), intensity=8.0)
    e = direct_irradiance(light, x, n)
    i = np.asarray(light.radiant_intensity(), np.float64)
    np.testing.assert_allclose(e, [i / 4, i / 8, 0 * i], rtol=1e-12, atol=1e-15)
    # broadcast normals (a stride-0 view) give the same values as the full array
    np.testing.assert_array_equal(direct_irradiance(light, x, np.broadcast_to(n[0], (3, 3))), np.tile(e[0], (3, 1)))
    with pytest.raises(ValueError, match="normals"):
        point_irradiance(x, n[:2], light.position, i)
