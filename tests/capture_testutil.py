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
