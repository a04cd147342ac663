"""Lazy re-exports for the subpackages' ``__init__`` files (PEP 562 module ``__getattr__``).

``from usd_gs.shadows import DGSMConfig`` imports ``usd_gs.shadows.dgsm`` on first use, so that
importing a package costs nothing (``usdgs --help`` stays instant) and package imports cannot
form cycles through their ``__init__`` files.
"""

from __future__ import annotations

import importlib


def lazy_exports(package: str, exports: dict[str, str]):
    """``(__getattr__, __dir__, __all__)`` for ``package`` whose public ``exports`` map a name to
    the submodule (relative to ``package``) that defines it."""

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def __dir__():
        return sorted(exports)

    return __getattr__, __dir__, sorted(exports)
