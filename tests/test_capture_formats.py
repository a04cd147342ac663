"""Capture readers (.splat, .compressed.ply, SOG, SOG LOD sets) against PlayCanvas splat-transform.

Every shared SOG / .splat file (and .compressed.ply files made by splat-transform from PLYs,
since none is shared) is converted to INRIA PLY by splat-transform and compared with this
project's decode. Tolerances (tests/capture_testutil.py): positions, log-scales, SH within
relative 2^-22 (one float32 rounding of the same float64 decode); opacity within 1.5e-6
absolute (splat-transform clamps to [1e-6, 1 - 1e-6] before its logit); quaternions up to sign
with 1 - |q1.q2| <= 1e-6, except .splat (see test_splat_matches_splat_transform). Without node
or splat-transform those tests skip with the reason; the format-only tests below always run.
"""

from __future__ import annotations

import numpy as np
import pytest
from capture_testutil import DATA, assert_same_decode, st_stats, st_to_ply

from usd_gs.gaussians import GaussianSet
from usd_gs.io.compressed_ply import is_compressed_ply, read_compressed_ply
from usd_gs.io.formats import capture_kind, read_capture, write_capture
from usd_gs.io.ply import read_ply, write_ply
from usd_gs.io.sog import read_sog
from usd_gs.io.splat import SH_C0, encode_splat, read_splat

STATUES = sorted((DATA / "humans" / "statues").glob("*.sog"))
MONKEY = sorted((DATA / "sequences" / "monkey").glob("monkey_*.sog"))
SEAL = DATA / "scenes" / "luma-seal.splat"
SKULL = DATA / "objects" / "skull.sog"
FLOWERS = DATA / "scenes" / "flowers" / "lod-meta.json"
PLAYBOT = DATA / "objects" / "playbot" / "lod-meta.json"

needs_data = pytest.mark.skipif(not SEAL.exists(), reason="shared data not found (../shared/data)")


def random_set(n: int, degree: int, seed: int = 0) -> GaussianSet:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    k = (degree + 1) ** 2
    sh = rng.uniform(-1.5, 1.5, size=(n, k, 3))
    sh[:, 1:] *= 0.3
    return GaussianSet(rng.normal(size=(n, 3)) * 2.0, q, np.exp(rng.uniform(-6, 0, size=(n, 3))),
                       rng.uniform(0.02, 0.98, size=n), sh, label="random")


# ------------------------------------------------------------------------ splat-transform reference
@needs_data
def test_sog_bundled_match_splat_transform(tmp_path):
    """All seven statues and the skull (SH 3 palette): merged in one splat-transform run."""
    assert len(STATUES) == 7
    ref = read_ply(st_to_ply(STATUES, tmp_path / "statues.ply"))
    ours = GaussianSet.concatenate([read_sog(f) for f in STATUES])
    assert_same_decode(ours, ref, "statues")
    skull = read_sog(SKULL)
    assert skull.sh_degree == 3
    assert_same_decode(skull, read_ply(st_to_ply([SKULL], tmp_path / "skull.ply")), "skull")


@needs_data
def test_sog_monkey_sequence_matches_splat_transform(tmp_path):
    """Every fifth frame of the 50 (merged in one run, to keep the test short)."""
    assert len(MONKEY) == 50
    frames = MONKEY[::5]
    ref = read_ply(st_to_ply(frames, tmp_path / "monkey.ply"))
    ours = GaussianSet.concatenate([read_capture(f) for f in frames])
    assert_same_decode(ours, ref, "monkey 1, 6, ... 46")


@needs_data
@pytest.mark.parametrize("lod_set,levels", [(PLAYBOT, (5, 6)), (FLOWERS, (3,))])
def test_sog_lod_levels_match_splat_transform(tmp_path, lod_set, levels):
    """Small levels of both LOD sets (the large ones are left to the benchmark, which checks
    flowers level 0 the same way)."""
    for lod in levels:
        ref = read_ply(st_to_ply([lod_set], tmp_path / f"lod{lod}.ply", lod=lod))
        ours = read_sog(lod_set, lod=lod)
        assert_same_decode(ours, ref, f"{lod_set} LOD {lod}")
        assert ours.sh_degree == 2


