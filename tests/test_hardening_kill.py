"""Issue #17 kill tests: every writing command killed (SIGINT, SIGTERM, SIGKILL) at a random point
of a small run in a subprocess leaves its previous output intact (or a complete new one, the
same bytes) and, after the next run, no temporary file."""

from __future__ import annotations

import hashlib
import random
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from hardening_util import leftovers, tiny_shot
from package_process import child_env, python

from usd_gs.cli import main

SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM, "SIGKILL": signal.SIGKILL}
EXPECTED_RC = {"SIGINT": 130, "SIGTERM": 143, "SIGKILL": -9}

_CHILD = """
import sys
sys.path.insert(0, {tests!r})
import numpy, pxr.Usd  # noqa: F401  (imports done before 'ready': the kill lands in the command)
import signal
# a signal after the command returned is not the command's: main installs its SIGTERM handler and
# restores this one (ignore) when it returns; a Ctrl-C that lands after main returned is ignored too
signal.signal(signal.SIGTERM, signal.SIG_IGN)
from usd_gs.cli import main
print("ready", flush=True)
try:
    rc = main({argv!r})
except KeyboardInterrupt:  # main handles its own: this one came after its command had returned
    rc = 0
finally:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.exit(rc)
"""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("kill_inputs")
    shot = tiny_shot(d / "shot.usda", n_scene=800, n_avatar=150, frames=2)
    from usd_gs.io.ply import write_ply
    from usd_gs.synthetic import random_gaussians

    write_ply(d / "cap.ply", random_gaussians(8000, degree=3, seed=1))
    clips = d / "clips"
    assert main(["process", str(shot), "-o", str(d / "farm.usdc"), "--avatar", "/World/Avatar", "--chunk-size", "1",
                 "--clips-dir", str(clips), "-q"]) == 0
    return {"shot": shot, "ply": d / "cap.ply", "clips": clips}


def _commands(inp, out: Path) -> dict:
    return {
        "process": (["process", str(inp["shot"]), "-o", str(out / "o.usdc"), "--avatar", "/World/Avatar", "-q"],
                    ["o.usdc", "o_probes"]),
        "import": (["import", str(inp["ply"]), "-o", str(out / "cap.usdc"), "-q"], ["cap.usdc"]),
        "export": (["export", str(inp["shot"]), "-o", str(out / "x_####.ply"), "--frames", "1-2", "-q"],
                   ["x_0001.ply", "x_0002.ply"]),
        "render": (["render", str(inp["shot"]), "-o", str(out / "r_####.png"), "--frames", "1-2", "--width", "320",
                    "-q"], ["r_0001.png", "r_0002.png"]),
        "lights": (["lights", str(inp["shot"]), "-o", str(out / "lights.usda"), "--lights", "1", "-q"],
                   ["lights.usda"]),
        "assemble": (["assemble", str(inp["clips"]), "-o", str(out / "asm.usdc"), "-q"],
                     ["asm.usdc", "asm.topology.usdc", "asm.manifest.usdc"]),
        "demo make": (["demo", "make", "-o", str(out / "stages" / "demo.usda"), "--quick", "-q"],
                      ["stages/demo.usda", "stages/demo_data"]),
    }


def _digest(path: Path) -> dict:
    """{file: SHA-256} of a file or a folder's files; for USD crate files the hash of their content as
    text: the crate writer's byte layout differs between processes (token and path tables in hash
    order), so a finished re-run writes the same content, not always the same bytes."""
    from pxr import Sdf

    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    out = {}
    for p in files:
        if not p.exists():
            continue
        data = p.read_bytes()
        if p.suffix == ".usdc":
            layer = Sdf.Layer.OpenAsAnonymous(str(p))
            data = layer.ExportToString().encode() if layer is not None else data
        out[str(p)] = hashlib.sha256(data).hexdigest()
    return out


def _state(out: Path, names) -> dict:
    state = {}
    for n in names:
        state.update(_digest(out / n))
    return state


@pytest.fixture(scope="module")
def previous(inputs, tmp_path_factory):
    """command -> (folder holding its finished output, seconds the run took), made once."""
    cache = {}

    def get(command):
        if command not in cache:
            folder = tmp_path_factory.mktemp("prev")
            argv, _ = _commands(inputs, folder)[command]
            t0 = time.perf_counter()
            assert main(argv) == 0
            cache[command] = (folder, time.perf_counter() - t0)
        return cache[command]

    return get


@pytest.mark.parametrize("sig", list(SIGNALS))
@pytest.mark.parametrize("command", ["process", "import", "export", "render", "lights", "assemble", "demo make"])
def test_kill_leaves_previous_output(inputs, previous, tmp_path, command, sig):
    if command == "demo make":
        from usd_gs.demo.stage import locate_data_dir

        try:
            locate_data_dir(None)
        except Exception:  # noqa: BLE001 - no shared data here
            pytest.skip("demo make needs ../shared/data")
    argv, names = _commands(inputs, tmp_path)[command]
    prev, took = previous(command)
    shutil.copytree(prev, tmp_path, dirs_exist_ok=True)  # the previous output (same relative paths inside)
    before = {k.replace(str(prev), str(tmp_path)): v for k, v in _state(prev, names).items()}
    assert _state(tmp_path, names) == before
    assert before
    rng = random.Random(f"{command}-{sig}")
    code = _CHILD.format(tests=str(Path(__file__).parent), argv=argv)
    child = subprocess.Popen(python("-c", code), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=child_env(NUMBA_NUM_THREADS="1"))
    assert child.stdout.readline().strip() == "ready"
    time.sleep(rng.uniform(0.0, min(max(took, 0.05), 3.0)))
    child.send_signal(SIGNALS[sig])
    _, err = child.communicate(timeout=120)
    assert child.returncode in (0, EXPECTED_RC[sig]), err
    if child.returncode != 0 and sig != "SIGKILL":
        assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("usdgs")
    after = _state(tmp_path, names)
    assert after == before  # intact (a run that finished wrote the same bytes)
    if sig != "SIGKILL":
        assert leftovers(tmp_path) == []  # Ctrl-C and SIGTERM clean up at once
    assert main(argv) == 0  # the next run removes what a SIGKILL left
    assert leftovers(tmp_path) == []
    assert _state(tmp_path, names) == before
