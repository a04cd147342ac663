"""The parallel JIT warm-up (usd_gs.pipeline.jit_warmup): it must fill exactly the cache entries that the
main job needs after light estimation, and only start when the numba cache is cold."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from package_process import PACKAGE_ROOT, child_env, python

from usd_gs.pipeline import jit_warmup

_SIGNATURE_DIFF = textwrap.dedent("""
    import importlib, pkgutil, sys
    import numba_kernels
    from numba.core.registry import CPUDispatcher

    def signatures():
        out = {}
        for m in pkgutil.iter_modules(numba_kernels.__path__):
            mod = importlib.import_module("numba_kernels." + m.name)
            for k, v in vars(mod).items():
                if isinstance(v, CPUDispatcher) and v.__module__ == mod.__name__:
                    out[m.name + "." + k] = set(map(str, v.signatures))
        return out

    from usd_gs.pipeline import jit_warmup
    jit_warmup.warm_up()
    before = signatures()
    from usd_gs.cli import main
    assert main(["process", sys.argv[1], "-o", sys.argv[2], "--frames", "1-2", "-q"]) == 0
    after = signatures()
    print(" ".join(sorted(k for k in after if after[k] - before.get(k, set()))))
""")


def test_warm_up_types_match_the_main_job(quick_demo, tmp_path):
    """In a fresh process, after warm_up() the main job dispatches no kernel signature the
    warm-up did not already create, except what it runs first itself: the reading of the prims
    (the transform of a moved prim, the skinning of the avatar), the static part's checked copy
    and the light estimation (with its emitters' exact visibility, dgsm_exact)."""
    r = subprocess.run(python("-c", _SIGNATURE_DIFF, str(quick_demo), str(tmp_path / "o.usdc")),
                       capture_output=True, text=True, env=child_env(USDGS_JIT_WARMUP="0"), check=True)
    extra = set(r.stdout.split())
    assert extra, "the main job must at least add the light-estimation kernels"
    # (dgsm_model: dgsm_exact's callee, dispatched when dgsm_exact compiles rather than loads from the cache;
    # copy_finite: the static part's copy into the shot buffer, at the set-up)
    first = ("light_estimation", "grid_neighbours", "dgsm_exact", "dgsm_model", "skinning", "similarity",
             "copy_finite")
    assert all(k.split(".")[0] in first for k in extra), extra


def test_starts_only_on_a_cold_cache(tmp_path, monkeypatch):
    from usd_gs.render.rasterize import render_cube_faces
    from usd_gs.synthetic import random_gaussians

    render_cube_faces(random_gaussians(8, 0), (0.0, 0.0, 0.0), 8)  # compiles (and caches) the sentinel kernel
    assert not jit_warmup.cache_is_cold()
    assert jit_warmup.start() is None
    monkeypatch.setenv("USDGS_JIT_WARMUP", "0")
    assert jit_warmup.start() is None
    jit_warmup.stop(None)
    # an empty cache directory is cold
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "nbcache"))
    code = "from usd_gs.pipeline import jit_warmup; print(jit_warmup.cache_is_cold())"
    r = subprocess.run([sys.executable, "-c", code],
                       capture_output=True, text=True, env=env, check=True)
    assert r.stdout.strip() == "True"


def test_stop_ends_a_running_process():
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    jit_warmup.stop(proc)
    assert proc.poll() is not None


def test_warm_up_process_imports_the_main_process_package(tmp_path):
    """Launched from a directory holding another copy of the package (a checkout beside an
    installed one), the warm-up must not import that copy: -P keeps the current directory off
    sys.path, and a package mismatch makes it exit without compiling."""
    env = dict(os.environ, USDGS_JIT_WARMUP_PACKAGE=str(tmp_path / "elsewhere"), NUMBA_CACHE_DIR=str(tmp_path / "c"),
               PYTHONPATH=PACKAGE_ROOT)  # the copy this test imported
    r = subprocess.run([sys.executable, "-P", "-m", "usd_gs.pipeline.jit_warmup", "relight"],
                       capture_output=True, text=True,
                       env=env, cwd=tmp_path)
    assert r.returncode != 0 and "the main process runs" in r.stderr
    assert not (tmp_path / "c").exists() or not any((tmp_path / "c").rglob("*.nbi"))
