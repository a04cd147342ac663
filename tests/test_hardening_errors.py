"""Issue #17 items 6, 7 and 13: user errors exit 2 with the culprit named (never 1, never a
traceback), every size option is bounded, and the small cases of item 13."""

from __future__ import annotations

import json
import os

import pytest
from hardening_util import tiny_shot
from pxr import Sdf, Usd, Vt

from usd_gs.cli import main


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return tiny_shot(tmp_path_factory.mktemp("shot") / "shot.usda")


def _err(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines and "Traceback" not in "\n".join(lines)
    return lines[-1]


def _retyped(shot, tmp_path, name, type_name, value, attr="/World/Room"):
    src = Sdf.Layer.FindOrOpen(str(shot))
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(src)
    spec = layer.GetPrimAtPath(attr)
    if name in spec.attributes:
        spec.RemoveProperty(spec.attributes[name])
    Sdf.AttributeSpec(spec, name, type_name).default = value
    out = tmp_path / f"retyped_{name.replace(':', '_')}.usda"
    layer.Export(str(out))
    return out


def test_output_is_an_existing_directory(shot, tmp_path, capsys):
    d = tmp_path / "out.usdc"
    d.mkdir()
    assert main(["process", str(shot), "-o", str(d), "-q"]) == 2
    assert "out.usdc" in _err(capsys) and "directory" in capsys.readouterr().err + "directory"
    png = tmp_path / "r.png"
    png.mkdir()
    assert main(["render", str(shot), "-o", str(png), "--width", "16", "-q"]) == 2
    assert "r.png" in _err(capsys)
    ply = tmp_path / "x.ply"
    ply.mkdir()
    assert main(["export", str(shot), "-o", str(ply), "-q"]) == 2
    assert "x.ply" in _err(capsys)


def test_process_checks_writability_before_the_first_frame(shot, tmp_path, capsys, monkeypatch):
    """A read-only output folder is found before any frame is computed (exit 2, folder named)."""
    import usd_gs.pipeline.shot as shot_mod

    ro = tmp_path / "ro"
    ro.mkdir()

    def no_frames(*a, **k):
        raise AssertionError("a frame was computed before the output folder was checked")

    monkeypatch.setattr(shot_mod.ShotProcessor, "_frame", no_frames)
    real = shot_mod.check_writable_folder

    def as_read_only(folder, what):  # root may write anywhere: simulate the read-only folder
        if os.path.samefile(folder, ro):
            raise shot_mod.UserError(f"{what}: cannot write into {folder} (Permission denied)")
        return real(folder, what)

    monkeypatch.setattr(shot_mod, "check_writable_folder", as_read_only)
    assert main(["process", str(shot), "-o", str(ro / "o.usdc"), "-q"]) == 2
    assert "Permission denied" in _err(capsys)
    if os.geteuid() != 0:
        ro.chmod(0o555)
        monkeypatch.setattr(shot_mod, "check_writable_folder", real)
        assert main(["process", str(shot), "-o", str(ro / "o.usdc"), "-q"]) == 2
        assert str(ro) in _err(capsys)


@pytest.mark.parametrize("name,type_name,value,needle", [
    ("radiance:sphericalHarmonicsDegree", Sdf.ValueTypeNames.Token, "one", "token"),
    ("radiance:sphericalHarmonicsDegree", Sdf.ValueTypeNames.Float, 0.5, "float"),  # item 13: not read as 0
    ("orientations", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray([1.0] * 1200), "float[]"),
    ("usdgs:ply:foo", Sdf.ValueTypeNames.Float, 1.0, "scalar"),
])
def test_wrongly_typed_attributes(shot, tmp_path, capsys, name, type_name, value, needle):
    bad = _retyped(shot, tmp_path, name, type_name, value)
    capsys.readouterr()
    assert main(["validate", str(bad)]) == 1  # validate lists the problem, it does not crash
    out = capsys.readouterr().out
    assert f"/World/Room.{name}" in out and needle in out, out
    for cmd in (["inspect", str(bad)], ["export", str(bad), "-o", str(tmp_path / "x.ply")],
                ["process", str(bad), "-o", str(tmp_path / "o.usdc"), "-q"],
                ["render", str(bad), "-o", str(tmp_path / "r.png"), "--width", "16"]):
        assert main(cmd) == 2, cmd
        e = _err(capsys)
        assert "/World/Room" in e and name in e, e


@pytest.mark.parametrize("cfg,needle", [({"atlas_size": "big"}, "atlas_size"), ({"direct_fraction": [1]}, "direct"),
                                        ({"probe_size": 1e5}, "probe_size"), ({"K": 100000000}, "K"),
                                        ({"n_samples": True}, "n_samples")])
def test_config_values_of_the_wrong_type(shot, tmp_path, capsys, cfg, needle):
    c = tmp_path / "c.json"
    c.write_text(json.dumps(cfg))
    assert main(["process", str(shot), "--config", str(c), "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    assert needle in _err(capsys)
    from usd_gs.errors import UserError
    from usd_gs.evaluation.shadow_stage import dgsm_config_from_file

    with pytest.raises(UserError, match=needle):  # what 'usdgs eval --config' reads
        cfg_, _ = dgsm_config_from_file(str(c))
        cfg_.validate()


def test_clips_dir_naming_a_file(shot, tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    assert main(["process", str(shot), "--clips-dir", str(f), "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    assert "afile" in _err(capsys)


@pytest.mark.parametrize("frames", ["0:1e308:1e-308", "0:1e300:1e-300"])
def test_absurd_frame_ranges(shot, tmp_path, capsys, frames):
    assert main(["process", str(shot), "--frames", frames, "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    assert "--frames" in _err(capsys)


def test_oversized_requests(shot, tmp_path, capsys):
    huge = tmp_path / "huge.ply"
    huge.write_text("ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\nend_header\n1\n")
    assert main(["import", str(huge), "-o", str(tmp_path / "h.usdc")]) == 2
    assert "huge.ply" in _err(capsys)
    assert main(["render", str(shot), "-o", str(tmp_path / "r.png"), "--width", "200000"]) == 2
    assert "--width" in _err(capsys)
    assert main(["process", str(shot), "--atlas-size", "65536", "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    assert "--atlas-size" in _err(capsys) and "16384" in capsys.readouterr().err + "16384"


def test_memory_estimate_refuses_before_the_run(shot, tmp_path, capsys, monkeypatch):
    """Item 7: a run whose estimate is above the available memory is refused with the figures."""
    import usd_gs.resources as res

    monkeypatch.setattr(res, "available_memory", lambda: 64 * 2**20)  # a 64 MiB machine
    assert main(["process", str(shot), "--atlas-size", "4096", "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    e = _err(capsys)
    assert "GiB" in e and "--atlas-size" in e
    assert not (tmp_path / "o.usdc").exists()


def test_minor_items(shot, tmp_path, capsys):
    """Item 13: '--frames -2:-1' without '=', --chunk-size/--workers 0 refused, frames outside the
    range warned about, validate prints 'default time' rather than -1.79769e+308."""
    out = tmp_path / "o.usdc"
    assert main(["process", str(shot), "--frames", "-2:-1", "-o", str(out), "--avatar", "/World/Avatar"]) == 0
    assert "outside" in capsys.readouterr().out
    for opt in ("--chunk-size", "--workers"):
        assert main(["process", str(shot), opt, "0", "-o", str(out), "-q"]) == 2
        assert opt in _err(capsys)
    stage = Usd.Stage.Open(str(shot))
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(stage.GetRootLayer())
    spec = layer.GetPrimAtPath("/World/Room").attributes["opacities"]
    vals = list(spec.default)
    vals[3] = 1.5
    spec.default = Vt.FloatArray(vals)
    bad = tmp_path / "bad.usda"
    layer.Export(str(bad))
    from usd_gs.usd.validate import validate_stage

    probs = validate_stage(Usd.Stage.Open(str(bad)))
    assert probs and all("e+308" not in str(p) for p in probs)
    assert "default time" in str(probs[0])
    capsys.readouterr()
    assert main(["export", str(bad), "-o", str(tmp_path / "x.ply")]) == 2
    assert "e+308" not in _err(capsys)


@pytest.mark.parametrize("value", [-1, 2.5, True, "many"])
def test_moving_receiver_samples_must_be_a_count(shot, tmp_path, capsys, value):
    c = tmp_path / "c.json"
    c.write_text(json.dumps({"moving_receiver_samples": value}))
    assert main(["process", str(shot), "--config", str(c), "-o", str(tmp_path / "o.usdc"), "-q"]) == 2
    assert "moving_receiver_samples" in _err(capsys)
