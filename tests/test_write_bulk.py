"""usd_gs.usd.bulk: the fast write-path helpers return exactly what the plain calls return."""

import numpy as np
import pytest
from pxr import Vt

from usd_gs.errors import GaussianDataError
from usd_gs.extent import gaussian_extent
from usd_gs.gaussians import GaussianSet
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.bulk import vt_from_numpy


def _same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.mark.parametrize("seed", range(6))
def test_extent_equals_the_float64_extent_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    g = random_gaussians(20_000 + 997 * seed, 0, seed=seed)
    # unnormalised quaternions, a spread of scales and far-away centres
    g.orientations *= rng.uniform(0.05, 20.0, (g.count, 1)).astype(np.float32)
    g.scales *= np.exp(rng.normal(0.0, 2.0, g.scales.shape)).astype(np.float32)
    g.positions += rng.normal(0.0, 1e3 * seed, g.positions.shape).astype(np.float32)
    assert _same_bits(gaussian_extent(g, 3.0), g.extent(3.0))
    assert _same_bits(gaussian_extent(g, 1.0), g.extent(1.0))


@pytest.mark.parametrize("case", ["one centre", "one centre, isotropic"])
def test_extent_when_the_scale_bounds_do_not_narrow_it(case):
    # every Gaussian at the same centre: the min/max-scale bound keeps them all, so the rotated
    # float32 boxes decide (anisotropic), or nothing narrows it and the float64 pass runs on all
    g = random_gaussians(30_000, 0, seed=4)
    g.positions[:] = np.float32([1.5, -2.0, 0.25])
    if "isotropic" in case:
        g.scales[:] = np.float32(0.01)
    assert _same_bits(gaussian_extent(g), g.extent(3.0))


def test_extent_falls_back_on_zero_quaternions_and_names_an_overflow():
    g = random_gaussians(10_000, 0, seed=1)
    g.orientations[123] = 0.0  # identity by the GaussianSet convention
    assert _same_bits(gaussian_extent(g), g.extent(3.0))
    g.scales[4321] = 3e38
    with pytest.raises(GaussianDataError, match="element 4321"):
        gaussian_extent(g)


def test_extent_of_a_small_set_and_an_empty_one():
    g = random_gaussians(100, 0, seed=2)
    assert _same_bits(gaussian_extent(g), g.extent(3.0))
    empty = GaussianSet(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 1, 3)))
    assert np.array_equal(gaussian_extent(empty), np.zeros((2, 3), np.float32))


@pytest.mark.parametrize("cuts", [(0, 7_000, 7_001, 30_000), (0, 30_000), (0, 100, 4_000, 17_000, 30_000)])
def test_extent_of_parts_is_the_whole_sets_bit_for_bit(cuts):
    import threading

    from usd_gs.extent import ExtentOfParts

    rng = np.random.default_rng(len(cuts))
    g = random_gaussians(30_000, 1, seed=len(cuts))
    g.scales *= np.exp(rng.normal(0.0, 1.5, g.scales.shape)).astype(np.float32)
    g.positions += rng.normal(0.0, 50.0, g.positions.shape).astype(np.float32)
    parts = ExtentOfParts(3.0)
    spans = list(zip(cuts[:-1], cuts[1:], strict=True))[::-1]  # added last part first, from threads
    threads = [threading.Thread(target=parts.add, args=(g.subset(np.arange(a, b)),)) for a, b in spans]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert _same_bits(parts.box(g.count), g.extent(3.0))
    assert parts.box(g.count + 1) is None  # rows missing: no box


def test_extent_of_parts_leaves_an_overflow_to_the_whole_set():
    from usd_gs.extent import ExtentOfParts

    g = random_gaussians(10_000, 0, seed=5)
    g.scales[77] = 3e38
    parts = ExtentOfParts(3.0)
    parts.add(g.subset(np.arange(0, 5_000)))
    parts.add(g.subset(np.arange(5_000, 10_000)))
    assert parts.box(g.count) is None
    with pytest.raises(GaussianDataError, match="element 77"):
        gaussian_extent(g)


@pytest.mark.parametrize("cls,dtype,shape", [
    (Vt.Vec3fArray, np.float32, (3,)), (Vt.FloatArray, np.float32, ()), (Vt.QuatfArray, np.float32, (4,)),
    (Vt.Vec3hArray, np.float16, (3,)), (Vt.HalfArray, np.float16, ()), (Vt.QuathArray, np.float16, (4,)),
    (Vt.IntArray, np.int32, ()), (Vt.DoubleArray, np.float64, ()),
])
@pytest.mark.parametrize("n", [5, 100_000])
def test_vt_from_numpy_equals_from_numpy(cls, dtype, shape, n):
    arr = np.random.default_rng(n).normal(0.0, 100.0, (n, *shape)).astype(dtype)
    fast = vt_from_numpy(cls, arr)
    assert type(fast) is cls and len(fast) == n
    assert fast == cls.FromNumpy(arr)
    assert np.array_equal(np.asarray(fast), arr)
    arr[0] = 7  # the Vt array owns its copy
    assert np.asarray(fast).reshape(n, -1)[0, 0] != 7 or n == 0