@needs_data
def test_sog_lod_level_of_several_chunks(tmp_path):
    """A LOD set whose level 0 is two chunk files (playbot's 6_0 and 5_0 folders, referenced
    in that file order by two tree nodes): the level is the chunks in file-index order."""
    import json
    import shutil

    for name in ("5_0", "6_0"):
        shutil.copytree(PLAYBOT.parent / name, tmp_path / name)
    counts = {n: json.loads((tmp_path / n / "meta.json").read_text())["count"] for n in ("5_0", "6_0")}
    meta = {"lodLevels": 1, "filenames": ["6_0/meta.json", "5_0/meta.json"],
            "tree": {"children": [{"lods": {"0": {"file": 1, "offset": 0, "count": counts["5_0"]}}},
                                  {"lods": {"0": {"file": 0, "offset": 0, "count": counts["6_0"]}}}]}}
    (tmp_path / "lod-meta.json").write_text(json.dumps(meta))
    ref = read_ply(st_to_ply([tmp_path / "lod-meta.json"], tmp_path / "two.ply", lod=0))
    ours = read_sog(tmp_path / "lod-meta.json")
    assert ours.count == counts["5_0"] + counts["6_0"]
    assert_same_decode(ours, ref, "two-chunk level")
    np.testing.assert_array_equal(ours.positions[:counts["6_0"]], read_sog(tmp_path / "6_0").positions)


@needs_data
def test_splat_matches_splat_transform(tmp_path):
    """The seal. splat-transform decodes quaternion bytes as u/255*2-1, antimatter15 (and this
    reader) as (u-128)/128: ours is checked exactly against antimatter15's formula, and
    against splat-transform's quaternion within the angle the two decodes can differ by
    (1 - |q1.q2| <= 2e-4; about 1.1 degrees)."""
    ref = read_ply(st_to_ply([SEAL], tmp_path / "seal.ply"))
    ours = read_splat(SEAL)
    assert_same_decode(ours, ref, "seal", quat_tol=2e-4)
    raw = np.fromfile(SEAL, dtype=np.uint8).reshape(-1, 32)[:, 28:32].astype(np.float64)
    a15 = (raw - 128) / 128
    a15 /= np.linalg.norm(a15, axis=1, keepdims=True)
    np.testing.assert_array_equal(ours.orientations, a15.astype(np.float32))
    st = raw / 255 * 2 - 1
    st /= np.linalg.norm(st, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(ref.orientations), np.abs(st), atol=1e-6)


@needs_data
def test_compressed_ply_matches_splat_transform(tmp_path):
    """No .compressed.ply is shared: splat-transform compresses guitar.ply (SH 0) and a random
    1,000-Gaussian SH-3 set (a partial last chunk), then decompresses both to PLY."""
    src = tmp_path / "rand.ply"
    write_ply(src, random_set(1000, 3))
    for name, ply in (("guitar", DATA / "splats" / "guitar.ply"), ("rand", src)):
        comp = tmp_path / f"{name}.compressed.ply"
        st_to_ply([ply], comp)
        assert is_compressed_ply(comp) and capture_kind(comp) == "compressed-ply"
        ref = read_ply(st_to_ply([comp], tmp_path / f"{name}.back.ply"))
        ours = read_compressed_ply(comp)
        assert_same_decode(ours, ref, name)
        # a compressed PLY without the .compressed suffix is still recognised by its header
        plain = tmp_path / f"{name}_packed.ply"
        plain.write_bytes(comp.read_bytes())
        np.testing.assert_array_equal(read_capture(plain).positions, ours.positions)
    assert read_compressed_ply(tmp_path / "rand.compressed.ply").sh_degree == 3


def test_written_files_read_back_by_splat_transform(tmp_path):
    """.ply, .splat and .spz written here: splat-transform's --stats agree on counts, SH
    bands and per-column min/max/mean, within each format's quantisation."""
    g = random_set(3000, 1, seed=3)
    pos_tol = {".ply": 1e-6, ".splat": 1e-6, ".spz": 2.0 / 4096}
    for ext in (".ply", ".splat", ".spz"):
        path = tmp_path / f"out{ext}"
        write_capture(path, g)
        info = st_stats(path)
        assert info["numGaussians"] == g.count, ext
        assert info["shBands"] == (1 if ext != ".splat" else 0), ext
        cols = info["by_column"]
        for j, c in enumerate("xyz"):
            for stat, ours in (("min", g.positions[:, j].min()), ("max", g.positions[:, j].max()),
                               ("mean", g.positions[:, j].mean())):
                assert abs(cols[c][stat] - ours) <= pos_tol[ext] + 1e-5 * abs(ours), (ext, c, stat)
        # --stats reports f_dc as the colour 0.5 + C0 f_dc (u8 in .splat; SPZ steps of 1/(0.15*255) f_dc)
        dc_tol = {".ply": 1e-5, ".splat": 0.5 / 255 + 1e-5, ".spz": 0.5 * SH_C0 / (0.15 * 255) + 1e-5}[ext]
        for c in range(3):
            colour = 0.5 + SH_C0 * g.sh[:, 0, c].astype(np.float64)
            for stat, ours in (("mean", colour.mean()), ("min", colour.min()), ("max", colour.max())):
                assert abs(cols[f"f_dc_{c}"][stat] - ours) <= dc_tol, (ext, c, stat)
        op_tol = {".ply": 1e-5, ".splat": 0.5 / 255 + 1e-6, ".spz": 0.5 / 255 + 1e-6}[ext]
        # (--stats maps mean/stdDev of opacity and scale through the sigmoid / exp: min and max only)
        assert abs(cols["opacity"]["min"] - g.opacities.min()) <= op_tol, ext
        assert abs(cols["opacity"]["max"] - g.opacities.max()) <= op_tol, ext
        s_tol = {".ply": 1e-5, ".splat": 1e-5, ".spz": 1 / 32}[ext]  # SPZ: log-scale steps of 1/16
        for j in range(3):
            for stat, ours in (("min", g.scales[:, j].min()), ("max", g.scales[:, j].max())):
                assert abs(np.log(cols[f"scale_{j}"][stat]) - np.log(ours)) <= s_tol, (ext, j, stat)


