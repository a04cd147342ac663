"""SPZ reader/writer: the real v4 capture against its PLY conversion, hand-packed v2/v3
files, quantisation-bounded round trips, the coordinate conversion, and error paths."""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest

from usd_gs import sh3dgs
from usd_gs.errors import InputFormatError
from usd_gs.io.ply import read_ply
from usd_gs.io.spz import _RDF_SH_SIGN, read_spz, write_spz
from usd_gs.synthetic import random_gaussians

SPLATS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "splats"
MAGIC = 0x5053474E
C = 0.15  # SPZ colour scale


def _legacy(version, n, degree, arrays, flags=0, frac=12, ext=b""):
    raw = struct.pack("<IIIBBBB", MAGIC, version, n, degree, frac, flags, 0) + ext + b"".join(arrays)
    return gzip.compress(raw)


def _abs_dot(a, b):
    return np.abs(np.sum(a.astype(np.float64) * b.astype(np.float64), axis=1))


# ----------------------------------------------------------------------------- real capture
def test_biker_spz_matches_its_ply_conversion_within_quantisation():
    s = read_spz(SPLATS / "biker.spz")
    p = read_ply(SPLATS / "biker.ply")
    assert s.count == p.count == 152746 and s.sh_degree == 0 and s.label.endswith("biker.spz")
    # 24-bit fixed point with 12 fractional bits
    assert np.abs(s.positions - p.positions).max() <= 2.0 ** -12
    # log-scale byte: steps of 1/16
    assert np.abs(s.log_scales - p.log_scales).max() <= 1 / 16
    # colour byte: (c/255 - 0.5)/0.15 -> one step is 1/(255*0.15)
    assert np.abs(s.sh - p.sh).max() <= 1 / (255 * C)
    # alpha byte: one step is 1/255 in linear opacity
    assert np.abs(s.opacities - p.opacities).max() <= 1 / 255
    # smallest-three: each stored component within half a step (sqrt(1/2)/511/2), so
    # |q1 - q2| <= 2*sqrt(3)*6.9e-4 and |dot| >= 1 - |q1-q2|^2/2 > 1 - 3e-6
    assert _abs_dot(s.orientations, p.orientations).min() >= 1 - 3e-6
    # Y-up native frame, like the PLY: the head is ~3.1 units up
    assert 3.0 < s.positions[:, 1].max() < 3.3
    assert s.problems() == []


def test_rewriting_biker_as_v4_reproduces_the_quantised_streams(tmp_path):
    s = read_spz(SPLATS / "biker.spz")
    write_spz(tmp_path / "b.spz", s, version=4)
    data = (tmp_path / "b.spz").read_bytes()
    orig = (SPLATS / "biker.spz").read_bytes()
    assert data[:32] == orig[:32]  # same header: v4, N, degree 0, 12 bits, 5 streams, TOC at 32
    t = read_spz(tmp_path / "b.spz")
    for f in ("positions", "log_scales", "opacities", "sh"):
        assert np.array_equal(getattr(t, f), getattr(s, f)), f
    assert _abs_dot(t.orientations, s.orientations).min() >= 1 - 3e-6


# ----------------------------------------------------------------------- hand-packed files
def test_hand_packed_v2(tmp_path):
    # one splat: position (1.5, -2.25, 4/4096) in 24-bit fixed point with 12 fractional bits
    pos = bytes([0x00, 0x18, 0x00, 0x00, 0xDC, 0xFF, 0x04, 0x00, 0x00])
    alpha, color, scale = bytes([204]), bytes([128, 255, 0]), bytes([96, 160, 0])
    rot = bytes([255, 128, 128])  # x = 1, y = z = 1/255 -> w = 0
    (tmp_path / "v2.spz").write_bytes(_legacy(2, 1, 0, [pos, alpha, color, scale, rot]))
    g = read_spz(tmp_path / "v2.spz")
    assert g.positions.tolist() == [[1.5, -2.25, 4 / 4096]]
    assert g.opacities[0] == np.float32(0.8)
    np.testing.assert_allclose(g.sh[0, 0], [(128 / 255 - 0.5) / C, 0.5 / C, -0.5 / C], rtol=1e-6)
    assert g.log_scales.tolist() == [[-4.0, 0.0, -10.0]]
    np.testing.assert_allclose(g.scales[0], np.exp([-4.0, 0.0, -10.0]), rtol=1e-7)
    q = np.array([0.0, 1.0, 1 / 255, 1 / 255])
    np.testing.assert_allclose(g.orientations[0], q / np.linalg.norm(q), atol=1e-7)


