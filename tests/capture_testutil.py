"""Helpers for the capture-format tests: finding and running PlayCanvas splat-transform, and
comparing two Gaussian sets within the tolerances the tests state."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"

#: positions, log-scales and SH: the same float64 decode rounded once to float32 on both
#: sides, so at most one float32 rounding apart (relative 2^-23, doubled for safety).
RTOL_F32 = 2.0 ** -22
#: opacities: ours is the stored linear value; splat-transform writes logit(clamp(v, 1e-6,
#: 1 - 1e-6)) to PLY, so sigmoid of it is within 1e-6 (plus float32 rounding) of ours.
ATOL_OPACITY = 1.5e-6
#: quaternions, up to sign: both sides normalise the same decoded components (splat-transform
#: stores them un-normalised in float32), so 1 - |q1 . q2| is float32 rounding only.
QUAT_DOT_TOL = 1e-6


def splat_transform() -> str:
    """Path of splat-transform (env USDGS_SPLAT_TRANSFORM, <repo>/.ci/node, PATH) or skip."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the splat-transform comparison cannot run (see .ci/run)")
    cands = [os.environ.get("USDGS_SPLAT_TRANSFORM"), str(REPO / ".ci" / "node" / "node_modules" / ".bin" /
                                                          "splat-transform"), shutil.which("splat-transform")]
    for c in cands:
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    pytest.skip("splat-transform not found (npm install --prefix .ci/node @playcanvas/splat-transform@3, "
                "as .ci/run does): the reference comparison cannot run")


