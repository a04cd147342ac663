"""Farm-run throughput and per-chunk overhead on the demo stage.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_farm.py [--stage stages/demo.usda] [--frames 1-8] [--chunk-size 2]

Prints (and writes as JSON to --json FILE):
- frames/s of ``usdgs process --chunk-size N --workers 1`` and ``--workers 2`` (chunk phase
  only, and end to end with the shot-level lights step and the stitch), and their ratio;
- the fixed overhead of one chunk as a farm task pays it: a fresh ``usdgs process`` process
  for a one-frame chunk (interpreter start, imports, numba cache load, stage open, static
  read, save, sidecar) minus the steady per-frame compute time, with a warm numba cache;
- the same overhead split: interpreter + imports, first-frame extra (numba cache load);
- the shot cache (``usd_gs.pipeline.shot_cache``): a farm task as a fresh process on the lights
  layer (``usdgs lights``, then ``usdgs process LIGHTS --lights stage --frames F --chunk-size 1``),
  a later frame's one-frame chunk with the cache file that the first chunk wrote and without it,
  alternating ``--cache-repeats`` times (same code, same run).

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


def _shot_cache_ab(a, tmp: Path, env: dict) -> dict:
    """Seconds of a one-frame farm task at a later frame in a fresh process, with and without the
    shot cache file (module docstring); the chunk's own seconds from its manifest entry too."""
    first, last = (float(v) for v in a.frames.split("-"))
    later = float(int(first + (last - first) // 2))
    lights = tmp / "shot.lights.usda"
    _cli(["lights", a.stage, "-o", str(lights), "--frames", a.frames, "-q"], env)

    def task(frame: float, folder: Path):
        folder.mkdir(exist_ok=True)
        wall, _ = _cli(["process", str(lights), "--lights", "stage", "--frames", f"{frame:g}", "--chunk-size", "1",
                        "--clips-dir", str(folder), "-o", str(folder / "task.usdc"), "-q"], env)
        side = json.loads((folder / f"chunk_{int(frame):04d}_{int(frame):04d}.json").read_text())
        return wall, side["seconds"]

    task(first, tmp / "cache_first")  # writes the shot cache
    cache = sorted((tmp / "cache_first").glob("shot_cache_*.npz"))
    if len(cache) != 1:
        raise SystemExit(f"expected one shot cache file in {tmp / 'cache_first'}, found {len(cache)}")
    rows = {"with": [], "without": []}
    for r in range(a.cache_repeats):
        for kind in ("with", "without"):
            folder = tmp / f"cache_{kind}_{r}"
            folder.mkdir()
            if kind == "with":
                shutil.copy(cache[0], folder / cache[0].name)
            rows[kind].append(task(later, folder))
    med = {k: sorted(w for w, _ in v)[len(v) // 2] for k, v in rows.items()}
    med_chunk = {k: sorted(c for _, c in v)[len(v) // 2] for k, v in rows.items()}
    out = {"frame": later, "cache_bytes": cache[0].stat().st_size,
           "task_wall_s": {k: [round(w, 3) for w, _ in v] for k, v in rows.items()},
           "chunk_s": {k: [round(c, 3) for _, c in v] for k, v in rows.items()},
           "median_saving_s": round(med["without"] - med["with"], 3),
           "median_chunk_saving_s": round(med_chunk["without"] - med_chunk["with"], 3)}
    print(f"shot cache ({cache[0].stat().st_size / 1e6:.1f} MB): one-frame task at frame {later:g}, fresh process, "
          f"median of {a.cache_repeats}: {med['with']:.2f} s with the cache, {med['without']:.2f} s without "
          f"(chunk alone {med_chunk['with']:.2f} / {med_chunk['without']:.2f} s)")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stage", default=str(ROOT / "stages" / "demo.usda"))
    ap.add_argument("--frames", default="1-8")
    ap.add_argument("--chunk-size", type=int, default=2)
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--cache-repeats", type=int, default=3, help="rounds of the shot-cache comparison")
    ap.add_argument("--only-cache", action="store_true", help="run the shot-cache comparison only")
    a = ap.parse_args()
    if not Path(a.stage).is_file():
        raise SystemExit(f"{a.stage}: missing; run 'usdgs demo make' first")
    env = dict(os.environ, NUMBA_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    tmp = Path(tempfile.mkdtemp(prefix="bench_farm_"))
    fig = {"stage": a.stage, "frames": a.frames, "chunk_size": a.chunk_size, "cpus": os.cpu_count()}
    try:
        # warm the numba cache (and the OS file cache) once
        _cli(["process", a.stage, "--frames", a.frames.split("-")[0], "-o", str(tmp / "warm.usdc"), "-q"], env)
        fig["shot_cache"] = _shot_cache_ab(a, tmp, env)
        if not a.only_cache:
            _farm_runs(a, tmp, env, fig)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if a.json:
        Path(a.json).write_text(json.dumps(fig, indent=2) + "\n")
    return 0


def _farm_runs(a, tmp: Path, env: dict, fig: dict) -> None:
    """The throughput of 1 and 2 workers and the fixed overhead of one chunk (module docstring)."""
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


if __name__ == "__main__":
    sys.exit(main())