def test_hand_packed_v3_smallest_three_and_sh(tmp_path):
    # splat 0: (w,x,y,z) = (0.8, 0.6, 0, 0): largest w (index 3 in x,y,z,w order); x stored
    #          in the highest 10 bits: magnitude round(511*0.6/sqrt(1/2)) = 434
    # splat 1: (x,y,z,w) = (0.9, -0.3, 0.3, 0.1): largest x (index 0); w in the lowest bits
    # splat 2: (-0.8, 0.6, 0, 0) = same rotation as (0.8, -0.6, 0, 0): sign bit set on x
    c0 = (3 << 30) | (434 << 20)
    c1 = (0 << 30) | ((512 | 217) << 20) | (217 << 10) | 72
    c2 = (3 << 30) | ((512 | 434) << 20)
    rots = struct.pack("<III", c0, c1, c2)
    n = 3
    pos = bytes(9 * n)
    sh = bytes([0, 64, 128, 192, 255, 128, 128, 128, 96]) + bytes([128] * 18)
    data = _legacy(3, n, 1, [pos, bytes([255] * n), bytes([128] * 3 * n), bytes([0] * 3 * n), rots, sh])
    (tmp_path / "v3.spz").write_bytes(data)
    g = read_spz(tmp_path / "v3.spz")
    s = np.sqrt(0.5) / 511
    x0 = 434 * s
    np.testing.assert_allclose(g.orientations[0], [np.sqrt(1 - x0 ** 2), x0, 0, 0], atol=1e-7)
    yz, w1 = 217 * s, 72 * s
    np.testing.assert_allclose(g.orientations[1], [w1, np.sqrt(1 - 2 * yz ** 2 - w1 ** 2), -yz, yz], atol=1e-7)
    np.testing.assert_allclose(g.orientations[2], [np.sqrt(1 - x0 ** 2), -x0, 0, 0], atol=1e-7)
    assert abs(g.orientations[0, 1] - 0.6) < s
    # SH coefficient-major, channel fastest, (q - 128)/128
    assert g.sh_degree == 1
    assert g.sh[0, 1:].tolist() == [[-1.0, -0.5, 0.0], [0.5, 127 / 128, 0.0], [0.0, 0.0, -0.25]]
    assert np.all(g.sh[1:, 1:] == 0.0)
    assert np.all(g.opacities == 1.0) and np.all(g.log_scales == -10.0)


def test_legacy_extension_records_are_skipped(tmp_path):
    pos = bytes([0x00, 0x10, 0x00] * 3)  # 1.0, 1.0, 1.0
    ext = struct.pack("<IBB", 0xADBE0001, 5, 4)
    arrays = [pos, bytes([10]), bytes([1, 2, 3]), bytes([4, 5, 6]), bytes([0, 0, 0, 0xC0])]
    (tmp_path / "ext.spz").write_bytes(_legacy(3, 1, 0, arrays, flags=0x2, ext=ext))
    g = read_spz(tmp_path / "ext.spz")
    assert g.positions.tolist() == [[1.0, 1.0, 1.0]]
    assert g.log_scales.tolist() == [[4 / 16 - 10, 5 / 16 - 10, 6 / 16 - 10]]
    assert g.orientations.tolist() == [[1.0, 0.0, 0.0, 0.0]]  # largest w, others 0


