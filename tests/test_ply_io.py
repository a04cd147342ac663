"""PLY reader/writer: real captures round trip bit-exactly, field mapping, every error path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile
import pytest

from usd_gs.errors import GaussianDataError, InputFormatError
from usd_gs.gaussians import GaussianSet
from usd_gs.io.ply import OPACITY_EPS, read_ply, write_ply
from usd_gs.synthetic import random_gaussians

SPLATS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "splats"
INRIA_ORDER_HEAD = ["x", "y", "z"]
INRIA_ORDER_TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def _norm_rot(data) -> np.ndarray:
    q = np.stack([data[f"rot_{i}"] for i in range(4)], axis=1).astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _inria_fields(n_rest: int, extras=()) -> list[str]:
    return (INRIA_ORDER_HEAD + list(extras) + ["f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(n_rest)] + INRIA_ORDER_TAIL)


def _write_raw(path: Path, columns: dict, text: bool = False, byte_order: str = "<", dtypes=None,
               element: str = "vertex") -> Path:
    """Write a PLY with plyfile directly (independent of the code under test)."""
    n = len(next(iter(columns.values())))
    dtypes = dtypes or {}
    arr = np.empty(n, dtype=[(k, dtypes.get(k, "f4")) for k in columns])
    for k, v in columns.items():
        arr[k] = v
    plyfile.PlyData([plyfile.PlyElement.describe(arr, element)], text=text, byte_order=byte_order).write(str(path))
    return path


def _columns(n: int, n_rest: int, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    cols = {k: rng.normal(size=n).astype(np.float32) for k in _inria_fields(n_rest)}
    for k in ("scale_0", "scale_1", "scale_2"):
        cols[k] = cols[k] - 4.0
    return cols


# ---------------------------------------------------------------------------------- real data
@pytest.mark.parametrize("name,count", [("biker.ply", 152746), ("guitar.ply", 90854)])
def test_real_capture_round_trip_is_bit_exact(tmp_path, name, count):
    src = SPLATS / name
    g = read_ply(src)
    assert g.count == count and g.sh_degree == 0 and g.label == str(src)
    out = tmp_path / name
    write_ply(out, g)
    a = plyfile.PlyData.read(str(src))["vertex"].data
    b = plyfile.PlyData.read(str(out))["vertex"].data
    # written in INRIA order whatever the source order (biker.ply has x,y,z,rot,scale,opacity,f_dc)
    assert list(b.dtype.names) == _inria_fields(0)
    for field in a.dtype.names:
        if field.startswith("rot_"):
            continue
        assert np.array_equal(_bits(a[field]), _bits(b[field])), field
    np.testing.assert_allclose(_norm_rot(b), _norm_rot(a), rtol=0, atol=2.5e-7)
    # and a second pass is the identity, rot included
    write_ply(tmp_path / "again.ply", read_ply(out))
    assert (tmp_path / "again.ply").read_bytes() == out.read_bytes()


def test_biker_values_follow_the_3dgs_activations():
    g = read_ply(SPLATS / "biker.ply")
    raw = plyfile.PlyData.read(str(SPLATS / "biker.ply"))["vertex"].data
    # Y-up capture: the rider's head is about 3.1-3.2 units up
    assert 3.0 < g.positions[:, 1].max() < 3.3
    log_s = np.stack([raw[f"scale_{i}"] for i in range(3)], axis=1).astype(np.float64)
    # exp and sigmoid rounded once to float32: within half an ulp of the float64 value
    assert np.all(np.abs(g.scales - np.exp(log_s)) <= np.exp(log_s) * 2.0 ** -24)
    sig = 1.0 / (1.0 + np.exp(-raw["opacity"].astype(np.float64)))
    assert np.all(np.abs(g.opacities - sig) <= 2.0 ** -25)
    assert np.array_equal(_bits(g.logit_opacities), _bits(raw["opacity"]))
    np.testing.assert_allclose(np.linalg.norm(g.orientations.astype(np.float64), axis=1), 1.0, atol=3e-7)
    assert np.array_equal(g.sh[:, 0, 1], raw["f_dc_1"])
    assert g.problems() == []


# ------------------------------------------------------------------------- generated data
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_layout_is_channel_major_in_the_file(tmp_path, degree):
    k = (degree + 1) ** 2
    n = 4
    cols = _columns(n, 3 * (k - 1))
    for i in range(3 * (k - 1)):
        cols[f"f_rest_{i}"] = (1000.0 * np.arange(n) + i).astype(np.float32)
    g = read_ply(_write_raw(tmp_path / "sh.ply", cols))
    assert g.sh.shape == (n, k, 3) and g.sh_degree == degree
    for c in range(3):
        assert np.array_equal(g.sh[:, 0, c], cols[f"f_dc_{c}"])
        for j in range(k - 1):  # USD coefficient j+1 of channel c is f_rest[c*(K-1)+j]
            assert np.array_equal(g.sh[:, 1 + j, c], 1000.0 * np.arange(n) + c * (k - 1) + j)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_generated_round_trip_with_extras(tmp_path, degree):
    g = random_gaussians(50, degree, seed=degree)
    rng = np.random.default_rng(7)
    g.extras = {"nx": rng.normal(size=50).astype(np.float32), "ny": np.zeros(50, np.float32),
                "nz": np.ones(50, np.float32)}
    if degree == 2:  # a non-float extra takes the column-by-column path
        g.extras["segment"] = np.arange(50, dtype=np.uint8)
    path = tmp_path / "g.ply"
    write_ply(path, g)
    names = list(plyfile.PlyData.read(str(path))["vertex"].data.dtype.names)
    assert names == _inria_fields(3 * ((degree + 1) ** 2 - 1), extras=list(g.extras))
    h = read_ply(path)
    for f in ("positions", "orientations", "scales", "opacities", "sh", "log_scales", "logit_opacities"):
        assert np.array_equal(_bits(getattr(g, f)), _bits(getattr(h, f))), f
    assert list(h.extras) == list(g.extras)
    for k, v in g.extras.items():
        assert h.extras[k].dtype == v.dtype and np.array_equal(h.extras[k], v)


def test_ascii_and_big_endian_and_double_read_like_binary(tmp_path):
    cols = _columns(6, 9)
    cols["nx"] = np.linspace(-1, 1, 6).astype(np.float32)
    ref = read_ply(_write_raw(tmp_path / "bin.ply", cols))
    for path in (_write_raw(tmp_path / "ascii.ply", cols, text=True),
                 _write_raw(tmp_path / "be.ply", cols, byte_order=">")):
        g = read_ply(path)
        for f in ("positions", "orientations", "scales", "opacities", "sh", "log_scales", "logit_opacities"):
            assert np.array_equal(getattr(g, f), getattr(ref, f)), (path.name, f)
        assert np.array_equal(g.extras["nx"], cols["nx"])
    dbl = read_ply(_write_raw(tmp_path / "double.ply", cols, dtypes={"x": "f8", "opacity": "f8", "rot_0": "f8"}))
    assert dbl.positions.dtype == np.float32 and np.array_equal(dbl.positions, ref.positions)
    assert np.array_equal(dbl.logit_opacities, ref.logit_opacities)


def test_ascii_write_round_trip(tmp_path):
    g = random_gaussians(20, 1, seed=3)
    write_ply(tmp_path / "a.ply", g, binary=False)
    assert (tmp_path / "a.ply").read_bytes().startswith(b"ply\nformat ascii 1.0\n")
    h = read_ply(tmp_path / "a.ply")
    assert np.array_equal(h.sh, g.sh) and np.array_equal(h.log_scales, g.log_scales)


def test_activations_and_limits(tmp_path):
    cols = _columns(4, 0)
    cols["opacity"] = np.array([-np.inf, np.inf, 0.0, 30.0], np.float32)
    cols["scale_0"] = np.array([-120.0, 0.0, np.log(2.0), -4.0], np.float32)
    g = read_ply(_write_raw(tmp_path / "a.ply", cols))
    assert g.opacities.tolist() == [0.0, 1.0, 0.5, 1.0]
    assert g.scales[0, 0] == np.finfo(np.float32).tiny  # exp underflow stays > 0
    assert g.scales[1, 0] == 1.0 and g.scales[2, 0] == np.float32(2.0)
    assert np.isneginf(g.logit_opacities[0])  # raw kept


def test_writer_without_raw_values_clamps_opacity(tmp_path):
    g = random_gaussians(3, 0, seed=1)
    g = GaussianSet(g.positions, g.orientations, np.array([[1.0, 2.0, 0.5]] * 3), np.array([0.0, 1.0, 0.25]), g.sh)
    write_ply(tmp_path / "c.ply", g)
    d = plyfile.PlyData.read(str(tmp_path / "c.ply"))["vertex"].data
    eps = OPACITY_EPS
    expect = [np.log(eps / (1 - eps)), np.log((1 - eps) / eps), np.log(0.25 / 0.75)]
    np.testing.assert_allclose(d["opacity"], expect, rtol=1e-6)
    assert d["opacity"][1] == pytest.approx(16.118, abs=1e-3)
    np.testing.assert_allclose(d["scale_1"], np.log(2.0), rtol=1e-7)
    assert np.all(d["scale_0"] == 0.0)


def test_write_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "keep.ply"
    write_ply(path, random_gaussians(5, 0, seed=1))
    before = path.read_bytes()

    def boom(self, stream):
        stream.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(plyfile.PlyData, "write", boom)
    with pytest.raises(OSError, match="disk full"):
        write_ply(path, random_gaussians(9, 0, seed=2))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.ply"]


def test_synthetic_generator_statistics():
    g = random_gaussians(20000, 3, seed=5)
    assert g.count == 20000 and g.sh_degree == 3 and g.problems() == []
    assert abs(g.log_scales.mean() + 4.0) < 0.05 and abs(g.log_scales.std() - 1.0) < 0.05
    assert abs(g.logit_opacities.std() - 2.0) < 0.05
    assert abs(g.sh[:, 1:].std() - 0.1) < 0.005 and abs(g.sh[:, 0].std() - 1.0) < 0.05
    assert g.positions.min() >= -5.0 and g.positions.max() <= 5.0
    np.testing.assert_allclose(np.linalg.norm(g.orientations, axis=1), 1.0, atol=1e-6)
    assert np.array_equal(random_gaussians(10, 1, seed=9).sh, random_gaussians(10, 1, seed=9).sh)


# ------------------------------------------------------------------------------- errors
def _raises(path, *needles):
    with pytest.raises(InputFormatError) as info:
        read_ply(path)
    msg = str(info.value)
    assert str(path) in msg
    for s in needles:
        assert s in msg, msg
    return msg


def test_missing_and_not_ply(tmp_path):
    _raises(tmp_path / "nope.ply", "no such file")
    (tmp_path / "t.ply").write_text("hello world\n")
    _raises(tmp_path / "t.ply", "not a PLY")
    (tmp_path / "e.ply").write_bytes(b"")
    _raises(tmp_path / "e.ply", "not a PLY")
    _raises(tmp_path, "not a regular file")


def test_truncated_binary_and_ascii(tmp_path):
    path = _write_raw(tmp_path / "full.ply", _columns(10, 9))
    data = path.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-5])
    _raises(tmp_path / "cut.ply", "element 'vertex'", "truncated")
    apath = _write_raw(tmp_path / "full_a.ply", _columns(10, 0), text=True)
    lines = apath.read_text().splitlines()
    (tmp_path / "cut_a.ply").write_text("\n".join(lines[:-3]) + "\n")
    _raises(tmp_path / "cut_a.ply", "element 'vertex'", "truncated")


def test_no_vertex_element(tmp_path):
    path = _write_raw(tmp_path / "pts.ply", _columns(3, 0), element="points")
    _raises(path, "no 'vertex' element", "points")


def test_missing_required_fields_are_listed(tmp_path):
    cols = _columns(3, 0)
    del cols["opacity"], cols["rot_2"]
    _raises(_write_raw(tmp_path / "m.ply", cols), "lacks required properties", "opacity", "rot_2")


def test_bad_f_rest_count_and_gap(tmp_path):
    _raises(_write_raw(tmp_path / "r5.ply", _columns(3, 5)), "5 'f_rest_*'", "0, 9, 24 or 45")
    cols = _columns(3, 9)
    cols["f_rest_9"] = cols.pop("f_rest_3")
    _raises(_write_raw(tmp_path / "gap.ply", cols), "f_rest_3")


@pytest.mark.parametrize("field,index,value", [("x", 2, np.nan), ("scale_1", 4, np.inf), ("f_dc_2", 0, -np.inf),
                                               ("f_rest_7", 3, np.nan), ("rot_3", 1, np.nan), ("opacity", 5, np.nan)])
def test_non_finite_required_field(tmp_path, field, index, value):
    cols = _columns(6, 9)
    cols[field][index] = value
    cols[field][5 if index != 5 else 4] = value  # a second bad element; the first is reported
    _raises(_write_raw(tmp_path / "nan.ply", cols), f"'{field}'", f"element {min(index, 5 if index != 5 else 4)} ")


def test_scale_overflow_and_zero_quaternion(tmp_path):
    cols = _columns(4, 0)
    cols["scale_2"][3] = 100.0
    _raises(_write_raw(tmp_path / "big.ply", cols), "'scale_2'", "element 3", "overflows")
    cols = _columns(4, 0)
    for i in range(4):
        cols[f"rot_{i}"][1] = 0.0
    _raises(_write_raw(tmp_path / "q0.ply", cols), "rot_0..rot_3", "element 1", "zero quaternion")


def test_write_errors_name_label_field_and_element(tmp_path):
    g = random_gaussians(4, 1, seed=0)
    g.positions[2, 1] = np.nan
    with pytest.raises(GaussianDataError, match=r"random_gaussians.*'y' element 2"):
        write_ply(tmp_path / "w.ply", g)
    g = random_gaussians(4, 0, seed=0)
    g.extras = {"opacity": np.zeros(4, np.float32)}
    with pytest.raises(GaussianDataError, match="'opacity' clashes"):
        write_ply(tmp_path / "w.ply", g)
    g.extras = {"c": np.zeros(4, np.complex64)}
    with pytest.raises(GaussianDataError, match="'c' has dtype complex64"):
        write_ply(tmp_path / "w.ply", g)
    assert list(tmp_path.iterdir()) == []
