"""Where the usd-gs schema plugin lives, and how ``import usd_gs`` registers it without loading pxr.

Standard library only (``os``, ``sys``, ``importlib.util``): this runs at every start of the
command line, before numpy or pxr are imported.
"""

from __future__ import annotations

import importlib.util
import os
import sys

#: the plugin's name in its plugInfo.json
PLUGIN_NAME = "usdGs"

#: the environment variable Plug reads, once, when its registry is first made (``os.pathsep`` list)
PLUGIN_PATH_VAR = "PXR_PLUGINPATH_NAME"


def schema_folder() -> str | None:
    """The folder holding ``plugInfo.json`` of the usd-gs schema plugin, or None when absent.

    Pip-installed: the package ``usd_gs.schemas``. Source tree (``PYTHONPATH=<repo>``),
    where ``usd_gs.schemas`` is not importable: ``<repo>/schemas`` next to ``usd_gs/``.
    """
    try:  # (find_spec, not importlib.resources: that costs 10 ms of imports at every start)
        spec = importlib.util.find_spec("usd_gs.schemas")
        for folder in (spec.submodule_search_locations or []) if spec is not None else []:
            if os.path.isfile(os.path.join(folder, "plugInfo.json")):
                return folder
    except (ModuleNotFoundError, TypeError, ValueError):
        pass
    here = os.path.dirname(os.path.realpath(__file__))
    folder = os.path.join(os.path.dirname(os.path.dirname(here)), "schemas")
    return folder if os.path.isfile(os.path.join(folder, "plugInfo.json")) else None


def pxr_loaded() -> bool:
    """True once any pxr module is imported in this process (Plug's registry may exist)."""
    return "pxr" in sys.modules


def missing_schema_error():
    """The ``UserError`` for a schema plugin that is not where :func:`schema_folder` looks."""
    from usd_gs.errors import UserError

    here = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__)))), "schemas")
    return UserError(f"usd-gs schema plugin not found: no plugInfo.json in the package usd_gs.schemas or in {here}")


def register_at_import() -> None:
    """Make the schema plugin known to USD, at ``import usd_gs``.

    Before pxr is loaded, the schema folder is put first on ``PXR_PLUGINPATH_NAME`` (unless it is
    already there), which Plug reads when its registry is first made: importing usd_gs then
    loads no pxr module, and every later stage of this process (and of its child processes,
    which inherit the variable) sees ``UsdGsRoleAPI``. Once pxr is loaded, the plugin is
    registered with ``Plug.Registry`` at once (as :func:`usd_gs.usd.schema.register_plugins`
    does). A missing schema folder raises ``UserError`` either way.
    """
    folder = schema_folder()
    if folder is None:
        raise missing_schema_error()
    if pxr_loaded():
        from pxr import Plug

        registry = Plug.Registry()
        if registry.GetPluginWithName(PLUGIN_NAME) is None:
            registry.RegisterPlugins(folder)
        return
    paths = [p for p in os.environ.get(PLUGIN_PATH_VAR, "").split(os.pathsep) if p]
    if not any(os.path.realpath(p) == os.path.realpath(folder) for p in paths):
        os.environ[PLUGIN_PATH_VAR] = os.pathsep.join([folder, *paths])
