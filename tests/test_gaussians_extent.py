"""GaussianSet.extent (its numba kernel, numba_kernels.extent, and its numpy path),
GaussianSet.subset and unit_quaternions against the row-by-row numpy implementation: the same
float32 boxes bit for bit (the output stage's extents and the shadow culling depend on them), the
same error for a box that does not fit in float32."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import numba_kernels.extent as extent_kernels
from numba_kernels.extent import gaussian_extent
from usd_gs.errors import GaussianDataError, first_bad_index
from usd_gs.gaussians import GaussianSet


def _unit_quaternions_reference(g: GaussianSet) -> np.ndarray:
    q = g.orientations.astype(np.float64)
    n = np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))


def _extent_reference(g: GaussianSet, n_sigma: float = 3.0) -> np.ndarray:
    """The implementation before the blocked one (kept verbatim as the reference)."""
    if g.count == 0:
        return np.zeros((2, 3), np.float32)
    w, x, y, z = _unit_quaternions_reference(g).T
    s2 = g.scales.astype(np.float64) ** 2
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    p = g.positions
    lo, hi = np.empty(3), np.empty(3)
    big = float(np.finfo(np.float32).max)
    for i, (a, b, c) in enumerate(rows):
        half = n_sigma * np.sqrt(a * a * s2[:, 0] + b * b * s2[:, 1] + c * c * s2[:, 2])
        lo_i, hi_i = p[:, i] - half, p[:, i] + half
        bad = ~(np.abs(lo_i) <= big) | ~(np.abs(hi_i) <= big)
        if bad.any():
            j = first_bad_index(bad)
            raise GaussianDataError(
                f"{g.label}: the {n_sigma:g}-sigma extent of element {j} (scales {g.scales[j].tolist()}) "
                f"is not finite in float32 ({int(bad.sum())} such elements); the scales are too large")
        lo[i] = np.min(lo_i)
        hi[i] = np.max(hi_i)
    return np.stack([lo, hi]).astype(np.float32)


def _random_set(rng, n: int) -> GaussianSet:
    q = rng.normal(size=(n, 4)) * rng.choice([1e-3, 1.0, 40.0], size=(n, 1))  # not unit
    q[rng.random(n) < 0.05] = 0.0  # zero quaternions count as identity
    q[rng.random(n) < 0.05] = [1.0, 0.0, 0.0, 0.0]
    scales = np.exp(rng.uniform(-9, 3, size=(n, 3)))
    pos = rng.normal(scale=rng.choice([0.1, 1e3]), size=(n, 3))
    return GaussianSet(pos, q, scales, rng.random(n), np.zeros((n, 1, 3)), label="/R")


@pytest.mark.parametrize("n", [1, 2, 7, 300, 5000])
@pytest.mark.parametrize("n_sigma", [3.0, 1.7, 0.0])
def test_extent_equals_the_reference_bit_for_bit(n, n_sigma):
    assert "numba" in sys.modules  # GaussianSet.extent takes the kernel
    rng = np.random.default_rng(n)
    for _ in range(3):
        g = _random_set(rng, n)
        want = _extent_reference(g, n_sigma)
        assert g.extent(n_sigma).tobytes() == want.tobytes()
        ro = g.positions.copy()
        ro.flags.writeable = False  # read-only views of USD memory: the same kernel
        box = gaussian_extent(ro, g.orientations, g.scales, n_sigma)
        assert box.astype(np.float32).tobytes() == want.tobytes()
        np.testing.assert_array_equal(g.unit_quaternions(), _unit_quaternions_reference(g))
    assert len(extent_kernels._extent_kernel.signatures) == 1


def test_numpy_path_without_numba_equals_the_reference(monkeypatch):
    g = _random_set(np.random.default_rng(5), 100)
    monkeypatch.delitem(sys.modules, "numba")
    assert g.extent(3.0).tobytes() == _extent_reference(g, 3.0).tobytes()
    assert GaussianSet.empty().extent().tobytes() == _extent_reference(GaussianSet.empty()).tobytes()


@pytest.mark.parametrize("numba_loaded", [True, False])
def test_extent_error_names_the_same_element_as_the_reference(monkeypatch, numba_loaded):
    if not numba_loaded:
        monkeypatch.delitem(sys.modules, "numba")
    g = _random_set(np.random.default_rng(9), 60)
    g.scales[[40, 52], 2] = 3e38  # beyond float32 once tripled; the reference checks axis 1 before axis 2
    g.scales[20, 1] = 2e38
    g.orientations[[20, 40, 52]] = [1.0, 0.0, 0.0, 0.0]
    with pytest.raises(GaussianDataError) as want:
        _extent_reference(g)
    with pytest.raises(GaussianDataError) as got:
        g.extent()
    assert str(got.value) == str(want.value) and "element 20 " in str(got.value)
    g.positions[3, 0] = np.nan  # not finite: no box
    assert gaussian_extent(g.positions, g.orientations, g.scales, 3.0) is None


@pytest.mark.parametrize("index", [slice(2, 9), slice(1, 20, 3), np.array([4, 0, 4, 19]),
                                   np.arange(20) % 3 == 0, np.array([], np.int64), np.array([7], np.uint32)])
def test_subset_fast_path_equals_the_checked_construction(index):
    rng = np.random.default_rng(2)
    g = _random_set(rng, 20)
    g = GaussianSet(g.positions, g.orientations, g.scales, g.opacities, rng.normal(size=(20, 4, 3)),
                    rng.normal(size=(20, 3)), rng.normal(size=20), {"nx": rng.normal(size=20).astype(np.float16),
                                                                    "i": np.arange(20)}, label="/S")
    got = g.subset(index)
    want = GaussianSet(g.positions[index], g.orientations[index], g.scales[index], g.opacities[index], g.sh[index],
                       g.log_scales[index], g.logit_opacities[index], {k: v[index] for k, v in g.extras.items()},
                       label="/S")
    for name in ("positions", "orientations", "scales", "opacities", "sh", "log_scales", "logit_opacities"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype == np.float32 and a.flags.c_contiguous and a.tobytes() == b.tobytes(), name
    assert got.extras.keys() == want.extras.keys() and got.label == "/S"
    for k in want.extras:
        assert got.extras[k].dtype == want.extras[k].dtype and got.extras[k].flags.c_contiguous
        np.testing.assert_array_equal(got.extras[k], want.extras[k])


def test_block_extents_equal_the_extent_of_each_block():
    """numba_kernels.extent.block_extents (the prims of a receiver set in threads, used for the
    prim spheres of the shadow culling): each block's box the same bits as gaussian_extent on its
    rows; an empty block and a block with a non-finite box flagged not ok."""
    from numba_kernels.extent import block_extents

    rng = np.random.default_rng(3)
    n = 40_000
    pos = rng.normal(0, 5, (n, 3)).astype(np.float32)
    quat = rng.normal(size=(n, 4)).astype(np.float32)
    quat[7] = 0.0  # a zero quaternion counts as the identity
    scales = rng.lognormal(-3, 1, (n, 3)).astype(np.float32)
    scales[30_001] = 2e38  # its 3-sigma box overflows float32
    starts = np.array([0, 9, 9, 12_345, 30_000, 30_002, n], np.int64)
    boxes, ok = block_extents(pos, quat, scales, starts, 3.0)
    assert ok.tolist() == [True, False, True, True, False, True]
    for b in np.flatnonzero(ok):
        a, e = starts[b], starts[b + 1]
        assert np.array_equal(boxes[b], gaussian_extent(pos[a:e], quat[a:e], scales[a:e], 3.0))
    assert gaussian_extent(pos[30_000:30_002], quat[30_000:30_002], scales[30_000:30_002], 3.0) is None
