"""Issue #17 items 1 and 11: every file goes through the atomic writer, SIGTERM is Ctrl-C, and
temp files of killed runs are removed by the next run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hardening_util import leftovers, tiny_shot
from package_process import child_env, python

from usd_gs.cli import main


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return tiny_shot(tmp_path_factory.mktemp("shot") / "shot.usda")


def _interrupt_after_partial_write(monkeypatch, module, name):
    """Make ``module.name(path, ...)`` write half a file at ``path`` and then raise Ctrl-C."""

    def broken(path, *a, **k):
        Path(path).write_bytes(b"\x89PNG partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(module, name, broken)


def test_render_png_interrupted_keeps_previous(shot, tmp_path, monkeypatch, capsys):
    out = tmp_path / "r.png"
    assert main(["render", str(shot), "-o", str(out), "--width", "48", "-q"]) == 0
    before = out.read_bytes()
    from PIL import Image

    def broken_save(self, fp, *a, **k):
        Path(fp).write_bytes(b"\x89PNG partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(Image.Image, "save", broken_save)
    assert main(["render", str(shot), "-o", str(out), "--width", "64", "-q"]) == 130
    assert out.read_bytes() == before
    assert leftovers(tmp_path) == []


def test_render_exr_interrupted_keeps_previous(shot, tmp_path, monkeypatch):
    import OpenEXR

    out = tmp_path / "r.exr"
    assert main(["render", str(shot), "-o", str(out), "--width", "48", "--exr", "-q"]) == 0
    before = out.read_bytes()
    real = OpenEXR.File

    class Broken:
        def __init__(self, *a, **k):
            self.f = real(*a, **k)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, path):
            Path(path).write_bytes(b"v/1\x01 partial")
            raise KeyboardInterrupt

    monkeypatch.setattr(OpenEXR, "File", Broken)
    assert main(["render", str(shot), "-o", str(out), "--width", "64", "--exr", "-q"]) == 130
    assert out.read_bytes() == before
    assert leftovers(tmp_path) == []


def test_probe_exr_and_report_writes_are_atomic(tmp_path, monkeypatch):
    """The library writers (probe textures, PNGs, reports) leave the previous file on a failure."""
    from usd_gs.io.envmap import write_exr
    from usd_gs.render.rasterize import write_png

    png, exr = tmp_path / "a.png", tmp_path / "a.exr"
    write_png(png, np.zeros((4, 4, 3), np.float32))
    write_exr(exr, np.zeros((4, 8, 3), np.float32))
    old_png, old_exr = png.read_bytes(), exr.read_bytes()
    with pytest.raises(ValueError):
        write_png(png, np.full((4, 4, 3), np.nan, np.float32)[None])  # a bad shape fails before writing
    from PIL import Image

    monkeypatch.setattr(Image.Image, "save", lambda self, fp, *a, **k: (Path(fp).write_bytes(b"x"), 1 / 0))
    with pytest.raises(ZeroDivisionError):
        write_png(png, np.ones((4, 4, 3), np.float32))
    assert png.read_bytes() == old_png and exr.read_bytes() == old_exr
    assert leftovers(tmp_path) == []


_SIGTERM_CHILD = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from PIL import Image
from usd_gs.cli import main

def slow_save(self, fp, *a, **k):
    Path(fp).write_bytes(b"partial")
    os.kill(os.getpid(), signal.SIGTERM)  # the scheduler's kill, mid-write
    raise SystemExit("SIGTERM was not handled")

Image.Image.save = slow_save
sys.exit(main(["render", {shot!r}, "-o", {out!r}, "--width", "48", "-q"]))
"""


