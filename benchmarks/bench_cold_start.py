"""Where a cold-cache ``usdgs process`` spends its compile time (not a test).

Two measurements, each in a fresh numba cache (a new temporary ``NUMBA_CACHE_DIR``):

- ``timeline`` (default): runs the command in this process with the JIT warm-up on, as a user's
  first run does, and prints every top-level numba compilation of the main process (start s,
  duration s, kernel), how long the main process waited for the warm-up's marker and when the
  marker appeared, then the wall time;
- ``groups``: compiles each ``usd_gs.pipeline.jit_warmup`` group on its own in a fresh process with one
  thread (``NUMBA_NUM_THREADS=1``) and prints its total compile seconds and largest kernels.

- ``install``: the install-step figure, back to back in one fresh cache: ``usdgs warmup`` (its
  own time), then the first ``usdgs process STAGE --frames 1-4`` after it, then the same command
  again (warm), each a fresh process; prints the three wall times and the ratio first / warm
  (``--cold`` first times the same command in another empty cache, without the warm-up).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_cold_start.py timeline process stages/demo.usda -o /tmp/x.usdc -q
    PYTHONPATH=. .venv/bin/python benchmarks/bench_cold_start.py groups
    PYTHONPATH=. .venv/bin/python benchmarks/bench_cold_start.py install [--cold] [--jobs N] [STAGE]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

_GROUP_SCRIPT = """
import sys, time
from numba.core import event
acc, stack = {}, []
class L(event.Listener):
    def on_start(self, ev): stack.append(time.perf_counter())
    def on_end(self, ev):
        t = time.perf_counter() - stack.pop()
        if not stack:
            fn = getattr(ev.data.get("dispatcher"), "py_func", None)
            acc[fn.__qualname__ if fn else "?"] = t
event.register("numba:compile", L())
from usd_gs.pipeline.jit_warmup import warm_up
warm_up((sys.argv[1],))
top = sorted(acc.items(), key=lambda kv: -kv[1])[:4]
print(f"{sys.argv[1]:<8} {sum(acc.values()):6.2f} s  " + ", ".join(f"{k} {v:.2f}" for k, v in top))
"""


def groups() -> int:
    from usd_gs.pipeline.jit_warmup import GROUPS

    print("compile seconds per warm-up group (fresh cache each, one thread):")
    for g in GROUPS:
        env = dict(os.environ, NUMBA_CACHE_DIR=tempfile.mkdtemp(prefix="usdgs_cold_"), NUMBA_NUM_THREADS="1")
        subprocess.run([sys.executable, "-c", _GROUP_SCRIPT, g], env=env, check=True)
    return 0


def timeline(argv: list[str]) -> int:
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="usdgs_cold_")  # before numba is imported
    from numba.core import event

    t0, wall0 = time.perf_counter(), time.time()
    stack: list[float] = []

    class _Listener(event.Listener):
        def on_start(self, ev):
            stack.append(time.perf_counter())

        def on_end(self, ev):
            start = stack.pop()
            if not stack:
                fn = getattr(ev.data.get("dispatcher"), "py_func", None)
                name = f"{fn.__module__}.{fn.__qualname__}" if fn is not None else "?"
                print(f"{start - t0:7.2f} {time.perf_counter() - start:6.2f}  {name}", flush=True)

    event.register("numba:compile", _Listener())
    from usd_gs.pipeline import jit_warmup

    wait = jit_warmup.WarmUp.wait

    def timed_wait(self, group):
        if group in self.done:
            return
        t = time.perf_counter()
        wait(self, group)
        marker = self.markers / group
        seen = f", marker at {marker.stat().st_mtime - wall0:.2f} s" if marker.exists() else ", no marker"
        print(f"{t - t0:7.2f} waited {time.perf_counter() - t:.2f} s for the warm-up's '{group}'{seen}", flush=True)

    jit_warmup.WarmUp.wait = timed_wait
    from usd_gs.cli import main as cli_main

    print("  start    dur  kernel (top-level compilations of the main process)")
    rc = cli_main(argv)
    print(f"{time.perf_counter() - t0:7.2f} end (exit {rc})")
    return rc


def _timed(argv: list[str], env: dict, show: bool = False) -> float:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "usd_gs.cli", *argv], env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed (exit {r.returncode}):\n{r.stdout}{r.stderr}")
    if show:
        print(r.stdout, end="", flush=True)
    return time.perf_counter() - t


def install(argv: list[str]) -> int:
    import shutil

    cold = "--cold" in argv
    argv = [a for a in argv if a != "--cold"]
    jobs = []
    if "--jobs" in argv:
        i = argv.index("--jobs")
        jobs = ["--jobs", argv[i + 1]]
        argv = argv[:i] + argv[i + 2:]
    stage = argv[0] if argv else "stages/demo.usda"
    out = tempfile.mkdtemp(prefix="usdgs_install_out_")
    run = ["process", stage, "-o", os.path.join(out, "demo.lit.usdc"), "--frames", "1-4", "-q"]
    base = {k: v for k, v in os.environ.items() if k not in ("USDGS_JIT_WARMUP", "NUMBA_NUM_THREADS")}
    caches = []
    try:
        if cold:
            caches.append(tempfile.mkdtemp(prefix="usdgs_cold_"))
            t_cold = _timed(run, dict(base, NUMBA_CACHE_DIR=caches[-1]))
        caches.append(tempfile.mkdtemp(prefix="usdgs_cold_"))
        env = dict(base, NUMBA_CACHE_DIR=caches[-1])
        t_warmup = _timed(["warmup", *jobs], env, show=True)  # its per-group report
        t_first = _timed(run, env)
        t_warm = _timed(run, env)
    finally:
        for c in caches:
            shutil.rmtree(c, ignore_errors=True)
        shutil.rmtree(out, ignore_errors=True)
    print(f"usdgs {' '.join(run[:2])} --frames 1-4, each a fresh process, fresh NUMBA_CACHE_DIR:")
    if cold:
        print(f"  cold (empty cache, no warm-up):   {t_cold:7.1f} s")
    print(f"  usdgs warmup {' '.join(jobs) or '(default jobs)'}:{'':<13}{t_warmup:7.1f} s")
    print(f"  first run after the warm-up:      {t_first:7.1f} s")
    print(f"  warm run (same cache, again):     {t_warm:7.1f} s")
    print(f"  first / warm = {t_first / t_warm:.2f}" + (f"; cold / warm = {t_cold / t_warm:.2f}" if cold else ""))
    return 0


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["install"]:
        sys.exit(install(args[1:]))
    if args[:1] == ["groups"]:
        sys.exit(groups())
    if args[:1] == ["timeline"]:
        args = args[1:]
    sys.exit(timeline(args or ["process", "stages/demo.usda", "-o", "/tmp/usdgs_cold.usdc", "-q"]))
