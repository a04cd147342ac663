"""Benchmark of the main job on the demo shot: cold and warm seconds per frame, output bytes
per frame, and bytes per frame with a scene ten times larger outside the avatars' reach.

Usage (from the repo root, package installed in .venv, ../shared/data present):
    .venv/bin/python benchmarks/bench_process.py [--frames 1-48] [--workdir bench_out/process]
        [--skip-cold] [--skip-large]

- cold: a fresh numba cache directory (NUMBA_CACHE_DIR), so JIT compilation is included;
- warm: the same command again with that cache (``--skip-cold``: with the default cache, as
  ``usdgs warmup`` filled it);
- large: the demo plus a bricked block of random Gaussians 9x the demo's scene size placed
  40 m away (beyond every light's and avatar's reach), sublayered into a new shot.
Each run is a whole ``usdgs process`` process; its ``--json`` summary gives the timings.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def usdgs() -> str:
    exe = Path(sys.executable).with_name("usdgs")
    return str(exe) if exe.exists() else "usdgs"


def run_process(stage: Path, out: Path, frames: str, cache_dir: str | None) -> tuple[float, dict]:
    """(wall s, ``--json`` summary) of one ``usdgs process``; ``cache_dir`` None: the default numba cache."""
    env = dict(os.environ) if cache_dir is None else dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    t0 = time.perf_counter()
    r = subprocess.run([usdgs(), "process", str(stage), "-o", str(out), "--frames", frames, "--json"],
                       capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"usdgs process failed:\n{r.stderr}")
    return wall, json.loads(r.stdout)


def make_large_shot(demo: Path, workdir: Path, factor: int = 9) -> Path:
    """A shot = the demo + ``factor`` x the room's Gaussian count, bricked, 40 m away."""
    from pxr import Sdf, Usd

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.bricks import write_bricked
    from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic

    stage = Usd.Stage.Open(str(demo))
    room = sum(read_gaussian_prim(p).count for p in stage.GetPrimAtPath("/World/Room").GetChildren())
    extra = random_gaussians(factor * room, 1, seed=5)
    extra.positions[:, 0] += 40.0  # x in [35, 45] m: far outside the room
    extra.opacities[:] = 0.5
    far = new_stage(default_prim="World")
    write_bricked(far, "/World/FarScene", extra, 12000, keep_raw=False, role="scene")
    far_path = workdir / "far_scene.usdc"
    save_stage_atomic(far, far_path)
    shot = workdir / "large_shot.usda"
    layer = Sdf.Layer.CreateNew(str(shot))
    src = Sdf.Layer.FindOrOpen(str(demo))
    for key in ("upAxis", "metersPerUnit", "timeCodesPerSecond", "startTimeCode", "endTimeCode", "defaultPrim"):
        if src.pseudoRoot.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, src.pseudoRoot.GetInfo(key))
    layer.subLayerPaths.append(os.path.relpath(demo, workdir))
    layer.subLayerPaths.append(far_path.name)
    layer.Save()
    print(f"large shot: demo + {extra.count:,} far Gaussians ({factor}x the room's {room:,})")
    return shot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default="1-48")
    ap.add_argument("--workdir", default="bench_out/process")
    ap.add_argument("--demo", default="stages/demo.usda")
    ap.add_argument("--skip-cold", action="store_true")
    ap.add_argument("--skip-large", action="store_true")
    args = ap.parse_args()
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    demo = Path(args.demo)
    if not demo.exists():
        subprocess.run([usdgs(), "demo", "make", "-o", str(demo), "-q"], check=True)
    # a fresh cache for the cold run (then warm from it); --skip-cold: the default cache (usdgs warmup)
    cache = None if args.skip_cold else tempfile.mkdtemp(prefix="numba_cache_")
    rows = []
    try:
        if not args.skip_cold:
            wall, s = run_process(demo, work / "demo.lit.usdc", args.frames, cache)
            rows.append(("demo, cold (JIT included)", wall, s))
        wall, s = run_process(demo, work / "demo.lit.usdc", args.frames, cache)
        rows.append(("demo, warm", wall, s))
        if not args.skip_large:
            shot = make_large_shot(demo, work)
            wall, s = run_process(shot, work / "large_shot.lit.usdc", args.frames, cache)
            rows.append(("demo + 9x scene far away, warm", wall, s))
    finally:
        if cache is not None:
            shutil.rmtree(cache, ignore_errors=True)
    print(f"machine: {os.cpu_count()} cores; frames {args.frames}")
    print(f"{'run':34s} {'wall s':>8s} {'s/frame':>8s} {'out MB':>8s} {'KB/frame':>9s}  stage seconds")
    for name, wall, s in rows:
        n = s["frames"]["count"]
        stages = ", ".join(f"{k} {v:.2f}" for k, v in s["timings_s"].items() if k not in ("frames", "total"))
        print(f"{name:34s} {wall:8.1f} {s['seconds_per_frame']:8.3f} {s['output_bytes'] / 1e6:8.1f} "
              f"{s['output_bytes'] / n / 1e3:9.0f}  {stages}")


if __name__ == "__main__":
    main()
