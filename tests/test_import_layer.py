"""``usdgs import`` of one capture writes its layer with Sdf alone (usd_gs.usd.gaussian_layer):
the same layer, byte for byte, as ``write_gaussian_prim`` on a ``new_stage``; and it builds only
its own module's subcommand parsers (the same parsers as the full ``usdgs`` parser)."""

import argparse
import importlib
import subprocess
import sys

import numpy as np
import pytest

from usd_gs.cli import COMMAND_MODULES, COMMANDS_OF, _Formatter, build_parser, main
from usd_gs.errors import UserError
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_layer import new_layer, save_stage_atomic, write_gaussian_layer
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, write_gaussian_prim


def _with_extras(g):
    g.extras = {"nx": np.arange(g.count, dtype=np.float32), "tag": (np.arange(g.count) % 7).astype(np.int16),
                "ids": np.arange(g.count, dtype=np.uint8)}
    return g


def _both(g, path, tmp_path, ext, **kw):
    """The files of the Usd-based writer and of the Sdf-only one (bytes)."""
    meta = {"up_axis": kw.pop("up_axis", "Y"), "meters_per_unit": kw.pop("meters_per_unit", 1.0),
            "default_prim": path.split("/")[1]}
    stage = new_stage(**meta)
    write_gaussian_prim(stage, path, g, **kw)
    save_stage_atomic(stage, tmp_path / f"usd{ext}")
    layer = new_layer(**meta)
    write_gaussian_layer(layer, path, g, **kw)
    save_stage_atomic(layer, tmp_path / f"sdf{ext}")
    return (tmp_path / f"usd{ext}").read_bytes(), (tmp_path / f"sdf{ext}").read_bytes()


@pytest.mark.parametrize("ext", [".usda", ".usdc"])
@pytest.mark.parametrize("case", [
    {"degree": 3, "path": "/Gaussians"},
    {"degree": 0, "path": "/World/Scene/Capture", "precision": "half"},
    {"degree": 2, "path": "/A/B", "keep_raw": False, "up_axis": "Z", "meters_per_unit": 0.01},
    {"degree": 1, "path": "/Extras", "extras": True},
])
def test_layer_writer_matches_the_stage_writer(tmp_path, ext, case):
    case = dict(case)
    g = random_gaussians(5_000, case.pop("degree"), seed=3)
    if case.pop("extras", False):
        g = _with_extras(g)
    usd, sdf = _both(g, case.pop("path"), tmp_path, ext, **case)
    assert usd == sdf