def test_v4_sh_range_extension(tmp_path):
    import zstandard

    n = 1
    streams = [bytes(9), bytes([255]), bytes([128] * 3), bytes([0] * 3), struct.pack("<I", 3 << 30),
               bytes([0, 255, 51] + [128] * 6)]
    ext = struct.pack("<II", 0xADBE0001, 10) + struct.pack("<BBff", 5, 4, -2.0, 3.0)
    comp = [zstandard.ZstdCompressor().compress(s) for s in streams]
    toc_at = 32 + len(ext)
    head = struct.pack("<IIIBBBBI12x", MAGIC, 4, n, 1, 12, 0x2, 6, toc_at)
    toc = b"".join(struct.pack("<QQ", len(c), len(s)) for c, s in zip(comp, streams, strict=True))
    (tmp_path / "r.spz").write_bytes(head + ext + toc + b"".join(comp))
    g = read_spz(tmp_path / "r.spz")
    np.testing.assert_allclose(g.sh[0, 1], [-2.0, 3.0, -2.0 + 51 / 255 * 5.0], rtol=1e-6)


# --------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("version", [2, 3, 4])
def test_write_read_round_trip_within_quantisation(tmp_path, version):
    g = random_gaussians(400, 3, seed=version)
    write_spz(tmp_path / "r.spz", g, version=version)
    h = read_spz(tmp_path / "r.spz")
    assert h.count == 400 and h.sh_degree == 3
    assert np.abs(h.positions - g.positions).max() <= 2.0 ** -13 + 1e-6
    assert np.abs(h.log_scales - g.log_scales).max() <= 1 / 32 + 1e-6
    assert np.abs(h.opacities - g.opacities).max() <= 1 / 510 + 1e-6
    inside = np.abs(g.sh[:, 0]) < 0.5 / C  # colour bytes clamp outside +/-3.33
    assert inside.mean() > 0.99
    assert np.abs(h.sh[:, 0] - g.sh[:, 0])[inside].max() <= 1 / (2 * 255 * C) + 1e-6
    # SH: rounded to 1/128, then to buckets of 8 (band 1) or 16 (bands 2, 3) steps of 1/128
    in1 = np.abs(g.sh[:, 1:4]) < 0.9
    assert np.abs(h.sh[:, 1:4] - g.sh[:, 1:4])[in1].max() <= (0.5 + 4) / 128 + 1e-6
    in2 = np.abs(g.sh[:, 4:]) < 0.9
    assert np.abs(h.sh[:, 4:] - g.sh[:, 4:])[in2].max() <= (0.5 + 8) / 128 + 1e-6
    bound = 0.99 if version == 2 else 1 - 3e-6
    assert _abs_dot(h.orientations, g.orientations).min() >= bound


def test_rdf_conversion_matches_a_180_degree_rotation_about_x(tmp_path):
    g = random_gaussians(200, 3, seed=11)
    write_spz(tmp_path / "c.spz", g)
    native = read_spz(tmp_path / "c.spz")
    rdf = read_spz(tmp_path / "c.spz", coordinates="rdf")
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    ref = native.transformed(flip, rotate_sh=True)
    np.testing.assert_allclose(rdf.positions, ref.positions, atol=1e-6)
    np.testing.assert_allclose(rdf.covariances(), ref.covariances(), atol=1e-9)
    np.testing.assert_allclose(rdf.sh, ref.sh, atol=2e-5)
    # and writing with coordinates="rdf" undoes it
    write_spz(tmp_path / "back.spz", rdf, coordinates="rdf")
    back = read_spz(tmp_path / "back.spz")
    assert np.array_equal(back.positions, native.positions) and np.array_equal(back.sh, native.sh)


def test_rdf_sh_signs_are_the_basis_parities():
    d = np.random.default_rng(0).normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    y = sh3dgs.eval_basis(d, 3)[:, 1:]
    y_flipped = sh3dgs.eval_basis(d * [1, -1, -1], 3)[:, 1:]
    np.testing.assert_allclose(y_flipped, y * _RDF_SH_SIGN, atol=1e-12)


