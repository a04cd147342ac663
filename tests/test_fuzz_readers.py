"""Fuzzing the PLY and SPZ readers through the CLI (``usdgs import``): every outcome is exit 0
with a stage that validates, or exit 2 with a one-line message; never 1 or a traceback.
Examples: the 'ci' hypothesis profile of tests/conftest.py (fixed and small)."""

from __future__ import annotations

import gzip
import struct
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from usd_gs.cli import main
from usd_gs.io.spz import write_spz
from usd_gs.synthetic import random_gaussians

PLY_FIELDS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
              "rot_0", "rot_1", "rot_2", "rot_3"]
PLY_TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "short": "<i2", "int": "<i4"}
SPECIAL = [0.0, 1.0, -1.0, np.nan, np.inf, -np.inf, 1e30, -88.0, 88.0, 70000.0, 1e-40]


def check_outcome(capsys, argv, out: Path | None) -> int:
    """Run ``usdgs argv``; exit 0 must leave an output that validates, exit 2 one error line."""
    capsys.readouterr()
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc in (0, 2), (rc, err)
    assert "Traceback" not in err and "internal error" not in err, err
    if rc == 2:
        lines = [ln for ln in err.strip().splitlines() if ln.startswith("usdgs ")]
        assert len(lines) == 1 and ": error: " in lines[0], err
        if out is not None:
            assert not out.exists()
    elif out is not None and out.suffix in (".usd", ".usda", ".usdc"):
        assert main(["validate", str(out), "-q"]) == 0, capsys.readouterr()
    return rc


@st.composite
def ply_files(draw):
    n = draw(st.integers(0, 12))
    rest = draw(st.sampled_from([0, 9, 24, 45, 7]))
    names = [f for f in PLY_FIELDS if draw(st.booleans()) or f not in ("opacity", "rot_3", "f_dc_2")] + \
        [f"f_rest_{i}" for i in range(rest)]
    if draw(st.booleans()):
        names.append("nx")
    types = {nm: draw(st.sampled_from(["float"] * 6 + list(PLY_TYPES))) for nm in names}
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    cols = {nm: rng.normal(0, 1, n) for nm in names}
    for nm in ("scale_0", "scale_1", "scale_2"):
        if nm in cols:
            cols[nm] = cols[nm] - 4
    for _ in range(draw(st.integers(0, 3))):  # special values at random places
        if n and names:
            nm = draw(st.sampled_from(names))
            cols[nm][draw(st.integers(0, n - 1))] = draw(st.sampled_from(SPECIAL))
    ascii_ = draw(st.booleans())
    claimed = n + draw(st.sampled_from([0, 0, 0, 1, -1, 10**12]))
    header = ["ply", "format ascii 1.0" if ascii_ else "format binary_little_endian 1.0",
              f"element vertex {max(claimed, 0)}"] + [f"property {types[nm]} {nm}" for nm in names] + ["end_header"]
    body = b""
    if ascii_:
        rows = [" ".join(repr(float(cols[nm][i])) if types[nm] in ("float", "double")
                         else str(int(np.clip(np.nan_to_num(cols[nm][i]), -100, 100))) for nm in names)
                for i in range(n)]
        body = ("\n".join(rows) + ("\n" if rows else "")).encode()
    elif names:
        rec = np.zeros(n, dtype=[(nm, PLY_TYPES[types[nm]]) for nm in names])
        for nm in names:
            v = cols[nm]
            if types[nm] not in ("float", "double"):
                v = np.clip(np.nan_to_num(v), -100, 100)
            with np.errstate(all="ignore"):
                rec[nm] = v
        body = rec.tobytes()
    data = ("\n".join(header) + "\n").encode() + body
    cut = draw(st.sampled_from([None, None, None, -1, 10]))
    if cut is not None:
        data = data[:cut] if cut > 0 else data[:-max(1, len(body) // 3)]
    return data


@given(data=ply_files(), half=st.booleans())
def test_fuzz_ply_import(capsys, data, half):
    with tempfile.TemporaryDirectory() as d:
        src, out = Path(d) / "in.ply", Path(d) / "out.usdc"
        src.write_bytes(data)
        argv = ["import", str(src), "-o", str(out), "-q"] + (["--precision", "half"] if half else [])
        check_outcome(capsys, argv, out)


def _valid_spz(n: int, degree: int, seed: int) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.spz"
        g = random_gaussians(n, degree=degree, seed=seed)
        g.positions *= 0.5
        write_spz(p, g, version=2)
        return p.read_bytes()


@st.composite
def spz_files(draw):
    n = draw(st.integers(0, 10))
    raw = bytearray(gzip.decompress(_valid_spz(n, draw(st.integers(0, 3)), draw(st.integers(0, 1000)))))
    what = draw(st.sampled_from(["none", "version", "count", "degree", "frac", "flags", "flip", "cut", "magic"]))
    if what == "version":
        struct.pack_into("<I", raw, 4, draw(st.sampled_from([0, 1, 3, 4, 7, 2**31])))
    elif what == "count":
        struct.pack_into("<I", raw, 8, draw(st.sampled_from([0, n + 1, max(n - 1, 0), 2**31, 2**32 - 1])))
    elif what == "degree":
        raw[12] = draw(st.sampled_from([0, 1, 2, 3, 4, 255]))
    elif what == "frac":
        raw[13] = draw(st.sampled_from([0, 12, 23, 24, 255]))
    elif what == "flags":
        raw[14] = draw(st.integers(0, 255))
    elif what == "flip" and len(raw) > 16:
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(16, len(raw) - 1))
            raw[i] = draw(st.integers(0, 255))
    elif what == "cut":
        raw = raw[:draw(st.integers(0, len(raw)))]
    elif what == "magic":
        raw[0] ^= 0xFF
    data = gzip.compress(bytes(raw))
    if draw(st.booleans()) and what == "none":
        data = data[:len(data) - draw(st.integers(1, 8))]  # a truncated gzip stream
    return data


@given(data=spz_files())
def test_fuzz_spz_import(capsys, data):
    with tempfile.TemporaryDirectory() as d:
        src, out = Path(d) / "in.spz", Path(d) / "out.usdc"
        src.write_bytes(data)
        check_outcome(capsys, ["import", str(src), "-o", str(out), "-q"], out)
