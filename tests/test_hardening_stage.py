"""Issue #17 items 4 and 5: a partial stage is an error (missing sublayer, reference or
payload: exit 2 naming the layer, ``--allow-missing`` to override), and ``assemble`` refuses a
chunk layer without its manifest entry (``--allow-gaps`` to override)."""

from __future__ import annotations

import json

import pytest
from hardening_util import leftovers, tiny_shot

from usd_gs.cli import main


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return tiny_shot(tmp_path_factory.mktemp("shot") / "shot.usda")


def _partial(tmp_path, shot, kind):
    p = tmp_path / f"partial_{kind}.usda"
    if kind == "sublayer":
        p.write_text(f'#usda 1.0\n(\n    subLayers = [@./gone.usda@, @{shot}@]\n)\n')
    else:
        arc = "references" if kind == "reference" else "payload"
        p.write_text(f'#usda 1.0\n(\n    subLayers = [@{shot}@]\n)\n'
                     f'def Xform "Extra" (prepend {arc} = @./gone.usda@</Asset>) {{}}\n')
    return p


@pytest.mark.parametrize("kind", ["sublayer", "reference", "payload"])
def test_missing_layer_is_an_error(shot, tmp_path, capsys, kind):
    p = _partial(tmp_path, shot, kind)
    for cmd in (["validate", str(p)], ["inspect", str(p)],
                ["process", str(p), "-o", str(tmp_path / "o.usdc"), "-q"],
                ["render", str(p), "-o", str(tmp_path / "r.png"), "--width", "16", "-q"]):
        capsys.readouterr()
        assert main(cmd) == 2, cmd
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert "gone.usda" in err and str(p.name) in err and "--allow-missing" in err, err
    assert not (tmp_path / "o.usdc").exists() and not (tmp_path / "r.png").exists()
    assert main(["validate", str(p), "--allow-missing", "-q"]) == 0
    assert main(["render", str(p), "-o", str(tmp_path / "r.png"), "--width", "16", "-q", "--allow-missing"]) == 0


def test_assemble_refuses_a_chunk_without_entry(shot, tmp_path, capsys):
    clips = tmp_path / "clips"
    out = tmp_path / "out.usdc"
    assert main(["process", str(shot), "-o", str(out), "--avatar", "/World/Avatar", "--chunk-size", "1",
                 "--clips-dir", str(clips), "-q"]) == 0
    (clips / "chunk_0002_0002.json").unlink()  # the entry of frame 2 is lost (a task died before writing it)
    capsys.readouterr()
    again = tmp_path / "again.usdc"
    assert main(["assemble", str(clips), "-o", str(again), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "chunk_0002_0002.usdc" in err and "frames 2" in err and "--allow-gaps" in err, err
    assert not again.exists()
    assert main(["assemble", str(clips), "-o", str(again), "-q", "--allow-gaps"]) == 0
    assert leftovers(tmp_path) == []
    entry = json.loads((clips / "chunk_0001_0001.json").read_text())
    assert entry["frames"] == [1.0]
