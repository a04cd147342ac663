"""The ``usdgs`` command line: argument parsing, dispatch and error reporting.

Exit codes: 0 success; 1 internal error (or, for ``validate``, problems found);
2 user error (bad input or options: a one-line message naming file, prim, attribute
and element); 130 interrupted. ``--debug`` prints the traceback of any error.

Each subcommand lives in its own module and registers itself through ``COMMANDS``;
heavy imports (pxr, numba) happen inside the handlers so ``usdgs --help`` and
``usdgs --version`` stay instant.
"""

from __future__ import annotations

import argparse
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
COMMAND_MODULES = ("io", "demo", "process", "render", "farm", "eval", "bench", "rig")


def build_parser() -> argparse.ArgumentParser:
    import importlib

    parser = argparse.ArgumentParser(prog="usdgs", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"usdgs {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of any error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        module = importlib.import_module(f"usd_gs.cli.{name}")
        for register in module.REGISTRARS:
            register(sub, _Formatter)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``usdgs`` console script; returns the process exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        return int(args.handler(args) or 0)
    except UserError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"usdgs {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"usdgs {args.command}: interrupted; no output was written", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the last line of defence of a CLI
        if args.debug:
            traceback.print_exc()
        print(f"usdgs {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(run with --debug for the traceback)", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
