"""Farm runs: the stitched value clips against a single-process run, every authored attribute at
every frame; the topology layer; the dask and local-process executors; retries."""

from __future__ import annotations

import numpy as np
import pytest
from farm_compare import stage_differences
from pxr import Gf, Sdf, Usd

from usd_gs.cli import main
from usd_gs.farm.clips import assemble
from usd_gs.farm.executor import ChunkFailed, run_chunk
from usd_gs.farm.run import run_farm
from usd_gs.pipeline.shot import ProcessOptions

FRAMES = [1.0, 2.0, 3.0, 4.0]


@pytest.fixture(scope="module")
def shot(quick_demo, tmp_path_factory):
    """The quick demo with the guitar jumping across the room between frames 2 and 3, so some
    room bricks are shadowed only in the first two frames and others only in the last two:
    each 2-frame chunk then lacks attributes the other one has (the manifest-default case)."""
    d = tmp_path_factory.mktemp("farm")
    path = d / "shot.usda"
    layer = Sdf.Layer.CreateNew(str(path))
    layer.subLayerPaths.append(str(quick_demo))
    layer.Save()
    stage = Usd.Stage.Open(str(path))
    t = stage.GetPrimAtPath("/World/Guitar").GetAttribute("xformOp:translate")
    for f, v in [(1, (2.3, 0, -0.45)), (2, (2.3, 0, -0.45)), (3, (-2.5, 0, -3.0)), (4, (-2.5, 0, -3.0))]:
        t.Set(Gf.Vec3d(*v), f)
    stage.Save()
    single = d / "single.usdc"
    assert main(["process", str(path), "-o", str(single), "--frames", "1-4", "-q"]) == 0
    return path, single


def test_chunked_run_is_value_identical(shot, tmp_path):
    path, single = shot
    out = tmp_path / "stitched.usdc"
    s = run_farm(str(path), str(out), ProcessOptions(frames="1-4"), 2, str(tmp_path / "clips"))
    assert s.computed == ["chunk_0001_0002", "chunk_0003_0004"] and s.skipped == []
    assert stage_differences(single, out, FRAMES) == []
    # the case that needs manifest defaults really occurs here ...
    again = assemble(tmp_path / "clips", tmp_path / "again.usdc")
    assert again.filled > 0
    # ... and without them the comparison fails (the test can see a wrong stitch)
    man = Sdf.Layer.FindOrOpen(str(tmp_path / "again.manifest.usdc"))
    cleared = 0
    for prim in man.GetPrimAtPath("/World/Room").nameChildren:
        for attr in prim.attributes:
            if attr.HasDefaultValue():
                attr.ClearDefaultValue()
                cleared += 1
    man.Save()
    assert cleared == again.filled
    Usd.Stage.Open(str(tmp_path / "again.usdc")).Reload()
    bad = stage_differences(single, tmp_path / "again.usdc", FRAMES)
    assert bad and all("/World/Room/" in b for b in bad)


def test_chunk_layers_and_topology(shot, tmp_path):
    path, _ = shot
    out = tmp_path / "stitched.usdc"
    assert main(["process", str(path), "-o", str(out), "--frames", "1-3", "--chunk-size", "2", "-q",
                 "--aovs", "transmittance"]) == 0
    clips = tmp_path / "stitched_clips"
    c0, c1 = (Sdf.Layer.FindOrOpen(str(clips / n)) for n in ("chunk_0001_0002.usdc", "chunk_0003_0003.usdc"))
    assert (c0.startTimeCode, c0.endTimeCode, c1.startTimeCode, c1.endTimeCode) == (1, 2, 3, 3)
    root = Sdf.Layer.FindOrOpen(str(out))
    assert list(root.subLayerPaths)[0] == "./stitched.topology.usdc"
    assert Sdf.ComputeAssetPathRelativeToLayer(root, root.subLayerPaths[1]) == str(path)
    topo = Sdf.Layer.FindOrOpen(str(tmp_path / "stitched.topology.usdc"))
    src = Usd.Stage.Open(str(path))
    n_gauss = n_sh = 0
    for spec in topo.GetPrimAtPath("/World/Room").nameChildren:
        n_gauss += 1
        assert spec.typeName == "ParticleField3DGaussianSplat"
        deg = spec.attributes["radiance:sphericalHarmonicsDegree"]
        assert deg.default == 1 and deg.variability == Sdf.VariabilityUniform
        if "radiance:sphericalHarmonicsCoefficientsh" in spec.attributes:  # SH written: half, the float blocked
            n_sh += 1
            shh = spec.attributes["radiance:sphericalHarmonicsCoefficientsh"]
            assert shh.GetInfo("interpolation") == "vertex" and shh.GetInfo("elementSize") == 4
            sh = spec.attributes["radiance:sphericalHarmonicsCoefficients"]
            assert sh.GetInfo("interpolation") == "vertex" and sh.GetInfo("elementSize") == 4
            assert isinstance(sh.default, Sdf.ValueBlock)
        tr = spec.attributes["primvars:usdgs:transmittance"]
        assert tr.GetInfo("interpolation") == "vertex" and not tr.HasInfo("timeSamples")
        assert src.GetPrimAtPath(spec.path).GetTypeName() == "ParticleField3DGaussianSplat"
    assert n_gauss > 0 and n_sh > 0
    # the stitched stage reads like the normal output: lights, probes, time samples at the frames
    st = Usd.Stage.Open(str(out))
    assert st.GetPrimAtPath("/UsdGs/Lights/Light_0").GetTypeName() == "SphereLight"
    probe_sh = st.GetPrimAtPath("/UsdGs/Probes/CesiumMan").GetAttribute("usdgs:probe:shCoefficients")
    assert probe_sh.GetTimeSamples() == [1.0, 2.0, 3.0]