def run_st(*args, timeout: float = 120) -> str:
    """Run splat-transform quietly with ``args``; return stdout; fail the test on error."""
    cmd = [splat_transform(), "-q", *map(str, args)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert res.returncode == 0, f"{' '.join(cmd)} failed: {res.stderr[-2000:]}"
    return res.stdout


def st_to_ply(inputs, out: Path, lod: int | None = None) -> Path:
    """Convert (and merge, in order) ``inputs`` to an INRIA PLY with splat-transform."""
    extra = ["-L", str(lod)] if lod is not None else []
    run_st("-w", *extra, *inputs, out)
    return out


def st_stats(path) -> dict:
    """``splat-transform FILE --stats json null`` parsed; ``columns`` -> per-stat dicts."""
    out = json.loads(run_st(path, "--stats", "json", "null"))
    st = out["stats"][0]
    cols = st["columns"]
    out["by_column"] = {c: {k: v[i] for k, v in st["data"].items()} for i, c in enumerate(cols)}
    return out


def assert_same_decode(ours, ref, what: str, quat_tol: float = QUAT_DOT_TOL) -> None:
    """``ours`` (this project's decode) equals ``ref`` (splat-transform's, via PLY) within the
    module tolerances; quaternions up to sign."""
    assert ours.count == ref.count, f"{what}: {ours.count} vs {ref.count} Gaussians"
    assert ours.sh_degree == ref.sh_degree, what
    np.testing.assert_allclose(ours.positions, ref.positions, rtol=RTOL_F32, atol=0, err_msg=f"{what}: positions")
    np.testing.assert_allclose(ours.log_scales, ref.log_scales, rtol=RTOL_F32, atol=0, err_msg=f"{what}: log-scales")
    np.testing.assert_allclose(ours.scales, ref.scales, rtol=2 * RTOL_F32, atol=0, err_msg=f"{what}: scales")
    np.testing.assert_allclose(ours.sh, ref.sh, rtol=RTOL_F32, atol=1e-30, err_msg=f"{what}: SH")
    np.testing.assert_allclose(ours.opacities, ref.opacities, rtol=0, atol=ATOL_OPACITY, err_msg=f"{what}: opacity")
    dot = np.abs(np.einsum("ij,ij->i", ours.orientations.astype(np.float64), ref.orientations.astype(np.float64)))
    worst = int(np.argmin(dot))
    assert 1.0 - dot[worst] <= quat_tol, f"{what}: quaternion {worst}: {ours.orientations[worst]} vs " \
                                         f"{ref.orientations[worst]}"


# ------------------------------------------------------------------------- small test files
def _unorm(x, bits):
    t = (1 << bits) - 1
    return np.clip(np.floor(np.asarray(x, np.float64) * t + 0.5), 0, t).astype(np.uint32)


def write_compressed_ply(path, g, sh_bytes: bool = True) -> None:
    """A PlayCanvas .compressed.ply of ``g`` packed here (independent of the reader), in the
    layout splat-transform writes: chunk bounds with colour, packed vertex words, uint8 SH."""
    from plyfile import PlyData, PlyElement

    n = g.count
    nc = (n + 255) // 256
    rows = np.arange(n) // 256
    c0 = 0.28209479177387814
    cols = {"pos": g.positions.astype(np.float64), "scale": np.log(g.scales.astype(np.float64)),
            "col": 0.5 + c0 * g.sh[:, 0, :].astype(np.float64)}
    chunk = np.zeros(nc, dtype=[(f"{m}_{k}", "<f4") for m, ks in (
        ("min", "xyz"), ("max", "xyz"), ("min_scale", "xyz"), ("max_scale", "xyz"), ("min", "rgb"), ("max", "rgb"))
        for k in ks])
    packed = {}
    for key, (lo_names, hi_names) in {"pos": (("min_x", "min_y", "min_z"), ("max_x", "max_y", "max_z")),
                                      "scale": (("min_scale_x", "min_scale_y", "min_scale_z"),
                                                ("max_scale_x", "max_scale_y", "max_scale_z")),
                                      "col": (("min_r", "min_g", "min_b"), ("max_r", "max_g", "max_b"))}.items():
        v = cols[key]
        lo = np.full((nc, 3), np.inf)
        hi = np.full((nc, 3), -np.inf)
        np.minimum.at(lo, rows, v)
        np.maximum.at(hi, rows, v)
        for j in range(3):
            chunk[lo_names[j]] = lo[:, j]
            chunk[hi_names[j]] = hi[:, j]
        lo32 = lo.astype(np.float32).astype(np.float64)[rows]
        hi32 = hi.astype(np.float32).astype(np.float64)[rows]
        span = np.where(hi32 - lo32 > 1e-5, hi32 - lo32, 1.0)
        packed[key] = np.clip((v - lo32) / span, 0, 1)
    bits = (11, 10, 11)
    pos = (_unorm(packed["pos"][:, 0], 11) << 21) | (_unorm(packed["pos"][:, 1], 10) << 11) | _unorm(
        packed["pos"][:, 2], 11)
    scl = (_unorm(packed["scale"][:, 0], bits[0]) << 21) | (_unorm(packed["scale"][:, 1], 10) << 11) | _unorm(
        packed["scale"][:, 2], 11)
    colw = ((_unorm(packed["col"][:, 0], 8) << 24) | (_unorm(packed["col"][:, 1], 8) << 16)
            | (_unorm(packed["col"][:, 2], 8) << 8) | _unorm(g.opacities, 8))
    q = g.unit_quaternions()
    big = np.argmax(np.abs(q), axis=1)
    q = q * np.sign(q[np.arange(n), big])[:, None]
    rot = big.astype(np.uint32)
    for i in range(4):
        keep = big != i
        rot = np.where(keep, (rot << 10) | _unorm(q[:, i] * np.sqrt(0.5) + 0.5, 10), rot)
    vertex = np.zeros(n, dtype=[("packed_position", "<u4"), ("packed_rotation", "<u4"), ("packed_scale", "<u4"),
                                ("packed_color", "<u4")])
    vertex["packed_position"], vertex["packed_rotation"] = pos, rot
    vertex["packed_scale"], vertex["packed_color"] = scl, colw
    elements = [PlyElement.describe(chunk, "chunk"), PlyElement.describe(vertex, "vertex")]
    k = g.sh.shape[1]
    if k > 1 and sh_bytes:
        rest = g.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1).astype(np.float64)
        b = np.clip(np.floor((rest / 8 + 0.5) * 256), 0, 255).astype(np.uint8)
        sh = np.zeros(n, dtype=[(f"f_rest_{i}", "u1") for i in range(b.shape[1])])
        for i in range(b.shape[1]):
            sh[f"f_rest_{i}"] = b[:, i]
        elements.append(PlyElement.describe(sh, "sh"))
    PlyData(elements, byte_order="<").write(str(path))


def sog_members(src) -> dict[str, bytes]:
    """The members of a bundled .sog (or the files of a SOG folder) by name."""
    import zipfile

    src = Path(src)
    if src.is_dir():
        return {p.name: p.read_bytes() for p in src.iterdir() if p.is_file()}
    with zipfile.ZipFile(src) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def write_sog_zip(path, members: dict[str, bytes]) -> None:
    import zipfile

    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