def test_vt_from_numpy_of_a_strided_array():
    base = np.arange(400_000, dtype=np.float32).reshape(-1, 4)
    arr = base[:, :3]
    assert vt_from_numpy(Vt.Vec3fArray, arr) == Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(arr))


@pytest.mark.parametrize("shape,cls", [((70_000, 3), Vt.Vec3fArray), ((70_000,), Vt.FloatArray),
                                       ((30_000, 16, 3), Vt.Vec3fArray)])
def test_vt_backed_arrays_are_written_without_a_copy(shape, cls):
    from usd_gs.usd.bulk import vt_backed_empty

    a = vt_backed_empty(shape)
    assert a.shape == shape and a.dtype == np.float32 and a.flags.writeable and not a.any()
    a[...] = np.random.default_rng(0).normal(size=shape)
    flat = a.reshape(-1, 3) if len(shape) > 1 else a
    vt = vt_from_numpy(cls, flat)
    assert np.asarray(vt).__array_interface__["data"][0] == a.__array_interface__["data"][0]
    assert vt == cls.FromNumpy(np.array(flat))
    # a part of it, another class or another dtype is copied as usual
    part = flat[1:]
    assert np.asarray(vt_from_numpy(cls, part)).__array_interface__["data"][0] != part.__array_interface__["data"][0]
    assert vt_from_numpy(cls, part) == cls.FromNumpy(np.array(part))
    other = Vt.FloatArray if cls is Vt.Vec3fArray else Vt.Vec3fArray
    if other is Vt.FloatArray:
        assert vt_from_numpy(other, flat.reshape(-1)) == Vt.FloatArray.FromNumpy(np.array(flat.reshape(-1)))


def test_vt_backed_empty_of_other_shapes_is_plain_numpy():
    from usd_gs.usd.bulk import vt_backed_empty

    for shape, dtype in (((10, 4), np.float32), ((10, 3), np.float64), ((0, 3), np.float32)):
        a = vt_backed_empty(shape, dtype)
        assert a.shape == shape and a.dtype == dtype and not a.any()


def test_sog_decoded_into_vt_storage_is_the_same_set(tmp_path):
    from usd_gs.io.sog import read_sog, write_sog
    from usd_gs.usd.bulk import vt_backed_empty

    g = random_gaussians(20_000, 0, seed=3)
    write_sog(tmp_path / "a.sog", g)
    plain, backed = read_sog(tmp_path / "a.sog"), read_sog(tmp_path / "a.sog", empty=vt_backed_empty)
    for name in ("positions", "orientations", "scales", "log_scales", "opacities", "sh"):
        x, y = getattr(plain, name), getattr(backed, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert vt_from_numpy(Vt.Vec3fArray, backed.positions) == Vt.Vec3fArray.FromNumpy(plain.positions)


def test_vt_writable_view_is_the_vt_arrays_value():
    from usd_gs.usd.bulk import vt_writable

    vt, view = vt_writable(Vt.QuatfArray, 70_000, np.float32)
    assert view.shape == (70_000, 4) and not view.any()
    view[:] = np.arange(280_000, dtype=np.float32).reshape(70_000, 4)
    q = vt[69_999]
    assert (q.imaginary[0], q.imaginary[1], q.imaginary[2], q.real) == (279_996.0, 279_997.0, 279_998.0, 279_999.0)
    assert vt_from_numpy(Vt.QuatfArray, view) is vt  # handed over without a copy
    assert vt_writable(Vt.QuatfArray, 10, np.float64) is None  # wrong scalar: the caller falls back
    assert vt_writable(Vt.Vec3fArray, 0, np.float32) is None


@pytest.mark.parametrize("bad, finite", [
    (None, True),
    ((5, 1, np.float32(3e38)), True),  # finite values whose sum overflows: decided element by element
    ((7, 2, np.nan), False), ((9, 0, np.inf), False), ((11, 1, -np.inf), False),
])
def test_all_finite_without_a_temporary(bad, finite):
    from usd_gs.usd.gaussian_layer import all_finite

    a = np.random.default_rng(1).normal(size=(50_000, 3)).astype(np.float32)
    if bad is not None:
        a[bad[0], bad[1]] = bad[2]
        if np.isfinite(bad[2]):
            a[bad[0] + 1] = bad[2]  # several huge values: the float32 sum overflows
    assert all_finite(a) is finite and finite == bool(np.isfinite(a).all())
    both = a.copy()
    both[0, 0], both[1, 0] = np.inf, -np.inf  # inf + -inf: a NaN sum
    assert not all_finite(both)
