"""`usdgs process`: the output contract, values against exact references, safety, determinism."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdLux

from usd_gs import sh3dgs
from usd_gs.cli import main
from usd_gs.usd.gaussian_prim import read_gaussian_prim

#: the main job writing every AOV exactly (float SH, every change): for comparisons with references
EXACT = ("--aovs", "transmittance,lightScale", "--precision", "float", "--sh-tolerance", "0")

FRAMES = "1-2"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _shot_over(demo: Path, shot: Path) -> Usd.Stage:
    """A new stage at ``shot`` whose root layer sublayers ``demo`` (edits go to the new layer)."""
    layer = Sdf.Layer.CreateNew(str(shot))
    layer.subLayerPaths.append(str(demo))
    layer.Save()
    return Usd.Stage.Open(str(shot))


@pytest.fixture(scope="module")
def processed(quick_demo, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "demo.lit.usdc"
    before = {p: _digest(p) for p in quick_demo.parent.rglob("*") if p.is_file()}
    # centre sampling: transmittance is then comparable with the exact function at the centres; every AOV, in
    # float and with every change written, so the values compare exactly
    assert main(["process", str(quick_demo), "-o", str(out), "--frames", FRAMES, "-q", "--sampling", "center",
                 *EXACT]) == 0
    after = {p: _digest(p) for p in quick_demo.parent.rglob("*") if p.is_file()}
    return out, before, after


def test_input_untouched_and_output_layered(quick_demo, processed):
    out, before, after = processed
    assert before == after  # the input files are byte-identical after the run
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert len(layer.subLayerPaths) == 1
    assert Path(out.parent / layer.subLayerPaths[0]).resolve() == quick_demo.resolve() or \
        Path(layer.subLayerPaths[0]).resolve() == quick_demo.resolve()
    # only overs for input prims; new prims are ours
    for spec in layer.rootPrims:
        if spec.name == "World":
            assert spec.specifier == Sdf.SpecifierOver
    stage = Usd.Stage.Open(str(out))
    assert stage.GetMetadata("upAxis") == "Y" and stage.GetTimeCodesPerSecond() == 24


def test_estimated_lights_at_the_lamps(processed):
    out, _, _ = processed
    stage = Usd.Stage.Open(str(out))
    lights = [p for p in stage.Traverse() if p.IsA(UsdLux.SphereLight)]
    assert [str(p.GetPath()) for p in lights] == ["/UsdGs/Lights/Light_0", "/UsdGs/Lights/Light_1"]
    truth = np.array(stage.GetPrimAtPath("/World").GetCustomDataByKey("usdgs:demo:lampPositions"))
    for p in lights:
        pos = np.array(p.GetAttribute("xformOp:translate").Get())
        assert np.min(np.linalg.norm(truth - pos, axis=1)) < 0.05
        assert p.GetCustomDataByKey("usdgs:score") > 0


def _world_sets(stage, paths, frame):
    return {p: read_gaussian_prim(stage.GetPrimAtPath(p), Usd.TimeCode(frame)) for p in paths}


def test_scene_transmittance_matches_exact_reference(processed):
    """DGSM transmittance on the room against the exact closed-form transmittance at the
    receiver centres (every caster, every light, combined as the pipeline does). The error
    left is the atlas discretisation (512^2 directions x 64 radial bins)."""
    from usd_gs.gaussians import GaussianSet
    from usd_gs.shadows.dgsm import exact_transmittance
    from usd_gs.shadows.shading import combine_lights, light_shares
    from usd_gs.usd.lux import read_stage_lights

    out, _, _ = processed
    stage = Usd.Stage.Open(str(out))
    frame = 2.0
    bricks = [p for p in stage.GetPrimAtPath("/World/Room").GetChildren()]
    authored = [b for b in bricks if b.GetAttribute("primvars:usdgs:transmittance").HasAuthoredValue()]
    assert 0 < len(authored) < len(bricks)  # only the bricks a shadow touches
    casters = _world_sets(stage, ["/World/CesiumMan", "/World/Biker", "/World/Guitar"], frame)
    occ = GaussianSet.concatenate(list(casters.values()))
    lights, _ = read_stage_lights(stage, Usd.TimeCode(frame))
    assert len(lights) == 2
    got, ref = [], []
    for b in authored:
        g = read_gaussian_prim(b, Usd.TimeCode(frame))
        t = np.array(b.GetAttribute("primvars:usdgs:transmittance").Get(frame))
        assert t.shape == (g.count,) and np.all((t >= 0) & (t <= 1))
        per = [exact_transmittance(occ, g.positions.astype(np.float64), lt.position) for lt in lights]
        ref.append(combine_lights(per, light_shares(lights, g.positions)))
        got.append(t)
    got, ref = np.concatenate(got), np.concatenate(ref)
    shadowed = ref < 0.95
    assert shadowed.sum() > 50  # the avatars do cast visible shadows
    err = np.abs(got - ref)
    assert err.mean() < 0.01 and err[shadowed].mean() < 0.08 and abs((got - ref)[shadowed].mean()) < 0.03


def test_shadowed_colour_is_original_times_transmittance(processed, quick_demo):
    out, _, _ = processed
    stage = Usd.Stage.Open(str(out))
    src = Usd.Stage.Open(str(quick_demo))
    frame = 1.0
    for b in stage.GetPrimAtPath("/World/Room").GetChildren():
        attr = b.GetAttribute("primvars:usdgs:transmittance")
        if not attr.HasAuthoredValue():
            continue
        t = np.array(attr.Get(frame), np.float64)
        lit = read_gaussian_prim(b, Usd.TimeCode(frame))
        orig = read_gaussian_prim(src.GetPrimAtPath(b.GetPath()), Usd.TimeCode(frame))
        d = np.random.default_rng(0).normal(size=(lit.count, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        np.testing.assert_allclose(sh3dgs.eval_color(lit.sh, d), t[:, None] * sh3dgs.eval_color(orig.sh, d),
                                   atol=2e-5)
        break
    else:
        pytest.fail("no shadowed brick")


def test_avatars_relit_with_probe(processed, quick_demo):
    out, _, _ = processed
    stage = Usd.Stage.Open(str(out))
    src = Usd.Stage.Open(str(quick_demo))
    for name in ("CesiumMan", "Biker", "Guitar"):
        prim = stage.GetPrimAtPath(f"/World/{name}")
        scale_attr = prim.GetAttribute("primvars:usdgs:lightScale")
        assert scale_attr.GetTimeSamples() == [1.0, 2.0]
        probe = stage.GetPrimAtPath(f"/UsdGs/Probes/{name}")
        assert probe.GetAttribute("usdgs:probe:shCoefficients").GetTimeSamples() == [1.0, 2.0]
        coeffs = np.array(probe.GetAttribute("usdgs:probe:shCoefficients").Get(2.0))
        assert coeffs.shape == (16, 3) and np.all(np.isfinite(coeffs))
        tex = probe.GetAttribute("usdgs:probe:texture").Get(2.0)
        assert Path(tex.resolvedPath).is_file() and tex.resolvedPath.endswith(".0002.exr")
        # relit colour = light scale * original colour: since issue 18 the light scale holds the
        # prim's shadows too (each light's visibility on that light's share of the irradiance;
        # before, relit = scale * transmittance * original, the shadow on all of the light)
        s = np.array(scale_attr.Get(2.0), np.float64)
        t = np.array(prim.GetAttribute("primvars:usdgs:transmittance").Get(2.0), np.float64)
        lit = read_gaussian_prim(prim, Usd.TimeCode(2.0), world=False)
        orig = read_gaussian_prim(src.GetPrimAtPath(prim.GetPath()), Usd.TimeCode(2.0), world=False)
        d = np.tile([0.0, 0.0, 1.0], (lit.count, 1))
        np.testing.assert_allclose(sh3dgs.eval_color(lit.sh, d), s * sh3dgs.eval_color(orig.sh, d), atol=1e-4)
        assert np.all(s >= 0) and s.mean() > 0.05
        # the avatars stand in the open: most of their Gaussians see the lights
        assert np.mean(t > 0.5) > 0.7, (name, t.mean())


def test_output_is_deterministic_with_mc_sampling(quick_demo, tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, b = tmp_path / "a" / "x.lit.usdc", tmp_path / "b" / "x.lit.usdc"  # same name: probe paths are relative
    for out in (a, b):
        assert main(["process", str(quick_demo), "-o", str(out), "--frames", "2", "--sampling", "mc", "-q"]) == 0
    assert a.read_bytes() == b.read_bytes()


def test_failure_leaves_no_partial_output(quick_demo, tmp_path, monkeypatch):
    from usd_gs.pipeline import shot as pipeline

    calls = {"n": 0}
    real = pipeline.ShotProcessor._frame

    def boom(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(pipeline.ShotProcessor, "_frame", boom)
    out = tmp_path / "x.lit.usdc"
    assert main(["process", str(quick_demo), "-o", str(out), "--frames", FRAMES, "-q"]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_stage_lights_are_used(quick_demo, tmp_path, capsys):
    shot = tmp_path / "shot.usda"
    stage = _shot_over(quick_demo, shot)
    key = UsdLux.SphereLight.Define(stage, "/Rig/Key")
    key.AddTranslateOp().Set(Gf.Vec3d(0.0, 2.8, 0.0))
    key.CreateIntensityAttr(5.0)
    stage.GetRootLayer().Save()
    out = tmp_path / "shot.lit.usdc"
    assert main(["process", str(shot), "-o", str(out), "--frames", "1", "--lights", "stage", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [lt["source"] for lt in summary["lights"]] == ["/Rig/Key"]
    assert summary["frames"]["count"] == 1
    assert not Usd.Stage.Open(str(out)).GetPrimAtPath("/UsdGs/Lights")


@pytest.mark.parametrize("argv, msg", [
    (["--lights", "0"], "--lights 0"),
    (["--frames", "9-3"], "before start"),
    (["--avatar", "/World/Nope"], "/World/Nope"),
    (["--direct-fraction", "2"], "--direct-fraction"),
])
def test_process_user_errors(quick_demo, tmp_path, capsys, argv, msg):
    code = main(["process", str(quick_demo), "-o", str(tmp_path / "o.usdc"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and msg in err and "Traceback" not in err
    assert not (tmp_path / "o.usdc").exists()


def test_process_refuses_to_overwrite_input(quick_demo, capsys):
    code = main(["process", str(quick_demo), "-o", str(quick_demo)])
    assert code == 2 and "demo.usda" in capsys.readouterr().err


def test_distant_light_uses_directional_dgsm(quick_demo, tmp_path):
    """A DistantLight straight down: the floor right under each mover is shadowed, and the
    transmittance there matches the exact parallel-ray transmittance."""
    from usd_gs.gaussians import GaussianSet
    from usd_gs.shadows.dgsm import exact_transmittance_directional

    shot = tmp_path / "sun.usda"
    stage = _shot_over(quick_demo, shot)
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.AddRotateXOp().Set(-90.0)  # local -Z -> world -Y
    sun.CreateIntensityAttr(3.0)
    stage.GetRootLayer().Save()
    out = tmp_path / "sun.lit.usdc"
    assert main(["process", str(shot), "-o", str(out), "--frames", "1", "--sampling", "center", "-q", *EXACT]) == 0
    lit = Usd.Stage.Open(str(out))
    casters = GaussianSet.concatenate([read_gaussian_prim(lit.GetPrimAtPath(f"/World/{n}"), Usd.TimeCode(1))
                                       for n in ("CesiumMan", "Biker", "Guitar")])
    got, ref = [], []
    for b in lit.GetPrimAtPath("/World/Room").GetChildren():
        attr = b.GetAttribute("primvars:usdgs:transmittance")
        if not attr.HasAuthoredValue():
            continue
        g = read_gaussian_prim(b, Usd.TimeCode(1))
        got.append(np.array(attr.Get(1.0)))
        ref.append(exact_transmittance_directional(casters, g.positions.astype(np.float64), [0.0, -1.0, 0.0]))
    got, ref = np.concatenate(got), np.concatenate(ref)
    assert (ref < 0.5).sum() > 20
    assert np.abs(got - ref).mean() < 0.01


def test_fresh_checkout_generates_the_missing_demo_stage(tmp_path, monkeypatch, capsys):
    """`usdgs process stages/demo.usda` in a checkout where the (git-ignored) demo was never made:
    the demo is generated first (here the --quick one, for time), then processed. Any other
    missing stage is still an error naming the file."""
    from usd_gs.cli import main
    from usd_gs.cli.process import is_missing_demo
    from usd_gs.demo import stage as demo_stage

    stages = tmp_path / "stages"
    stages.mkdir()
    demo = stages / "demo.usda"
    assert not is_missing_demo(demo)  # not this project's stages folder (no make_example.py)
    (stages / "make_example.py").write_text("# marker\n")
    assert is_missing_demo(demo) and not is_missing_demo(stages / "other.usda")
    real = demo_stage.make_demo
    monkeypatch.setattr(demo_stage, "make_demo", lambda out, opts, data, log=None: real(out, demo_stage.QUICK,
                                                                                         data, log))
    assert main(["process", str(demo), "--frames", "1-2", "-o", str(tmp_path / "lit.usdc")]) == 0
    out = capsys.readouterr().out
    assert "does not exist yet: generating the demo shot" in out and "2 frame(s)" in out
    assert demo.exists() and (tmp_path / "lit.usdc").exists()
    assert main(["process", str(stages / "other.usda")]) == 2
    assert "other.usda: no such file" in capsys.readouterr().err


def test_a_static_avatar_is_relit_and_casts(tmp_path):
    """An avatar without time samples (an inserted character in one pose) is processed like a
    moving one: relit (lightScale and a probe) and its shadow falls on the scene."""
    from lights_scene import make_emitter_test_scene
    from pxr import Usd

    from usd_gs.cli import main
    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    room = make_emitter_test_scene(spacing=0.2).gaussians
    avatar = random_gaussians(400, 0, seed=3)
    avatar.positions[:] = avatar.positions * 0.05 + np.array([0.0, 1.0, 0.0], np.float32)  # 1 m up, ~0.3 m wide
    stage = new_stage()
    write_gaussian_prim(stage, "/World/Room", room)
    write_gaussian_prim(stage, "/World/Statue", avatar)
    src = save_stage_atomic(stage, tmp_path / "shot.usda")
    out = tmp_path / "shot.lit.usdc"
    assert main(["process", str(src), "--avatar", "/World/Statue", "--lights", "2", "-o", str(out), "-q", *EXACT]) == 0
    lit = Usd.Stage.Open(str(out))
    scale = lit.GetPrimAtPath("/World/Statue").GetAttribute("primvars:usdgs:lightScale")
    assert scale and scale.GetNumTimeSamples() >= 1 and len(scale.Get(scale.GetTimeSamples()[0])) == avatar.count
    assert lit.GetPrimAtPath("/UsdGs/Probes/Statue")
    t = lit.GetPrimAtPath("/World/Room").GetAttribute("primvars:usdgs:transmittance")
    assert t and np.min(np.asarray(t.Get(t.GetTimeSamples()[0]))) < 0.9  # the statue shadows the room


def test_a_shot_without_any_light_keeps_the_relit_prims_mean_brightness(tmp_path, monkeypatch, capsys):
    """No light on the stage and none found in the capture: the main job relights with the probe
    alone but keeps each relit prim's captured mean brightness (``keep_level_without_lights``) and
    says so; with the option off the absolute rule's level comes out (here darker)."""
    from hardening_util import tiny_shot

    import usd_gs.pipeline.shot as shot
    from usd_gs.colorspace import to_linear

    stage = tiny_shot(tmp_path / "shot.usda")
    s = Usd.Stage.Open(str(stage))
    s.RemovePrim("/World/Lamp")
    s.GetRootLayer().Save()
    monkeypatch.setattr(shot.ShotProcessor, "_lights", lambda self, frame: [])  # nothing found, no sky

    def mean_luminance(path, prim="/World/Avatar"):
        opened = Usd.Stage.Open(str(path))
        g = read_gaussian_prim(opened.GetPrimAtPath(prim), Usd.TimeCode(1))
        lin = to_linear(np.clip(0.5 + sh3dgs.C0 * g.sh[:, 0, :].astype(np.float64), 0, None), "srgb")
        w = g.opacities.astype(np.float64)
        return float(w @ (lin @ np.array([0.2126, 0.7152, 0.0722])) / w.sum())

    runs = {}
    for keep in (True, False):
        cfg = tmp_path / f"{keep}.json"
        cfg.write_text(json.dumps({"keep_level_without_lights": keep}))
        out = tmp_path / f"{keep}.lit.usdc"
        assert main(["process", str(stage), "-o", str(out), "--frames", "1", "--json", "--config", str(cfg)]) == 0
        runs[keep] = (out, json.loads(capsys.readouterr().out))
    assert shot.NO_LIGHT_NOTE in runs[True][1]["warnings"] and shot.NO_LIGHT_NOTE not in runs[False][1]["warnings"]
    before = mean_luminance(stage)
    assert mean_luminance(runs[True][0]) == pytest.approx(before, rel=5e-3)  # half-precision output
    assert mean_luminance(runs[False][0]) < 0.9 * before


