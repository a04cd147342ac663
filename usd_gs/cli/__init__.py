"""The ``usdgs`` command line: argument parsing, dispatch and error reporting.

Exit codes: 0 success; 1 internal error (or, for ``validate``, problems found);
2 user error (bad input or options: a one-line message naming file, prim, attribute
and element; also an unwritable output, a full disk or a request too large for memory);
130 interrupted (Ctrl-C), 143 terminated (SIGTERM): no partial file is left either way.
``--debug`` prints the traceback of any error.

Each subcommand lives in its own module and registers itself through ``COMMANDS``;
heavy imports (pxr, numba) happen inside the handlers so ``usdgs --help`` and
``usdgs --version`` stay instant.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
import traceback

from usd_gs import __version__
from usd_gs.errors import UserError

DESCRIPTION = """\
usd-gs: consistent lighting and shadows for animated 3D Gaussian Splat avatars and
inserted objects inside captured 3DGS scenes, as a USD pipeline step.

Gaussians live in USD as UsdVol.ParticleField3DGaussianSplat prims. The tool reads a
stage, and writes its results to a separate layered output stage; the input is never
modified."""

EPILOG = """\
examples:
  usdgs import capture.ply -o capture.usdc --prim /World/Scene --role scene
  usdgs inspect shot.usda
  usdgs validate shot.usda
  usdgs export shot.usda --prim /World/Avatar --time 12 -o avatar_f12.ply

