"""Farm-run throughput and per-chunk overhead on the demo stage.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_farm.py [--stage stages/demo.usda] [--frames 1-8] [--chunk-size 2]

Prints (and writes as JSON to --json FILE):
- frames/s of ``usdgs process --chunk-size N --workers 1`` and ``--workers 2`` (chunk phase
  only, and end to end with the shot-level lights step and the stitch), and their ratio;
- the fixed overhead of one chunk as a farm task pays it: a fresh ``usdgs process`` process
  for a one-frame chunk (interpreter start, imports, numba cache load, stage open, static
  read, save, sidecar) minus the steady per-frame compute time, with a warm numba cache;
- the same overhead split: interpreter + imports, first-frame extra (numba cache load).

Every run's stitched output is compared with nothing here (tests/test_farm_clips.py checks
the values); numba threads are 1 per worker process (NUMBA_NUM_THREADS=1) so the two runs
differ only in the number of processes.
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

ROOT = Path(__file__).resolve().parents[1]


def _cli(args, env):
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "usd_gs.cli", *args], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if res.returncode:
        raise SystemExit(f"usdgs {' '.join(args)} failed:\n{res.stderr}")
    return wall, res.stdout


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stage", default=str(ROOT / "stages" / "demo.usda"))
    ap.add_argument("--frames", default="1-8")
    ap.add_argument("--chunk-size", type=int, default=2)
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args()
    if not Path(a.stage).is_file():
        raise SystemExit(f"{a.stage}: missing; run 'usdgs demo make' first")
    env = dict(os.environ, NUMBA_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    tmp = Path(tempfile.mkdtemp(prefix="bench_farm_"))
    fig = {"stage": a.stage, "frames": a.frames, "chunk_size": a.chunk_size, "cpus": os.cpu_count()}
    try:
        # warm the numba cache (and the OS file cache) once
        _cli(["process", a.stage, "--frames", a.frames.split("-")[0], "-o", str(tmp / "warm.usdc"), "-q"], env)
        runs = {}
        for workers in (1, 2):
            out = tmp / f"w{workers}.usdc"
            wall, stdout = _cli(["process", a.stage, "--frames", a.frames, "--chunk-size", str(a.chunk_size),
                                 "--workers", str(workers), "--clips-dir", str(tmp / f"clips{workers}"),
                                 "-o", str(out), "--json"], env)
            d = json.loads(stdout)
            n = d["frames"]["count"]
            runs[workers] = {"wall_s": round(wall, 2), "chunk_phase_s": d["timings_s"]["chunks"],
                             "frames_per_s_chunks": round(n / d["timings_s"]["chunks"], 3),
                             "frames_per_s_end_to_end": round(n / wall, 3),
                             "shot_step_s": d["timings_s"]["shot"], "assemble_s": d["timings_s"]["assemble"],
                             "chunk_s": d["chunk_seconds"]}
            print(f"{workers} worker(s): {n} frames, chunk phase {d['timings_s']['chunks']:.2f} s "
                  f"({runs[workers]['frames_per_s_chunks']:.3f} frames/s), end to end {wall:.2f} s "
                  f"({runs[workers]['frames_per_s_end_to_end']:.3f} frames/s); shot step "
                  f"{d['timings_s']['shot']:.2f} s, assemble {d['timings_s']['assemble']:.2f} s")
        fig["runs"] = runs
        fig["speedup_chunks"] = round(runs[2]["frames_per_s_chunks"] / runs[1]["frames_per_s_chunks"], 3)
        fig["speedup_end_to_end"] = round(runs[2]["frames_per_s_end_to_end"] / runs[1]["frames_per_s_end_to_end"], 3)
        print(f"2 vs 1 worker: {fig['speedup_chunks']:.2f}x (chunk phase), "
              f"{fig['speedup_end_to_end']:.2f}x (end to end)")

        # one chunk as a farm task: fresh process, warm numba cache
        first = float(a.frames.split("-")[0])
        t_imp, _ = _cli(["--version"], env)
        code = "import usd_gs.pipeline.shot, usd_gs.farm.executor, pxr.Usd, numba_kernels  # noqa"
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], env=env, check=True)
        t_imports = time.perf_counter() - t
        wall, stdout = _cli(["process", a.stage, "--frames", f"{first:g}", "--chunk-size", "1", "--clips-dir",
                             str(tmp / "one"), "-o", str(tmp / "one.usdc"), "--json"], env)
        side = json.loads((tmp / "one" / f"chunk_{int(first):04d}_{int(first):04d}.json").read_text())
        # steady per-frame compute: single in-process run over the frames, per frame after the first
        _, s1 = _cli(["process", a.stage, "--frames", f"{first:g}", "-o", str(tmp / "s1.usdc"), "--json"], env)
        _, s3 = _cli(["process", a.stage, "--frames", f"{first:g}-{first + 2:g}", "-o", str(tmp / "s3.usdc"), "--json"],
                     env)
        f1 = json.loads(s1)["timings_s"]["frames"]
        f3 = json.loads(s3)["timings_s"]["frames"]
        steady = (f3 - f1) / 2
        fig["overhead"] = {"fresh_process_one_frame_chunk_s": round(wall, 3), "steady_frame_s": round(steady, 3),
                           "per_chunk_overhead_s": round(wall - steady, 3),
                           "interpreter_and_imports_s": round(t_imports, 3), "cli_start_s": round(t_imp, 3),
                           "first_frame_extra_s": round(f1 - steady, 3),
                           "chunk_in_worker_s": side["seconds"]}
        o = fig["overhead"]
        print(f"one-frame chunk in a fresh process: {wall:.2f} s; steady frame {steady:.2f} s -> fixed overhead "
              f"{o['per_chunk_overhead_s']:.2f} s per chunk (interpreter+imports {t_imports:.2f} s, first-frame "
              f"extra incl. numba cache load {o['first_frame_extra_s']:.2f} s)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if a.json:
        Path(a.json).write_text(json.dumps(fig, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