def test_layer_writer_output_reads_back(tmp_path):
    from pxr import Usd

    g = _with_extras(random_gaussians(3_000, 2, seed=5))
    layer = new_layer(default_prim="G")
    write_gaussian_layer(layer, "/G", g)
    save_stage_atomic(layer, tmp_path / "g.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "g.usdc"))
    back = read_gaussian_prim(stage.GetPrimAtPath("/G"))
    assert np.array_equal(back.positions, g.positions) and np.array_equal(back.sh, g.sh)
    assert back.extras["tag"].dtype == np.int16 and np.array_equal(back.extras["tag"], g.extras["tag"])


def test_layer_writer_refuses_bad_input():
    g = random_gaussians(100, 0, seed=1)
    layer = new_layer()
    with pytest.raises(UserError, match="precision"):
        write_gaussian_layer(layer, "/G", g, precision="double")
    with pytest.raises(UserError, match="prim path"):
        write_gaussian_layer(layer, "/G.attr", g)
    write_gaussian_layer(layer, "/G/H", g)
    with pytest.raises(UserError, match="already has specs"):
        write_gaussian_layer(layer, "/G", g)
    g.positions[7] = np.nan
    with pytest.raises(Exception, match="element 7"):
        write_gaussian_layer(new_layer(), "/G", g)
    with pytest.raises(UserError, match="up axis"):
        new_layer(up_axis="X")


def test_import_does_not_import_pxr_usd(tmp_path):
    """The plain import of one capture (no --role, --brick-size or sequence) leaves pxr.Usd out."""
    from usd_gs.io.ply import write_ply

    src = tmp_path / "in.ply"
    write_ply(src, random_gaussians(2_000, 1, seed=2))
    code = ("import sys; from usd_gs.cli import main; rc = main(sys.argv[1:]); "
            "print('pxr.Usd' in sys.modules, 'pxr.UsdGeom' in sys.modules); sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code, "import", str(src), "-o", str(tmp_path / "o.usdc"), "-q"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_import_exits_quickly_with_everything_written(tmp_path):
    """As a process (python -m usd_gs.cli) the import ends without teardown: status 0, its line
    printed, the file complete."""
    from pxr import Usd

    from usd_gs.io.ply import write_ply

    src = tmp_path / "in.ply"
    write_ply(src, random_gaussians(2_000, 1, seed=2))
    out = subprocess.run([sys.executable, "-m", "usd_gs.cli", "import", str(src), "-o", str(tmp_path / "o.usdc"),
                          "--role", "scene"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"wrote {tmp_path / 'o.usdc'}: /in with 2,000 Gaussians")
    stage = Usd.Stage.Open(str(tmp_path / "o.usdc"))
    assert "UsdGsRoleAPI" in stage.GetPrimAtPath("/in").GetAppliedSchemas()
    bad = subprocess.run([sys.executable, "-m", "usd_gs.cli", "import", str(src), "-o", str(tmp_path / "o.txt")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "output must end in" in bad.stderr


def test_main_in_process_returns(tmp_path, capsys):
    from usd_gs.io.ply import write_ply

    src = tmp_path / "in.ply"
    write_ply(src, random_gaussians(500, 0, seed=2))
    assert main(["import", str(src), "-o", str(tmp_path / "o.usda")]) == 0
    assert "500 Gaussians" in capsys.readouterr().out


def test_sog_import_is_the_stage_writers_layer_and_holds_nothing_after_main(tmp_path):
    """A SOG's import (decoded in threads, its extent from the units' extents, its values not
    checked a second time) writes what write_gaussian_prim writes for the decoded set; in-process
    ``main`` keeps nothing alive for the process's end."""
    from usd_gs import cli
    from usd_gs.io.sog import read_sog, write_sog

    g = random_gaussians(6_000, 0, seed=8)
    g.positions[:, 0] *= 40.0  # the extent's x faces from a few Gaussians
    write_sog(tmp_path / "c.sog", g)
    assert main(["import", str(tmp_path / "c.sog"), "-o", str(tmp_path / "cli.usdc"), "-q"]) == 0
    assert cli.HELD == []
    stage = new_stage(default_prim="c")
    write_gaussian_prim(stage, "/c", read_sog(tmp_path / "c.sog"))
    save_stage_atomic(stage, tmp_path / "usd.usdc")
    assert (tmp_path / "cli.usdc").read_bytes() == (tmp_path / "usd.usdc").read_bytes()


def test_command_table_matches_the_registrars():
    for name in COMMAND_MODULES:
        module = importlib.import_module(f"usd_gs.cli.{name}")
        sub = argparse.ArgumentParser().add_subparsers()
        for register in module.REGISTRARS:
            register(sub, _Formatter)
        assert tuple(sub.choices) == COMMANDS_OF[name], name


def _sub(parser):
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


@pytest.mark.parametrize("command", [c for cs in COMMANDS_OF.values() for c in cs])
def test_one_command_parser_is_the_full_parsers_part(command):
    full, one = _sub(build_parser()), _sub(build_parser(command))
    assert set(one) <= set(full) and command in one
    assert one[command].format_help() == full[command].format_help()
    assert build_parser(command).format_usage() == build_parser().format_usage()


def test_unknown_command_gets_the_full_parser(capsys):
    with pytest.raises(SystemExit):
        main(["bogus"])
    err = capsys.readouterr().err
    assert "invalid choice: 'bogus'" in err and "'import'" in err and "'render'" in err