# ---------------------------------------------------------------------------- format-only checks
def test_splat_round_trip_quantisation(tmp_path):
    """write_splat -> read_splat: positions and scales exact, colour/opacity within half a
    u8 step, quaternions within the (q*128+128) rounding."""
    g = random_set(500, 2, seed=1)
    path = tmp_path / "r.splat"
    write_capture(path, g)
    assert path.stat().st_size == 500 * 32
    back = read_capture(path)
    np.testing.assert_array_equal(back.positions, g.positions)
    np.testing.assert_array_equal(back.scales, g.scales)
    assert back.sh_degree == 0
    np.testing.assert_allclose(back.sh[:, 0], g.sh[:, 0], atol=0.5 / 255 / SH_C0 + 1e-6)
    np.testing.assert_allclose(back.opacities, g.opacities, atol=0.5 / 255 + 1e-7)
    dot = np.abs(np.einsum("ij,ij->i", back.orientations.astype(np.float64), g.orientations))
    assert 1 - dot.min() < 2e-4
    rec = encode_splat(g)
    # byte-level: antimatter15's q*128+128 with (w, x, y, z) order
    np.testing.assert_array_equal(rec["rot"], np.clip(np.rint(g.unit_quaternions() * 128 + 128), 0, 255))


@needs_data
def test_sog_folder_and_meta_json_forms(tmp_path):
    """A LOD chunk folder, its meta.json and the LOD set folder read the same data."""
    chunk = DATA / "objects" / "playbot" / "6_0"
    a = read_capture(chunk)
    b = read_capture(chunk / "meta.json")
    np.testing.assert_array_equal(a.sh, b.sh)
    c = read_capture(PLAYBOT.parent, lod=6)
    np.testing.assert_array_equal(c.positions, a.positions)


def test_sog_writer_round_trip(tmp_path):
    """write_sog -> read_sog within the SOG quantisation (16-bit log positions, 256-entry
    codebooks, 8-bit opacity and quaternions); degree > 0 is refused."""
    from usd_gs.errors import UserError
    from usd_gs.io.sog import write_sog

    g = random_set(2000, 0, seed=4)
    path = tmp_path / "w.sog"
    write_capture(path, g)
    back = read_capture(path)
    assert back.count == g.count and back.sh_degree == 0
    lt = np.sign(g.positions) * np.log1p(np.abs(g.positions))
    step = (lt.max(0) - lt.min(0)) / 65535
    back_lt = np.sign(back.positions) * np.log1p(np.abs(back.positions))
    assert np.all(np.abs(back_lt - lt) <= 0.5 * step + 1e-6)
    np.testing.assert_allclose(back.opacities, g.opacities, atol=0.5 / 255 + 1e-7)
    dot = np.abs(np.einsum("ij,ij->i", back.orientations.astype(np.float64), g.orientations))
    assert 1 - dot.min() < 1e-4
    log_s = np.log(g.scales.astype(np.float64))
    assert np.abs(back.log_scales - log_s).max() < 0.05   # 256 codebook entries over a range of 6
    assert np.abs(back.sh - g.sh).max() < 0.05
    folder = tmp_path / "f"
    folder.mkdir()
    write_sog(folder / "meta.json", g)
    np.testing.assert_array_equal(read_capture(folder).positions, back.positions)
    with pytest.raises(UserError, match="SH degree 0 only"):
        write_sog(tmp_path / "x.sog", random_set(10, 1))


def test_sog_written_here_read_by_splat_transform(tmp_path):
    path = tmp_path / "w.sog"
    write_capture(path, random_set(3000, 0, seed=6))
    ref = read_ply(st_to_ply([path], tmp_path / "w.ply"))
    assert_same_decode(read_sog(path), ref, "written .sog")