exit codes: 0 ok, 1 internal error or validation problems, 2 bad input or options"""


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Raw descriptions; appends ``(default: X)`` only where X says something (not None/False:
    those options state their effective default in their own help)."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


# Modules that define subcommands; each has ``REGISTRARS``: functions (subparsers, formatter).
# With the commands each registers: ``usdgs X ...`` builds the parser of X's module only (the
# other modules are not imported); ``usdgs`` and ``usdgs --help`` build them all. Kept in step
# with the registrars by tests/test_cli_parser.py.
COMMANDS_OF = {"io": ("import", "export", "inspect", "validate"), "demo": ("demo",), "process": ("process",),
               "render": ("render",), "farm": ("lights", "assemble"), "eval": ("eval",), "bench": ("bench",),
               "rig": ("rig",), "warmup": ("warmup",)}
COMMAND_MODULES = tuple(COMMANDS_OF)


#: Commands that run the pipeline's numerics: the console script sets the allocator up for a batch
#: run first (``usd_gs.pipeline.allocator``).
BATCH_COMMANDS = ("process", "lights", "eval", "render", "bench", "demo")

#: Commands that read a USD stage (they get ``--allow-missing``).
STAGE_COMMANDS = ("export", "inspect", "validate", "process", "render", "lights", "assemble", "eval")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``usdgs`` parser; with ``command`` (a name of :data:`COMMANDS_OF`) only the subcommands
    of its module are registered (the same parser for ``usdgs command ...``, built faster)."""
    import importlib

    parser = argparse.ArgumentParser(prog="usdgs", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"usdgs {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of any error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = [m for m in COMMAND_MODULES if command is None or command in COMMANDS_OF[m]] or COMMAND_MODULES
    for name in modules:
        module = importlib.import_module(f"usd_gs.cli.{name}")
        for register in module.REGISTRARS:
            register(sub, _Formatter)
    for name, p in sub.choices.items():
        if name in STAGE_COMMANDS:
            p.add_argument("--allow-missing", action="store_true",
                           help="use a stage whose sublayers, references or payloads are partly missing (by default "
                                "a missing layer is an error)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``usdgs`` console script; returns the process exit code."""
    process_entry = argv is None  # the console script or ``python -m usd_gs.cli``
    argv = _join_negative_values(sys.argv[1:] if argv is None else list(argv))
    previous = _install_signal_handlers()  # first: a SIGTERM during start-up is handled too
    try:
        return _main(argv, process_entry)
    except KeyboardInterrupt as exc:  # before the command started: nothing was written
        print("usdgs: " + ("terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"), file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    finally:
        if previous is not None:
            _restore_signals(previous)


def _main(argv: list[str], process_entry: bool = False) -> int:
    command = next((a for a in argv if not a.startswith("-")), None)  # top-level options take no value
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    from usd_gs.usd.stage import set_allow_missing

    set_allow_missing(bool(getattr(args, "allow_missing", False)))
    try:
        if process_entry and args.command in BATCH_COMMANDS:  # (not for a caller's own process)
            from usd_gs.pipeline.allocator import tune_for_batch

            tune_for_batch()
        rc = int(args.handler(args) or 0)
        if rc == 0 and process_entry and getattr(args, "quick_exit", False):
            _exit_now()
        return rc
    except UserError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"usdgs {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"usdgs {args.command}: {how}; no partial file was left (files finished before stay)", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except BrokenPipeError:
        # the reader of the output went away (e.g. `usdgs inspect shot.usda | head`): stop quietly, as
        # a program killed by SIGPIPE would (the exit flush must not fail again: stdout goes nowhere)
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):  # (no real file descriptor: e.g. a captured stdout)
            pass
        return 141
    except MemoryError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"usdgs {args.command}: error: not enough memory for this request ({_one_line(exc)}); "
              "use smaller sizes or fewer Gaussians", file=sys.stderr)
        return 2
    except OSError as exc:
        if args.debug:
            traceback.print_exc()
        if exc.errno in _USER_ERRNOS:
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"usdgs {args.command}: error: {where}{exc.strerror or _one_line(exc)}", file=sys.stderr)
            return 2
        print(f"usdgs {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(run with --debug for the traceback)", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence of a CLI
        if args.debug:
            traceback.print_exc()
        print(f"usdgs {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(run with --debug for the traceback)", file=sys.stderr)
        return 1
    finally:
        HELD.clear()  # the process goes on (a test, or main([...]) in another program)


#: objects a ``quick_exit`` command's handler leaves to the end of the process (:func:`hold`)
HELD: list = []


def hold(*objects) -> None:
    """Keep ``objects`` alive until the process ends, for a ``quick_exit`` command whose big
    arrays and layers would otherwise be freed when its handler returns (about 0.01 s for the
    half million Gaussians of an import), just before :func:`_exit_now` skips all freeing.
    Released when ``main`` returns instead (not the process entry, or an error)."""
    HELD.extend(objects)


def _exit_now() -> None:
    """End the process with status 0 now, skipping the interpreter's teardown (freeing every
    module and the arrays of a big import: about 0.05 s) for commands whose work is done and
    whose files are closed (``quick_exit`` in their parser defaults: ``import``, after its atomic
    save). Only when ``main`` runs as the process (``main()``, not ``main([...])`` in a test or
    another program). stdout and stderr are flushed first; if that fails, the normal exit runs."""
    import os

    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    os._exit(0)


#: Options whose value may start with '-' (a negative frame or time): ``--frames -2:-1`` is read as
#: ``--frames=-2:-1`` (argparse would take ``-2:-1`` for an option).
_NEGATIVE_VALUE_OPTIONS = ("--frames", "--time")


def _join_negative_values(argv: list[str]) -> list[str]:
    import re

    out, i = [], 0
    while i < len(argv):
        tok = argv[i]
        if tok in _NEGATIVE_VALUE_OPTIONS and i + 1 < len(argv) and re.match(r"^-\.?\d", argv[i + 1]):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so every atomic write and temp folder is cleaned up."""


#: a SIGTERM or SIGINT that landed inside a module import, to be raised once the import is done
_PENDING: list[int] = []

#: seconds between checks whether the import a pending signal waits for has finished
_RECHECK_S = 0.02


def _in_import(frame) -> bool:
    """True when ``frame`` (where a signal handler interrupted the main thread) is inside a module
    import. An exception raised there can be swallowed by the importer: USD's
    ``Tf.PreparePythonModule`` prints it and leaves the module half loaded, and the command would
    go on instead of stopping."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _raise_signal(signum: int):
    import signal

    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _on_signal(signum, frame):
    """SIGTERM: :class:`Terminated`; SIGINT: ``KeyboardInterrupt``; inside an import, deferred
    until it has finished (:func:`_in_import`; checked again every :data:`_RECHECK_S`)."""
    import signal

    if _in_import(frame):
        _PENDING.append(signum)
        signal.setitimer(signal.ITIMER_REAL, _RECHECK_S)
        return
    _PENDING.clear()
    _raise_signal(signum)


def _on_recheck(signum, frame):
    import signal

    if not _PENDING:
        return
    if _in_import(frame):
        signal.setitimer(signal.ITIMER_REAL, _RECHECK_S)
        return
    pending = _PENDING[0]
    _PENDING.clear()
    _raise_signal(pending)


def _install_signal_handlers():
    """Install the SIGTERM, SIGINT and (for signals deferred past an import) SIGALRM handlers, in
    the main thread only; returns the previous handlers (for :func:`_restore_signals`) or None."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    previous = {}
    try:
        for sig, handler in ((signal.SIGTERM, _on_signal), (signal.SIGINT, _on_signal),
                             (signal.SIGALRM, _on_recheck)):
            previous[sig] = signal.signal(sig, handler)
    except (ValueError, OSError):
        _restore_signals(previous)
        return None
    return previous


def _restore_signals(previous: dict) -> None:
    """Put back the handlers :func:`_install_signal_handlers` replaced; a deferred signal is dropped."""
    import signal

    signal.setitimer(signal.ITIMER_REAL, 0.0)
    _PENDING.clear()
    for sig, handler in previous.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


#: errno values of OSError that are the user's environment (permissions, full disk, a file where a
#: folder should be), reported as user errors (exit 2) naming the file.
_USER_ERRNOS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EISDIR, errno.ENOTDIR,
                errno.EEXIST, errno.ENOENT, errno.ENAMETOOLONG}


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
