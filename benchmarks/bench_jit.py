"""numba compile time of a ``usdgs`` command, per kernel (not a test).

Runs the command in this process with an empty numba cache (a fresh temporary
``NUMBA_CACHE_DIR`` unless one is given) and records every numba compilation through
numba's event API. Prints the command's wall time, the top-level compile time (what the
run waited for) and, per dispatcher, the inclusive seconds (a caller includes the callees
compiled inside it), the exclusive seconds and the number of compilations (``x2`` and more:
several type specialisations of one kernel, usually avoidable).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_jit.py process stages/demo.usda --frames 1-2 -o /tmp/x.usdc -q
    PYTHONPATH=. .venv/bin/python benchmarks/bench_jit.py --top 60 process stages/demo.usda ...
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from collections import Counter, defaultdict


def main(argv: list[str]) -> int:
    top = 40
    if argv[:1] == ["--top"]:
        top, argv = int(argv[1]), argv[2:]
    if "NUMBA_CACHE_DIR" not in os.environ:  # must be set before numba is imported
        os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="usdgs_jit_")
    from numba.core import event

    incl: dict[str, float] = defaultdict(float)
    excl: dict[str, float] = defaultdict(float)
    count: Counter = Counter()
    total = [0.0]

    class _Listener(event.Listener):
        def __init__(self):
            self.stack: list[list[float]] = []

        def on_start(self, ev):
            self.stack.append([time.perf_counter(), 0.0])

        def on_end(self, ev):
            t0, child = self.stack.pop()
            dt = time.perf_counter() - t0
            disp = ev.data.get("dispatcher")
            fn = getattr(disp, "py_func", None)
            name = f"{fn.__module__}.{fn.__qualname__}" if fn is not None else str(disp)
            incl[name] += dt
            excl[name] += dt - child
            count[name] += 1
            if self.stack:
                self.stack[-1][1] += dt
            else:
                total[0] += dt

    event.register("numba:compile", _Listener())
    from usd_gs.cli import main as cli_main

    t = time.perf_counter()
    rc = 0
    try:
        rc = cli_main(argv) or 0
    except SystemExit as exc:  # argparse / CLI exits
        rc = int(exc.code or 0)
    wall = time.perf_counter() - t
    print(f"cache {os.environ['NUMBA_CACHE_DIR']}  wall {wall:.2f} s  top-level compile {total[0]:.2f} s")
    print("  incl s   excl s  count  dispatcher")
    for name, v in sorted(incl.items(), key=lambda kv: -kv[1])[:top]:
        print(f"{v:8.2f} {excl[name]:8.2f}  x{count[name]:<4d} {name}")
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