def test_compare_render_of_a_stitched_output_shows_the_input(shot, tmp_path):
    """`usdgs render --compare` on a chunked run's output: the left half is the input (not the
    stitched output's own topology layer, its first sublayer), the right half the output."""
    from PIL import Image

    path, _ = shot
    out = tmp_path / "stitched.usda"
    assert main(["process", str(path), "-o", str(out), "--frames", "1-2", "--chunk-size", "1", "-q"]) == 0
    args = ["--frames", "2", "--width", "48", "-q"]
    assert main(["render", str(out), "-o", str(tmp_path / "c.png"), "--compare", *args]) == 0
    assert main(["render", str(path), "-o", str(tmp_path / "in.png"), *args]) == 0
    assert main(["render", str(out), "-o", str(tmp_path / "out.png"), *args]) == 0
    c, left, right = (np.asarray(Image.open(tmp_path / n)) for n in ("c.png", "in.png", "out.png"))
    w = left.shape[1]
    np.testing.assert_array_equal(c[:, :w], left)
    np.testing.assert_array_equal(c[:, w + 4:], right)
    assert left.mean() > 5.0 and np.abs(left.astype(int) - right.astype(int)).mean() > 0.1


def test_local_processes_and_dask_cluster(shot, tmp_path):
    """Two local worker processes, then a LocalCluster with two in-process workers reached
    through ``--scheduler tcp://...`` and through a client: every stitched result equals the
    single run."""
    import distributed
    path, single = shot
    out = tmp_path / "procs.usdc"
    assert main(["process", str(path), "-o", str(out), "--frames", "1-4", "--chunk-size", "2", "--workers", "2",
                 "-q"]) == 0
    assert stage_differences(single, out, FRAMES) == []
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        # the command line's --scheduler path: a client connecting to the scheduler's tcp address
        out3 = tmp_path / "sched.usdc"
        assert main(["process", str(path), "-o", str(out3), "--frames", "1-4", "--chunk-size", "2", "--clips-dir",
                     str(tmp_path / "sclips"), "--scheduler", cluster.scheduler_address, "-q"]) == 0
        assert stage_differences(single, out3, FRAMES) == []
        out2 = tmp_path / "dask.usdc"
        lines = []
        s = run_farm(str(path), str(out2), ProcessOptions(frames="1-4"), 1, str(tmp_path / "dclips"), client=client,
                     report=lines.append)
        assert s.backend.startswith("dask scheduler")
        workers = {r.worker for r in s.results}
    assert len(s.results) == 4 and len(lines) == 4 and all(" done in " in ln for ln in lines)
    assert len(workers) == 1  # processes=False: both dask workers live in this process
    assert stage_differences(single, out2, FRAMES) == []


def _flaky(task):
    """Fails the first attempt at chunk 2 (a marker file counts the attempts), then runs."""
    from pathlib import Path

    mark = Path(task.folder) / f"attempts_{task.chunk.name}"
    n = int(mark.read_text()) if mark.exists() else 0
    mark.write_text(str(n + 1))
    if task.chunk.index == 1 and n == 0:
        raise OSError("simulated lost worker")
    return run_chunk(task)


def _broken(task):
    if task.chunk.index == 1:
        raise ValueError("always fails")
    return run_chunk(task)


def test_retries_then_failure_names_the_chunk(shot, tmp_path):
    path, single = shot
    lines = []
    out = tmp_path / "retry.usdc"
    run_farm(str(path), str(out), ProcessOptions(frames="1-4"), 2, str(tmp_path / "c"), report=lines.append,
             fn=_flaky)
    assert any("chunk 2/2 (frames 3-4) failed (attempt 1/3): OSError: simulated lost worker; retrying" in ln
               for ln in lines)
    assert (tmp_path / "c" / "attempts_chunk_0003_0004").read_text() == "2"
    assert stage_differences(single, out, FRAMES) == []
    with pytest.raises(ChunkFailed, match=r"chunk chunk_0003_0004 \(frames 3-4\) failed 2 time\(s\).*always fails"):
        run_farm(str(path), str(tmp_path / "x.usdc"), ProcessOptions(frames="1-4"), 2, str(tmp_path / "d"),
                 retries=1, fn=_broken)
    assert not (tmp_path / "x.usdc").exists()
    assert np.all([p.name != "chunk_0003_0004.json" for p in (tmp_path / "d").iterdir()])


def test_chunked_run_identical_under_a_sun_and_sky(quick_demo, tmp_path):
    """An authored DistantLight and DomeLight over the quick demo: the relit prims' self-shadowing
    (distant lights) estimates their normals in the shadow pass, before the relighting builds their
    probe clusters, which a chunk must still take from the shot's first frame; the sky the avatars
    hide from the room (a dome among the lights) must match too."""
    from pxr import UsdLux

    path = tmp_path / "sun.usda"
    layer = Sdf.Layer.CreateNew(str(path))
    layer.subLayerPaths.append(str(quick_demo))
    layer.Save()
    stage = Usd.Stage.Open(str(path))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.GetIntensityAttr().Set(3.0)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Sky").GetIntensityAttr().Set(0.5)
    stage.Save()
    single = tmp_path / "single.usdc"
    assert main(["process", str(path), "-o", str(single), "--frames", "1-4", "-q"]) == 0
    out = tmp_path / "stitched.usdc"
    run_farm(str(path), str(out), ProcessOptions(frames="1-4"), 2, str(tmp_path / "clips"))
    assert stage_differences(single, out, FRAMES) == []
