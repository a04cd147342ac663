"""Child Python processes for tests that run the package the tests imported.

Under CI the package is installed (not editable) and the tests run from the checkout: a plain
``python -c`` or ``python -m`` from there would import the checkout's copy instead (the current
directory comes first on ``sys.path``), whose numba cache is a separate one, so the child would
compile every kernel it calls again. :func:`python` adds ``-P`` (no current directory) and
:func:`child_env` puts the imported package's folder first on ``PYTHONPATH``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import usd_gs

PACKAGE_ROOT = str(Path(usd_gs.__file__).resolve().parents[1])


def python(*args: str) -> list[str]:
    """``[python, -P, *args]``."""
    return [sys.executable, "-P", *args]


def child_env(**extra: str) -> dict:
    """``os.environ`` with ``extra`` and the imported package's folder first on ``PYTHONPATH``."""
    env = dict(os.environ, **extra)
    env["PYTHONPATH"] = os.pathsep.join([PACKAGE_ROOT] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env