def test_sigterm_is_handled_like_ctrl_c(shot, tmp_path):
    out = tmp_path / "r.png"
    assert main(["render", str(shot), "-o", str(out), "--width", "48", "-q"]) == 0
    before = out.read_bytes()
    code = _SIGTERM_CHILD.format(tests=str(Path(__file__).parent), shot=str(shot), out=str(out))
    r = subprocess.run(python("-c", code), capture_output=True, text=True, timeout=120, env=child_env())
    assert r.returncode == 143, r.stderr
    assert "terminated" in r.stderr.splitlines()[-1]
    assert out.read_bytes() == before
    assert leftovers(tmp_path) == []


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temp_files_of_dead_processes_removed(shot, tmp_path):
    from usd_gs.io.atomic import host_tag

    out = tmp_path / "out.usdc"
    dead = _dead_pid()
    tag = f"tmp{dead}-{host_tag()}"
    stale_file = tmp_path / f".out.{tag}.abc123.usdc"
    stale_file.write_bytes(b"PXR-USDC partial" * 1000)
    stale_dir = tmp_path / f".out_probes.{tag}"
    stale_dir.mkdir()
    (stale_dir / "Avatar.0001.exr").write_bytes(b"x")
    old_style = tmp_path / f".out_probes.tmp{dead}"  # what today's version leaves
    old_style.mkdir()
    live = tmp_path / f".out.tmp{os.getppid()}-{host_tag()}.zzz.usdc"  # a live process's: kept
    live.write_bytes(b"busy")
    user_file = tmp_path / ".out.tmp.notes"  # not ours: kept
    user_file.write_text("mine")
    assert main(["process", str(shot), "-o", str(out), "--avatar", "/World/Avatar", "-q"]) == 0
    assert not stale_file.exists() and not stale_dir.exists() and not old_style.exists()
    assert live.exists() and user_file.exists()
    assert leftovers(tmp_path) == sorted([live.name, user_file.name])


def test_an_interrupt_waits_until_the_temp_file_is_in_hand(tmp_path, monkeypatch):
    """A Ctrl-C right after the trial file of check_writable_folder, or atomic_output's temporary
    file, is created (before the code that removes it is armed) arrives once it is: nothing
    is left behind."""
    import os
    import signal
    import tempfile

    from usd_gs.io import atomic

    real = tempfile.mkstemp

    def mkstemp_then_ctrl_c(*args, **kwargs):
        out = real(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return out

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_ctrl_c)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own Ctrl-C
    try:
        with pytest.raises(KeyboardInterrupt):
            atomic.check_writable_folder(tmp_path, "test")
        assert list(tmp_path.iterdir()) == []
        with pytest.raises(KeyboardInterrupt):
            with atomic.atomic_output(tmp_path / "out.txt") as tmp:
                tmp.write_text("never")
        assert list(tmp_path.iterdir()) == []
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_signal_deferred_past_an_import_also_waits_until_the_temp_file_is_in_hand(tmp_path, monkeypatch):
    """usdgs raises a SIGTERM that landed inside a module import from its SIGALRM handler once the
    import is done (``usd_gs.cli._on_recheck``); when that SIGALRM comes right after atomic_output's
    temporary file is created, it is held like a SIGTERM: ``Terminated`` arrives once the file is
    in hand, and nothing is left behind."""
    import os
    import signal
    import tempfile

    from usd_gs import cli
    from usd_gs.io import atomic

    real = tempfile.mkstemp

    def mkstemp_then_deferred_sigterm(*args, **kwargs):
        out = real(*args, **kwargs)
        cli._PENDING[:] = [signal.SIGTERM]  # (as _on_signal leaves it for a SIGTERM inside an import)
        os.kill(os.getpid(), signal.SIGALRM)
        return out

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_deferred_sigterm)
    previous = cli._install_signal_handlers()
    try:
        with pytest.raises(cli.Terminated):
            with atomic.atomic_output(tmp_path / "out.usdc") as tmp:
                tmp.write_text("never")
        assert list(tmp_path.iterdir()) == [] and not cli._PENDING
    finally:
        cli._PENDING.clear()
        cli._restore_signals(previous)
