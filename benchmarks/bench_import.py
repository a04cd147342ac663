"""Benchmark: `usdgs import` / `usdgs export` of a large SH-degree-3 PLY, as whole processes,
side by side with NVIDIA's public converter `usd-convert-gsplat`.

Prints wall time and peak RSS of each process, the PLY -> USD -> PLY round-trip check
(bit-exact fields), and the speed ratio against the public converter.

Usage (from the repo root, with the package installed in .venv):
    .venv/bin/python benchmarks/bench_import.py [--n 1000000] [--degree 3] [--workdir bench_out]
        [--skip-nvidia]

The public converter is run only if its console script ``usd-convert-gsplat`` is on PATH
or next to this interpreter (``pip install usd-convert-gsplat``, also in the ``bench`` extra).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time

import numpy as np


def run_measured(cmd: list[str]) -> tuple[float, float]:
    """Run ``cmd`` as a child process; return (wall seconds, peak RSS in MiB) of that child."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"command failed ({' '.join(cmd)}):\n{err}")
    return wall, usage.ru_maxrss / 1024.0


def tool(name: str) -> str | None:
    here = os.path.join(os.path.dirname(sys.executable), name)
    return here if os.path.exists(here) else shutil.which(name)


def compare_ply(a: str, b: str) -> dict[str, str]:
    """Field-by-field comparison of two INRIA PLYs: 'bit-exact' or the max abs difference."""
    from plyfile import PlyData

    va = PlyData.read(a)["vertex"].data
    vb = PlyData.read(b)["vertex"].data
    out = {}
    groups = {"xyz": ["x", "y", "z"], "f_dc": [n for n in va.dtype.names if n.startswith("f_dc")],
              "f_rest": [n for n in va.dtype.names if n.startswith("f_rest")], "opacity": ["opacity"],
              "scale": [n for n in va.dtype.names if n.startswith("scale")]}
    for g, names in groups.items():
        exact = all(np.array_equal(va[n].view(np.uint32), vb[n].view(np.uint32)) for n in names)
        out[g] = "bit-exact" if exact else f"max |diff| {max(np.max(np.abs(va[n] - vb[n])) for n in names):.3g}"
    qa = np.stack([va[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qb = np.stack([vb[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    qa /= np.linalg.norm(qa, axis=1, keepdims=True)
    qb /= np.linalg.norm(qb, axis=1, keepdims=True)
    out["rot (normalised)"] = f"max |diff| {np.max(np.abs(qa - qb)):.3g}"
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--workdir", default="bench_out")
    ap.add_argument("--skip-nvidia", action="store_true")
    args = ap.parse_args()

    from usd_gs.io.ply import write_ply
    from usd_gs.synthetic import random_gaussians

    os.makedirs(args.workdir, exist_ok=True)
    ply = os.path.join(args.workdir, f"random_{args.n}_sh{args.degree}.ply")
    if not os.path.exists(ply):
        write_ply(ply, random_gaussians(args.n, args.degree, seed=0))
    size_mb = os.path.getsize(ply) / 1e6
    usdgs = tool("usdgs") or "usdgs"
    out_usd = os.path.join(args.workdir, "usdgs.usdc")
    back_ply = os.path.join(args.workdir, "usdgs_back.ply")

    # warm the page cache so both tools read from memory
    with open(ply, "rb") as f:
        while f.read(1 << 24):
            pass
    rows = []
    t_imp, m_imp = run_measured([usdgs, "import", ply, "-o", out_usd, "--prim", "/Splats", "-q"])
    rows.append(("usdgs import (PLY -> usdc)", t_imp, m_imp))
    t_exp, m_exp = run_measured([usdgs, "export", out_usd, "--prim", "/Splats", "-o", back_ply, "-q"])
    rows.append(("usdgs export (usdc -> PLY)", t_exp, m_exp))
    nv = None if args.skip_nvidia else tool("usd-convert-gsplat")
    if nv:
        t_nv, m_nv = run_measured([nv, "-i", ply, "-o", os.path.join(args.workdir, "nvidia.usdc")])
        rows.append(("usd-convert-gsplat (PLY -> usdc)", t_nv, m_nv))

    print(f"input: {ply} ({args.n:,} Gaussians, SH degree {args.degree}, {size_mb:.0f} MB); "
          f"machine: {os.cpu_count()} cores")
    print(f"{'step':36s} {'wall s':>8s} {'peak RSS MiB':>13s}")
    for name, t, m in rows:
        print(f"{name:36s} {t:8.2f} {m:13.0f}")
    if nv:
        print(f"speed ratio usd-convert-gsplat / usdgs import: {t_nv / t_imp:.1f}x; "
              f"memory ratio {m_nv / m_imp:.1f}x")
    print("round trip PLY -> USD -> PLY:")
    for field, verdict in compare_ply(ply, back_ply).items():
        print(f"  {field:18s} {verdict}")
    print(f"usdc size: {os.path.getsize(out_usd) / 1e6:.0f} MB")


if __name__ == "__main__":
    main()