# ------------------------------------------------------------------------------- errors
def _raises(path, *needles):
    with pytest.raises(InputFormatError) as info:
        read_spz(path)
    msg = str(info.value)
    assert str(path) in msg, msg
    for s in needles:
        assert s in msg, msg


def test_header_errors(tmp_path):
    cases = {
        "text.spz": (b"hello world", ("not an SPZ file",)),
        "empty.spz": (b"", ("not an SPZ file",)),
        "magic.spz": (gzip.compress(struct.pack("<IIIBBBB", 0x12345678, 2, 0, 0, 12, 0, 0)), ("magic 0x12345678",)),
        "v1.spz": (gzip.compress(struct.pack("<IIIBBBB", MAGIC, 1, 0, 0, 12, 0, 0)), ("version 1 ",)),
        "v9gz.spz": (gzip.compress(struct.pack("<IIIBBBB", MAGIC, 9, 0, 0, 12, 0, 0)), ("version 9 ",)),
        "v5.spz": (struct.pack("<IIIBBBBI12x", MAGIC, 5, 0, 0, 12, 0, 0, 32), ("version 5 ",)),
        "raw3.spz": (struct.pack("<IIIBBBB", MAGIC, 3, 0, 0, 12, 0, 0), ("version 3", "gzip")),
        "deg.spz": (gzip.compress(struct.pack("<IIIBBBB", MAGIC, 3, 1, 7, 12, 0, 0)), ("SH degree 7",)),
        "badgz.spz": (b"\x1f\x8b\x08\x00" + bytes(range(40)), ("bad gzip",)),
        "short.spz": (gzip.compress(b"NGSP"), ("truncated",)),
        "streams.spz": (struct.pack("<IIIBBBBI12x", MAGIC, 4, 10, 0, 12, 0, 6, 32), ("6 streams",)),
    }
    for name, (data, needles) in cases.items():
        (tmp_path / name).write_bytes(data)
        _raises(tmp_path / name, *needles)
    _raises(tmp_path / "missing.spz", "no such file")


def test_truncated_files(tmp_path):
    orig = (SPLATS / "biker.spz").read_bytes()
    (tmp_path / "cut4.spz").write_bytes(orig[: len(orig) // 2])
    _raises(tmp_path / "cut4.spz", "truncated", "stream 'colors'")
    (tmp_path / "toc.spz").write_bytes(orig[:40])
    _raises(tmp_path / "toc.spz", "truncated", "table of contents")
    bad = bytearray(orig)
    bad[112:116] = bytes(4)  # the first stream's zstd frame magic
    (tmp_path / "zstd.spz").write_bytes(bytes(bad))
    _raises(tmp_path / "zstd.spz", "stream 'positions'")
    g = random_gaussians(50, 1, seed=0)
    write_spz(tmp_path / "v3.spz", g)
    data = (tmp_path / "v3.spz").read_bytes()
    (tmp_path / "cutgz.spz").write_bytes(data[: len(data) - 40])
    _raises(tmp_path / "cutgz.spz", "truncated")
    raw = gzip.decompress(data)
    (tmp_path / "short_data.spz").write_bytes(gzip.compress(raw[:-10]))
    _raises(tmp_path / "short_data.spz", "truncated", "50 points")


def test_sh_quantisation_matches_the_reference_formula():
    from usd_gs.io.spz import _pack_sh

    def ref(x, bits):  # quantizeSHLegacy in plain Python: C++ std::round, int division, clamp
        b = 1 << (8 - bits)
        v = x * 128.0
        q = int(np.copysign(np.floor(abs(v) + 0.5), v)) + 128
        q = int((q + b // 2) / b) * b
        return min(max(q, 0), 255)

    xs = np.concatenate([np.linspace(-1.3, 1.3, 2001), np.arange(-140, 140) / 128 + 1 / 256]).astype(np.float32)
    for bits in (1, 4, 5, 8):
        assert _pack_sh(xs, bits).tolist() == [ref(float(x), bits) for x in xs], bits
