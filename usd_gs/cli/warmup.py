"""``usdgs warmup``: compile every numba kernel the commands use, once per machine (install step).

The kernels are ``@njit(cache=True)``: compiled on first use and kept in numba's on-disk cache
(``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside the installed ``numba_kernels``
sources when writable). This command fills that cache by running the warm-up groups of
``usd_gs.pipeline.machine_warmup`` (``GROUPS``: the main job's relighting, shadow maps, refined
sampling, light estimation, UsdSkel skinning, DistantLight and SphereLight runs, the preview
renders of ``usdgs render``, and last a whole ``usdgs process`` of a tiny generated shot that
compiles whatever the others left) in ``--jobs`` processes at once. Each group runs in a fresh
``python -P -m usd_gs.pipeline.jit_warmup GROUP`` process that reports the kernels it compiled
(cache misses); a group waits for the groups whose kernels it also calls (:data:`AFTER`), so that
two processes never compile the same kernel. ``usdgs import``, ``export``, ``inspect`` and
``validate`` call no numba kernel.
"""

from __future__ import annotations

import os
import sys
import time

#: the groups in the order they are started (the longest compile first)
ORDER = ("relight", "skin", "shadows", "refine", "author", "estimate", "directional", "render", "process")
#: groups that call kernels another group compiles: they start once those are finished
AFTER = {
    "estimate": ("relight",),  # the emitters' visibility renders use the probe rasteriser
    "directional": ("relight", "shadows", "refine", "skin", "author"),  # whole runs
    "render": ("relight", "shadows", "refine", "skin", "estimate", "directional"),
    "process": ("relight", "shadows", "refine", "skin", "author", "estimate", "directional", "render"),
}


def cache_location() -> str:
    """The folder numba caches the kernels of ``numba_kernels`` in, for this process's environment."""
    from numba_kernels import rasterize

    try:
        return str(rasterize._blend._cache.cache_path)
    except AttributeError:  # pragma: no cover - numba internals changed
        return os.environ.get("NUMBA_CACHE_DIR", "(numba's default cache folder)")


def host_cpu() -> str:
    """The CPU name numba compiles for (part of every cache entry's key)."""
    import llvmlite.binding as ll
    from numba.core import config

    return config.CPU_NAME or ll.get_host_cpu_name()


def run_groups(jobs: int, say=None) -> list[dict]:
    """Run every group of :data:`ORDER` in its own process, at most ``jobs`` at a time, each
    after the groups :data:`AFTER` lists; returns one report per group (``group``, ``compiled``
    kernel names, ``compile_s``, ``wall_s``). ``say(line)`` is called as each group ends.
    Raises ``RuntimeError`` with the process's last output lines when a group fails."""
    import json
    import shutil
    import subprocess
    import tempfile
    from pathlib import Path

    from usd_gs.pipeline import jit_warmup

    folder = Path(tempfile.mkdtemp(prefix="usdgs_warmup_"))
    package = jit_warmup._package_dir()
    # the groups must compile this process's copy of the package (a checkout run with `python -m`
    # from its root, or the installed one): its folder's parent goes first on the children's path
    path = os.pathsep.join([str(Path(package).parent)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    env = dict(os.environ, NUMBA_NUM_THREADS="1", USDGS_JIT_WARMUP="0", USDGS_JIT_WARMUP_PACKAGE=package,
               PYTHONPATH=path)
    pending, running, done, reports = list(ORDER), {}, set(), []
    try:
        while pending or running:
            ready = [g for g in pending if all(d in done for d in AFTER.get(g, ()))]
            while ready and len(running) < jobs:
                g = ready.pop(0)
                pending.remove(g)
                log = open(folder / f"{g}.log", "wb")  # noqa: SIM115 - closed when the process ends
                # -P: the installed package, not a checkout in the current directory (jit_warmup.start)
                proc = subprocess.Popen([sys.executable, "-P", "-m", "usd_gs.pipeline.machine_warmup", g],
                                        env=dict(env, USDGS_JIT_WARMUP_REPORT=str(folder / f"{g}.json")),
                                        stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
                running[g] = (proc, log)
            time.sleep(0.05)
            for g, (proc, log) in list(running.items()):
                if proc.poll() is None:
                    continue
                log.close()
                del running[g]
                if proc.returncode != 0:
                    tail = (folder / f"{g}.log").read_text(errors="replace").strip().splitlines()[-8:]
                    raise RuntimeError(f"warm-up group '{g}' failed (exit {proc.returncode}): " + " | ".join(tail))
                rep = json.loads((folder / f"{g}.json").read_text())
                rep["group"] = g
                reports.append(rep)
                done.add(g)
                if say:
                    say(report_line(rep))
    finally:
        for proc, log in running.values():
            jit_warmup.stop(proc)
            log.close()
        shutil.rmtree(folder, ignore_errors=True)
    return reports


def report_line(rep: dict) -> str:
    n = len(rep["compiled"])
    what = f"{n:3d} kernel signature(s) compiled in {rep['compile_s']:6.1f} s" if n else "  nothing to compile (cached)"
    return f"  {rep['group']:<12}{what}, {rep['wall_s']:6.1f} s in all"


def cmd_warmup(args) -> int:
    from usd_gs.errors import UserError

    if args.jobs < 1:
        raise UserError(f"--jobs must be >= 1, got {args.jobs}")
    say = (lambda *a: None) if args.quiet else (lambda line: print(line, flush=True))
    t0 = time.perf_counter()
    where = cache_location()
    say(f"usdgs warmup: compiling the numba kernels into {where} (CPU {host_cpu()}, {args.jobs} job(s))")
    try:
        reports = run_groups(args.jobs, say)
    except RuntimeError as exc:
        print(f"usdgs warmup: internal error: {exc}", file=sys.stderr)
        return 1
    names = sorted({k for r in reports for k in r["compiled"]})
    n = sum(len(r["compiled"]) for r in reports)
    if args.verbose and names:
        say("compiled: " + ", ".join(names))
    say(f"done in {time.perf_counter() - t0:.1f} s: {n} kernel signature(s) compiled" if n else
        f"done in {time.perf_counter() - t0:.1f} s: the cache was already warm, nothing compiled")
    return 0


def register_warmup(sub, formatter):
    p = sub.add_parser(
        "warmup", formatter_class=formatter, help="compile the numba kernels once (install step, farm machines)",
        description="Compile every numba kernel that 'usdgs process', 'lights', 'render' and the farm commands use, "
                    "for the argument types they use, into numba's on-disk cache, so that the first real run "
                    "loads them instead of compiling them. Run it once after 'pip "
                    "install' and on each farm machine type (or once into a shared NUMBA_CACHE_DIR). Tiny "
                    "generated shots are processed in --jobs parallel processes; nothing is written outside the "
                    "cache and a temporary folder. Re-running it on a warm cache compiles nothing.",
        epilog="cache: NUMBA_CACHE_DIR when set, else __pycache__ beside the installed numba_kernels sources (when "
               "writable). numba keys each entry by the numba version, the source file's contents, the function's "
               "bytecode, the argument types and the CPU (name and features), so machines of different CPU types "
               "may share one folder without loading each other's code; the folder must be writable (numba ignores a "
               "read-only one and compiles).")
    p.add_argument("--jobs", "-j", type=int, default=max(1, min(4, os.cpu_count() or 1)),
                   help="warm-up processes at once")
    p.add_argument("-v", "--verbose", action="store_true", help="also list the kernels compiled")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_warmup)


REGISTRARS = (register_warmup,)
