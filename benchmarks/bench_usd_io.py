"""Speed of writing/reading Gaussian splat prims to/from usdc, with the round-trip error.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_usd_io.py [--n 1000000] [--degree 3] [--half]

Prints write time (build layer + atomic save), open+read time (wall and process CPU time:
the CPU time is the steadier figure on a shared machine), peak RSS and the max round-trip
error per attribute (0 for float precision: bit-exact).
Targets (1M splats, SH degree 3, float): write < 1 s, read < 0.5 s.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pxr import Usd  # noqa: E402

from usd_gs.gaussians import GaussianSet  # noqa: E402
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic, write_gaussian_prim  # noqa: E402


def make(n: int, degree: int, seed: int = 0) -> GaussianSet:
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((n, 4), dtype=np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    log_s = rng.normal(-4.0, 1.0, (n, 3)).astype(np.float32)
    logit = rng.normal(0.0, 3.0, n).astype(np.float32)
    return GaussianSet(rng.standard_normal((n, 3), dtype=np.float32), q, np.exp(log_s),
                       (1.0 / (1.0 + np.exp(-logit))).astype(np.float32),
                       rng.standard_normal((n, (degree + 1) ** 2, 3), dtype=np.float32) * 0.3,
                       log_s, logit)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--half", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    precision = "half" if args.half else "float"
    g = make(args.n, args.degree)
    print(f"n={args.n} degree={args.degree} precision={precision}  (data {g.sh.nbytes / 1e6:.0f} MB SH)")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.usdc"
        wt, rt, wc, rc = [], [], [], []
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            stage = new_stage(out, default_prim="World")
            write_gaussian_prim(stage, "/World/splats", g, precision=precision)
            save_stage_atomic(stage, out)
            wt.append(time.perf_counter() - t0)
            wc.append(time.process_time() - c0)
            del stage
            t0, c0 = time.perf_counter(), time.process_time()
            st = Usd.Stage.Open(str(out))
            r = read_gaussian_prim(st.GetPrimAtPath("/World/splats"))
            rt.append(time.perf_counter() - t0)
            rc.append(time.process_time() - c0)
            del st
        size = out.stat().st_size / 1e6
    print(f"write (stage + usdc save): best wall {min(wt):.3f} s, cpu {min(wc):.3f} s  "
          f"(wall all {', '.join(f'{x:.3f}' for x in wt)})  file {size:.0f} MB")
    print(f"read  (open + read_gaussian_prim): best wall {min(rt):.3f} s, cpu {min(rc):.3f} s  "
          f"(wall all {', '.join(f'{x:.3f}' for x in rt)})")
    for name in ("positions", "orientations", "scales", "opacities", "sh"):
        err = float(np.max(np.abs(getattr(r, name).astype(np.float64) - getattr(g, name))))
        print(f"  max |error| {name:12s} {err:.3g}")
    print(f"peak RSS {peak_rss_mb():.0f} MB")


if __name__ == "__main__":
    main()
