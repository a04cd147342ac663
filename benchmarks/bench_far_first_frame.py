"""The first frame of a shot with a large static scene far from the avatars against the demo's
(issue 16: "frame 1 of the far-scene variant within 1.2x of the demo's"), per phase, in rounds
that alternate the two shots (this host's load moves from minute to minute; not a test).

The far-scene shot is the demo plus a bricked block of 9x the room's Gaussians 40 m away
(``bench_process.make_large_shot``). Each run is a whole ``usdgs process --frames 1 --json``
process (warm numba cache); printed per run: the total and the phases of ``timings_s`` (stage
open, reading, light estimation, relighting, shadows with the probe renders, authoring) and the
child's peak resident memory; per round the far / demo ratio of the totals.

    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_far_first_frame.py [--rounds 3]
        [--threads T] [--workdir DIR] [--demo stages/demo.usda]

``--threads T``: ``NUMBA_NUM_THREADS`` for the runs (1: every phase's CPU time, no task beside it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
from pathlib import Path

from bench_process import make_large_shot, usdgs

PHASES = ("open", "read", "lights", "relight", "shadows", "write")


def first_frame(stage: Path, out: Path, threads: int | None) -> dict:
    """``timings_s`` of ``usdgs process stage --frames 1`` in a child process, plus its own peak
    resident memory (``peak_gb``, from ``os.wait4``'s ``ru_maxrss``, KiB on Linux)."""
    env = dict(os.environ) if threads is None else dict(os.environ, NUMBA_NUM_THREADS=str(threads))
    with tempfile.TemporaryFile() as fout, tempfile.TemporaryFile() as ferr:
        child = subprocess.Popen([usdgs(), "process", str(stage), "-o", str(out), "--frames", "1", "--json"],
                                 stdout=fout, stderr=ferr, env=env)
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)  # (reaped here: Popen must not wait again)
        fout.seek(0)
        ferr.seek(0)
        stdout, stderr = fout.read().decode(), ferr.read().decode()
    if child.returncode != 0:
        raise SystemExit(f"usdgs process {stage} failed ({child.returncode}): {stderr.strip()[-2000:]}")
    timings = dict(json.loads(stdout)["timings_s"])
    timings["peak_gb"] = usage.ru_maxrss * 1024 / 1e9
    return timings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--demo", default="stages/demo.usda")
    a = ap.parse_args()
    work = Path(a.workdir or tempfile.mkdtemp(prefix="bench_far_f1_"))
    work.mkdir(parents=True, exist_ok=True)
    demo = Path(a.demo).resolve()
    large = make_large_shot(demo, work)
    print(f"frame 1 only; threads {a.threads or 'default'}; seconds (timings_s) and peak resident memory")
    print(f"{'round':>5s} {'shot':6s} {'total':>6s} " + " ".join(f"{p:>8s}" for p in PHASES) + f" {'peak GB':>8s}")
    ratios = []
    for r in range(a.rounds):
        got = {}
        for name, stage in (("far", large), ("demo", demo)):
            t = got[name] = first_frame(stage, work / f"{name}.lit.usdc", a.threads)
            print(f"{r + 1:5d} {name:6s} {t['total']:6.2f} " + " ".join(f"{t.get(p, 0.0):8.2f}" for p in PHASES)
                  + f" {t['peak_gb']:8.2f}", flush=True)
        ratios.append(got["far"]["total"] / got["demo"]["total"])
        print(f"round {r + 1}: far / demo {ratios[-1]:.2f}x (target 1.2x)", flush=True)
    print("far / demo per round: " + " / ".join(f"{x:.2f}x" for x in ratios))


if __name__ == "__main__":
    main()
