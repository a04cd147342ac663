"""PLY read/write speed and peak memory for a large 3DGS file.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_ply.py [PATH] [--n 1000000] [--degree 3] [--repeat 3]

If PATH (default: a file in a temporary directory) does not exist, a random set of
``--n`` Gaussians of SH degree ``--degree`` is generated (``usd_gs.synthetic``) and
written there. ``read_ply`` and ``write_ply`` are then timed, each in a fresh Python
process so that the peak RSS printed (``resource.getrusage``) is that of a process doing
only the import (interpreter and numpy included), resp. a read followed by a write.
The written file is compared byte for byte with the input (lossless round trip).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _child(mode: str, path: str, repeat: int) -> None:
    import resource

    t0 = time.perf_counter()
    from usd_gs.io.ply import read_ply, write_ply

    t_import = time.perf_counter() - t0
    out = {"import_s": t_import}
    if mode == "read":
        best = float("inf")
        for _ in range(repeat):
            t = time.perf_counter()
            g = read_ply(path)
            best = min(best, time.perf_counter() - t)
            del g
        out["read_s"] = best
    else:
        g = read_ply(path)
        target = str(Path(path).with_suffix(".rewrite.ply"))
        best = float("inf")
        for _ in range(repeat):
            if os.path.exists(target):
                os.unlink(target)  # time the write, not the unlink of the previous copy
            t = time.perf_counter()
            write_ply(target, g)
            best = min(best, time.perf_counter() - t)
        out["write_s"] = best
        out["identical"] = Path(target).read_bytes() == Path(path).read_bytes()
        os.unlink(target)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps(out))


def _run_child(mode: str, path: str, repeat: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, __file__, "--child", mode, path, "--repeat", str(repeat)],
                         capture_output=True, text=True, env=env, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("path", nargs="?")
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", choices=["read", "write"], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(args.child, args.path, args.repeat)
        return

    tmp = None
    path = args.path
    if path is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_ply_")
        path = os.path.join(tmp.name, f"random_{args.n}_sh{args.degree}.ply")
    try:
        if not os.path.exists(path):
            from usd_gs.io.ply import write_ply
            from usd_gs.synthetic import random_gaussians

            t = time.perf_counter()
            g = random_gaussians(args.n, args.degree, args.seed)
            t_gen = time.perf_counter() - t
            write_ply(path, g)
            del g
            print(f"generated {args.n} splats, SH degree {args.degree} in {t_gen:.2f} s -> {path}")
        size_mb = os.path.getsize(path) / 1e6
        r = _run_child("read", path, args.repeat)
        w = _run_child("write", path, args.repeat)
        print(f"file            {size_mb:9.1f} MB")
        print(f"import usd_gs   {r['import_s']:9.3f} s")
        print(f"read_ply        {r['read_s']:9.3f} s   (best of {args.repeat}; {size_mb / r['read_s']:.0f} MB/s)"
              f"   peak RSS of a read-only process {r['peak_rss_mb']:7.0f} MB")
        print(f"write_ply       {w['write_s']:9.3f} s   (best of {args.repeat}; {size_mb / w['write_s']:.0f} MB/s)"
              f"   peak RSS of a read+write process {w['peak_rss_mb']:7.0f} MB")
        print(f"round trip bit-exact: {w['identical']}")
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":
    main()
