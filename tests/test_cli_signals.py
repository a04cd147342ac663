"""usd_gs.cli signal handling: SIGTERM / SIGINT raised as exceptions in the main thread, but never
inside a module import (an importer may swallow the exception: USD's Tf.PreparePythonModule prints
it and goes on with a half-loaded module); there they wait until the import is done."""

from __future__ import annotations

import signal
import sys
import types

import pytest

from usd_gs import cli


def _frame(filename: str, back=None):
    return types.SimpleNamespace(f_code=types.SimpleNamespace(co_filename=filename), f_back=back)


IMPORTING = _frame("/pxr/Tf/__init__.py", _frame("<frozen importlib._bootstrap>", _frame("/usd_gs/cli/io.py")))
RUNNING = _frame("/usd_gs/cli/io.py", _frame("/usd_gs/cli/__init__.py"))


@pytest.mark.parametrize("signum, exc", [(signal.SIGTERM, cli.Terminated), (signal.SIGINT, KeyboardInterrupt)])
def test_signal_outside_an_import_raises_at_once(signum, exc):
    with pytest.raises(exc):
        cli._on_signal(signum, RUNNING)


def test_signal_inside_an_import_waits_for_it(monkeypatch):
    timers = []
    monkeypatch.setattr(signal, "setitimer", lambda which, seconds: timers.append(seconds))
    cli._PENDING.clear()
    cli._on_signal(signal.SIGTERM, IMPORTING)  # deferred: no exception inside the import
    assert cli._PENDING == [signal.SIGTERM] and timers == [cli._RECHECK_S]
    cli._on_recheck(signal.SIGALRM, IMPORTING)  # still importing: checked again later
    assert timers == [cli._RECHECK_S] * 2
    with pytest.raises(cli.Terminated):
        cli._on_recheck(signal.SIGALRM, RUNNING)
    assert not cli._PENDING
    cli._on_recheck(signal.SIGALRM, RUNNING)  # nothing pending: nothing raised


def test_handlers_are_put_back():
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGALRM)}
    previous = cli._install_signal_handlers()
    assert signal.getsignal(signal.SIGTERM) is cli._on_signal and signal.getsignal(signal.SIGALRM) is cli._on_recheck
    cli._restore_signals(previous)
    assert {s: signal.getsignal(s) for s in before} == before


def test_real_frames_of_an_import_are_recognised():
    seen = []

    class Finder:  # runs inside the import machinery, as a module's own code would
        def find_spec(self, name, path=None, target=None):
            if name == "usdgs_signal_probe":
                seen.append(cli._in_import(sys._getframe()))
            return None

    sys.meta_path.insert(0, Finder())
    try:
        with pytest.raises(ModuleNotFoundError):
            __import__("usdgs_signal_probe")
    finally:
        sys.meta_path.pop(0)
    assert seen == [True] and not cli._in_import(sys._getframe())


def test_a_closed_output_pipe_ends_quietly(tmp_path, monkeypatch, capsys):
    """``usdgs inspect shot.usda | head``: the reader goes away; exit 141 (as SIGPIPE would give)
    with nothing on stderr, not an internal error."""
    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    stage = new_stage()
    write_gaussian_prim(stage, "/World/G", random_gaussians(5, 0, seed=1))
    save_stage_atomic(stage, tmp_path / "s.usdc")

    class ClosedPipe:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert cli.main(["inspect", str(tmp_path / "s.usdc")]) == 141
    assert capsys.readouterr().err == ""
