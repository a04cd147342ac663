"""Bad capture files: every reader exits 2 with a one-line message naming the file and the
field, never a traceback; hypothesis mutates bytes of small valid files (each reader must give
a valid set or a UserError)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from capture_testutil import DATA, sog_members, write_compressed_ply, write_sog_zip
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_capture_formats import random_set

from usd_gs.cli import main
from usd_gs.errors import UserError
from usd_gs.io.formats import read_capture
from usd_gs.io.splat import encode_splat

PB6 = DATA / "objects" / "playbot" / "6_0"    # 1,873 Gaussians, SH 2 palette: the small SOG
needs_data = pytest.mark.skipif(not PB6.exists(), reason="shared data not found (../shared/data)")


def cli_error(capsys, path, *extra, out=None) -> str:
    """Run ``usdgs import path``; assert exit 2 with one line on stderr; return that line."""
    out = out or path.parent / "out.usdc"
    code = main(["import", str(path), "-o", str(out), *map(str, extra)])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def small_sog(tmp_path):
    if not PB6.exists():
        pytest.skip("shared data not found")
    members = sog_members(PB6)
    path = tmp_path / "pb6.sog"
    write_sog_zip(path, members)
    return path, members


# ------------------------------------------------------------------------------------ SOG
def test_sog_truncated_and_corrupt_zip(capsys, tmp_path, small_sog):
    path, _ = small_sog
    data = path.read_bytes()
    cut = tmp_path / "cut.sog"
    cut.write_bytes(data[: len(data) // 2])
    msg = cli_error(capsys, cut)
    assert str(cut) in msg and "zip" in msg
    # a flipped byte inside a stored member: the zip CRC check names the member
    bad = bytearray(data)
    off = data.index(b"RIFF") + 40
    bad[off] ^= 0xFF
    crc = tmp_path / "crc.sog"
    crc.write_bytes(bytes(bad))
    msg = cli_error(capsys, crc)
    assert str(crc) in msg and "corrupt" in msg and ".webp" in msg


def test_sog_webp_that_does_not_decode(capsys, tmp_path, small_sog):
    _, members = small_sog
    members = dict(members)
    members["quats.webp"] = b"RIFF\x10\x00\x00\x00WEBPVP8L" + b"\x00" * 16
    path = tmp_path / "badwebp.sog"
    write_sog_zip(path, members)
    msg = cli_error(capsys, path)
    assert str(path) in msg and "quats.webp" in msg and "does not decode" in msg
    members["quats.webp"] = members["means_l.webp"][:0] + b"not an image"
    write_sog_zip(path, members)
    assert "quats.webp" in cli_error(capsys, path)


@pytest.mark.parametrize("field", ["count", "means.mins", "scales.codebook", "sh0.files", "shN.bands", "version"])
def test_sog_meta_missing_field(capsys, tmp_path, small_sog, field):
    _, members = small_sog
    meta = json.loads(members["meta.json"])
    head, _, last = field.rpartition(".")
    (meta[head] if head else meta).pop(last)
    path = tmp_path / "nofield.sog"
    write_sog_zip(path, {**members, "meta.json": json.dumps(meta).encode()})
    msg = cli_error(capsys, path)
    assert str(path) in msg and f"'{field}'" in msg


def test_sog_counts_disagree_with_images(capsys, tmp_path, small_sog):
    _, members = small_sog
    meta = json.loads(members["meta.json"])
    meta["count"] = 10 ** 6
    path = tmp_path / "count.sog"
    write_sog_zip(path, {**members, "meta.json": json.dumps(meta).encode()})
    msg = cli_error(capsys, path)
    assert str(path) in msg and "means_l.webp" in msg and "'count' 1000000" in msg
    meta = json.loads(members["meta.json"])
    meta["shN"]["count"] = 10 ** 6
    write_sog_zip(path, {**members, "meta.json": json.dumps(meta).encode()})
    assert "'shN.count'" in cli_error(capsys, path)
    meta = json.loads(members["meta.json"])
    meta["scales"]["codebook"] = meta["scales"]["codebook"][:3]
    write_sog_zip(path, {**members, "meta.json": json.dumps(meta).encode()})
    msg = cli_error(capsys, path)
    assert "'scales'" in msg and "codebook" in msg


@needs_data
def test_lod_set_default_level_and_missing_chunks(capsys, tmp_path):
    """A LOD set copied with only its coarse levels: the default is the finest complete level;
    --lod of a level whose chunk folder is missing names the missing files."""
    src = DATA / "objects" / "playbot"
    dst = tmp_path / "playbot"
    dst.mkdir()
    shutil.copy(src / "lod-meta.json", dst)
    for level in ("5_0", "6_0"):
        shutil.copytree(src / level, dst / level)
    g = read_capture(dst)
    assert g.count == json.loads((src / "5_0" / "meta.json").read_text())["count"]
    msg = cli_error(capsys, dst / "lod-meta.json", "--lod", 0)
    assert "LOD level 0 is incomplete" in msg and str(dst / "0_0" / "meta.json") in msg
    assert "not in the set" in cli_error(capsys, dst / "lod-meta.json", "--lod", 9)
    assert "only applies to SOG LOD sets" in cli_error(capsys, tmp_path / "x.splat", "--lod", 1)


# -------------------------------------------------------------------------- .splat / packed PLY
def test_splat_size_not_multiple_of_32(capsys, tmp_path):
    rec = encode_splat(random_set(10, 0))
    path = tmp_path / "odd.splat"
    path.write_bytes(rec.tobytes()[:-5])
    msg = cli_error(capsys, path)
    assert str(path) in msg and "315 bytes" in msg and "multiple of the 32-byte" in msg
    path.write_bytes(b"")
    assert "empty" in cli_error(capsys, path)
    bad = rec.copy()
    bad["scale"][3, 1] = -1.0
    path.write_bytes(bad.tobytes())
    msg = cli_error(capsys, path)
    assert "record 3" in msg and "'scale'" in msg


def test_compressed_ply_chunk_count_mismatch(capsys, tmp_path):
    path = tmp_path / "c.compressed.ply"
    write_compressed_ply(path, random_set(600, 1))   # 3 chunks
    data = path.read_bytes()
    assert b"element chunk 3\n" in data
    bad = tmp_path / "bad.compressed.ply"
    bad.write_bytes(data.replace(b"element chunk 3\n", b"element chunk 2\n"))
    msg = cli_error(capsys, bad)
    assert str(bad) in msg and "'chunk'" in msg and "2 rows" in msg and "need 3" in msg
    bad.write_bytes(data[: len(data) - 100])
    msg = cli_error(capsys, bad)
    assert str(bad) in msg and "truncated" in msg
    bad.write_bytes(data.replace(b"property uint packed_scale", b"property uint packed_scalx"))
    assert "packed_scale" in cli_error(capsys, bad)


# -------------------------------------------------------------------------------------- fuzz
def _valid_or_user_error(path) -> None:
    try:
        g = read_capture(path)
    except UserError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    assert g.problems() == [], g.problems()


_FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@st.composite
def _mutations(draw, size: int):
    k = draw(st.integers(1, 8))
    return [(draw(st.integers(0, size - 1)), draw(st.integers(0, 255))) for _ in range(k)], \
        draw(st.one_of(st.none(), st.integers(0, size)))


def _mutate(data: bytes, muts) -> bytes:
    edits, cut = muts
    b = bytearray(data)
    for i, v in edits:
        b[i] = v
    return bytes(b if cut is None else b[:cut])


SPLAT_BYTES = encode_splat(random_set(12, 0, seed=5)).tobytes()


@_FUZZ
@given(muts=_mutations(len(SPLAT_BYTES)))
def test_fuzz_splat(tmp_path, muts):
    path = tmp_path / "f.splat"
    path.write_bytes(_mutate(SPLAT_BYTES, muts))
    _valid_or_user_error(path)


@_FUZZ
@given(data=st.data())
def test_fuzz_compressed_ply(tmp_path, data):
    src = tmp_path / "src.compressed.ply"
    if not src.exists():
        write_compressed_ply(src, random_set(300, 1, seed=2))
    raw = src.read_bytes()
    path = tmp_path / "f.compressed.ply"
    path.write_bytes(_mutate(raw, data.draw(_mutations(len(raw)))))
    _valid_or_user_error(path)


@needs_data
@_FUZZ
@given(data=st.data())
def test_fuzz_sog_members(tmp_path, data):
    """Mutations inside the members (meta.json or a webp) of a re-zipped valid .sog, so the
    zip CRC does not hide them; and mutations of the zip bytes themselves."""
    members = sog_members(PB6)
    name = data.draw(st.sampled_from(sorted(members) + ["<zip>"]))
    path = tmp_path / "f.sog"
    if name == "<zip>":
        write_sog_zip(path, members)
        raw = path.read_bytes()
        path.write_bytes(_mutate(raw, data.draw(_mutations(len(raw)))))
    else:
        blob = members[name]
        write_sog_zip(path, {**members, name: _mutate(blob, data.draw(_mutations(len(blob))))})
    _valid_or_user_error(path)


def test_fuzz_cli_exit_codes(tmp_path, capsys):
    """A mutated .splat through the CLI: exit 0 or 2, never 1 (internal error)."""
    rng = np.random.default_rng(0)
    for i in range(20):
        b = bytearray(SPLAT_BYTES)
        idx = rng.integers(0, len(b), size=6)
        b[idx[0]:idx[0] + 4] = rng.integers(0, 256, size=len(b[idx[0]:idx[0] + 4]), dtype=np.uint8).tobytes()
        for j in idx[1:]:
            b[j] = int(rng.integers(0, 256))
        path = tmp_path / f"m{i}.splat"
        path.write_bytes(bytes(b))
        code = main(["import", str(path), "-o", str(tmp_path / "m.usdc"), "-q"])
        err = capsys.readouterr().err
        assert code in (0, 2) and "Traceback" not in err, err
