"""``import usd_gs`` loads neither numpy nor pxr, and the schema plugin is known to USD whether
pxr was imported before usd_gs or after (usd_gs.usd.plugin_path)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

AFTER = """
import sys
import usd_gs
heavy = sorted(m for m in sys.modules if m == "numpy" or m.split(".")[0] in ("pxr", "numba"))
assert not heavy, heavy
from pxr import Usd
print(Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("UsdGsRoleAPI") is not None)
"""

BEFORE = """
from pxr import Usd, Plug
import usd_gs
from usd_gs.usd.schema import schema_available
print(schema_available() and Plug.Registry().GetPluginWithName("usdGs") is not None)
"""


@pytest.mark.parametrize("code", [AFTER, BEFORE], ids=["pxr after usd_gs", "pxr before usd_gs"])
def test_schema_registered_and_nothing_heavy_imported(code):
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"


def test_plugin_path_is_not_repeated(monkeypatch):
    from usd_gs.usd import plugin_path

    folder = plugin_path.schema_folder()
    assert folder is not None and (Path(folder) / "plugInfo.json").is_file()
    monkeypatch.setattr(plugin_path, "pxr_loaded", lambda: False)
    monkeypatch.setenv("PXR_PLUGINPATH_NAME", os.pathsep.join(["/elsewhere", folder]))
    plugin_path.register_at_import()
    assert os.environ["PXR_PLUGINPATH_NAME"] == os.pathsep.join(["/elsewhere", folder])
    monkeypatch.setenv("PXR_PLUGINPATH_NAME", "/elsewhere")
    plugin_path.register_at_import()
    assert os.environ["PXR_PLUGINPATH_NAME"] == os.pathsep.join([folder, "/elsewhere"])
