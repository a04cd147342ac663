"""Where a cold-cache ``usdgs process`` spends its compile time (not a test).

Two measurements, each in a fresh numba cache (a new temporary ``NUMBA_CACHE_DIR``):

- ``timeline`` (default): runs the command in this process with the JIT warm-up on, as a user's
  first run does, and prints every top-level numba compilation of the main process (start s,
  duration s, kernel), how long the main process waited for the warm-up's marker and when the
  marker appeared, then the wall time;
- ``groups``: compiles each ``usd_gs.pipeline.jit_warmup`` group on its own in a fresh process with one
  thread (``NUMBA_NUM_THREADS=1``) and prints its total compile seconds and largest kernels.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_cold_start.py timeline process stages/demo.usda -o /tmp/x.usdc -q
    PYTHONPATH=. .venv/bin/python benchmarks/bench_cold_start.py groups
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


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["groups"]:
        sys.exit(groups())
    if args[:1] == ["timeline"]:
        args = args[1:]
    sys.exit(timeline(args or ["process", "stages/demo.usda", "-o", "/tmp/usdgs_cold.usdc", "-q"]))
