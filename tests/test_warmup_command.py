"""``usdgs warmup``: after it has run in an empty numba cache, the main job compiles nothing.

The slow test of this file (``test_process_after_warmup_compiles_nothing``) compiles every kernel
once, in a fresh ``NUMBA_CACHE_DIR``: about 30-40 s of compilation on two cores.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from usd_gs.cli import main

# Runs a command in-process with a listener on numba's compile events (fired on cache misses only)
# and prints, one per line, "compiled NAME" for every top-level compilation, then "hits N": the
# number of kernel signatures loaded from the on-disk cache.
_COUNT_COMPILES = textwrap.dedent("""
    import sys
    from numba.core import event
    depth = [0]
    class L(event.Listener):
        def on_start(self, ev):
            depth[0] += 1
        def on_end(self, ev):
            depth[0] -= 1
            if depth[0] == 0:
                fn = getattr(ev.data.get("dispatcher"), "py_func", None)
                print("compiled", f"{fn.__module__}.{fn.__qualname__}" if fn else "?")
    event.register("numba:compile", L())
    from usd_gs.cli import main
    rc = main(sys.argv[1:])
    import gc
    from numba.core.registry import CPUDispatcher
    hits = sum(sum(d._cache_hits.values()) for d in gc.get_objects() if isinstance(d, CPUDispatcher))
    print("hits", hits)
    sys.exit(rc)
""")


def _cache_files(folder):
    """{relative path: (size, mtime_ns)} of numba's index (.nbi) and data (.nbc) files."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.suffix in (".nbi", ".nbc")}


def test_process_after_warmup_compiles_nothing(quick_demo, tmp_path):
    """The one slow test: ``usdgs warmup`` into an empty cache, then ``usdgs process`` on the quick
    demo (estimated point lights, a skinned avatar, bricks) and ``usdgs render`` of its output in
    other processes with the same cache: no compilation, no cache file written."""
    cache = tmp_path / "nbcache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    env.pop("USDGS_JIT_WARMUP", None)
    r = subprocess.run([sys.executable, "-m", "usd_gs.cli", "warmup", "--jobs", "2"], capture_output=True, text=True,
                       env=env, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert str(cache) in r.stdout and "kernel signature(s) compiled" in r.stdout, r.stdout
    before = _cache_files(cache)
    assert sum(k.endswith(".nbc") for k in before) > 40, sorted(before)  # one data file per kernel signature

    out = tmp_path / "demo.lit.usdc"
    for argv in (["process", str(quick_demo), "-o", str(out), "--frames", "1-2", "-q"],
                 ["render", str(out), "-o", str(tmp_path / "f_####.png"), "--frames", "1", "--width", "48", "-q"]):
        r = subprocess.run([sys.executable, "-c", _COUNT_COMPILES, *argv], capture_output=True, text=True, env=env,
                           timeout=600)
        assert r.returncode == 0, r.stdout + r.stderr
        lines = r.stdout.split("\n")
        compiled = [ln.split(" ", 1)[1] for ln in lines if ln.startswith("compiled ")]
        hits = int(next(ln.split()[1] for ln in lines if ln.startswith("hits ")))
        assert compiled == [], (argv[0], compiled)
        assert hits >= (30 if argv[0] == "process" else 2), (argv[0], hits)  # the kernels did come from the cache
    assert _cache_files(cache) == before  # nothing new or rewritten


def test_jobs_must_be_positive(capsys):
    assert main(["warmup", "--jobs", "0"]) == 2
    assert "--jobs must be >= 1" in capsys.readouterr().err


def test_schedule_runs_every_group_after_its_dependencies():
    from usd_gs.cli.warmup import AFTER, ORDER
    from usd_gs.pipeline.machine_warmup import GROUPS as ALL_GROUPS

    assert sorted(ORDER) == sorted(ALL_GROUPS)
    for g, deps in AFTER.items():
        assert all(ORDER.index(d) < ORDER.index(g) for d in deps), g
    assert ORDER[-1] == "process" and set(AFTER["process"]) == set(ORDER) - {"process"}