def test_shot_buffer_shares_the_static_receivers_arrays(quick_demo, tmp_path, monkeypatch):
    """The probe renders' shot buffer is the static receivers' own arrays with the moving prims'
    rows (and their merged rows) after them, and each static prim's set its rows (one copy of the
    static scene, not two), and the output is the one the plain concatenation gives (the same run
    with the sharing turned off: every value the same)."""
    from farm_compare import stage_differences

    from usd_gs.pipeline import shot as pipeline

    seen = []
    real = pipeline.ShotProcessor._shot_buffer

    def spy(self, dyn):
        buf, spans = real(self, dyn)
        seen.append((buf, self._static_recv.gaussians, dict(self.static), spans, self._buffer[3]))
        return buf, spans

    monkeypatch.setattr(pipeline.ShotProcessor, "_shot_buffer", spy)
    shared, plain = tmp_path / "shared.usdc", tmp_path / "plain.usdc"
    argv = ["--frames", "1-2", "-q", *EXACT]
    assert main(["process", str(quick_demo), "-o", str(shared), *argv]) == 0
    buf, recv, static, spans, slots = seen[-1]
    assert np.shares_memory(buf.positions, recv.positions) and np.shares_memory(buf.sh, recv.sh)
    # each static prim's own set is its rows of the buffer (the arrays read from USD are let go)
    assert len(static) > 1 and all(np.shares_memory(g.positions, buf.positions) and np.shares_memory(g.sh, buf.sh)
                                   and not g.positions.flags.writeable for g in static.values())
    # then the rows of the moving prims merged for the probes (usd_gs.relight.probe_merge)
    end = max(spans[p][1] for p in spans)
    assert slots and min(a for a, _ in slots.values()) == end
    assert buf.count > recv.count and end + sum(n for _, n in slots.values()) == buf.count
    first = seen[0][0]
    assert first is buf  # frame 2 wrote its moving prims into the same arrays
    monkeypatch.setattr(pipeline.ShotProcessor, "_static_part", lambda self: None)
    seen.clear()
    assert main(["process", str(quick_demo), "-o", str(plain), *argv]) == 0
    assert not np.shares_memory(seen[-1][0].positions, seen[-1][1].positions)
    assert stage_differences(shared, plain, [1, 2]) == []
