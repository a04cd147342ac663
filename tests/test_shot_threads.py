"""The main job's concurrent tasks (shadow tasks of every light and caster, self-shadows, static
scene lookups, the sky task and the probe renders side by side, ``usd_gs.pipeline.shot.run_tasks``)
give the output of a one-thread run, value for value: two moving avatars, a sphere light, a
distant light with a dome (self-shadows, the sun atlas and the sky occlusion all run). Each frame's
authoring runs on the main thread beside the next frame's tasks (``run_tasks``' ``meanwhile``)."""

import numba
import pytest
from farm_compare import stage_differences
from hardening_util import tiny_shot

from usd_gs.cli import main


def _shot(path):
    from pxr import Gf, Usd, UsdGeom, UsdLux

    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim

    tiny_shot(path, n_scene=1500, n_avatar=300, frames=3)
    stage = Usd.Stage.Open(str(path))
    second = random_gaussians(300, degree=1, seed=9)
    second.positions *= 0.12
    second.positions[:, 1] += 0.9
    write_gaussian_prim(stage, "/World/Second", second)
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Second")).AddTranslateOp()
    for f in (1, 2, 3):
        op.Set(Gf.Vec3d(-0.3, 0, 0.05 * f), Usd.TimeCode(f))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-55.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.5)
    save_stage_atomic(stage, path)
    return path


def test_threads_give_the_one_thread_output(tmp_path):
    threads = min(2, numba.config.NUMBA_NUM_THREADS)
    if threads < 2:
        pytest.skip("one CPU thread here: nothing runs side by side")
    shot = _shot(tmp_path / "shot.usda")
    argv = ["process", str(shot), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "--lights", "stage",
            "--aovs", "transmittance,lightScale", "--precision", "float", "--sh-tolerance", "0", "-q"]
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert main([*argv, "-o", str(tmp_path / "one.usdc")]) == 0
        numba.set_num_threads(threads)
        assert main([*argv, "-o", str(tmp_path / "two.usdc")]) == 0
    finally:
        numba.set_num_threads(before)
    assert stage_differences(tmp_path / "one.usdc", tmp_path / "two.usdc", [1, 2, 3]) == []
    # every task ended and every kernel call inside them closed (numba_kernels.thread_chunks.as_task)
    from numba_kernels import thread_chunks

    assert (thread_chunks._RUNNING, thread_chunks._WAITING, thread_chunks._OPEN) == ([0], [0], [])


def test_avatar_shadows_at_samples_spread_to_every_gaussian():
    """_spread_samples: each Gaussian of a sampled receiver takes its nearest sample's value;
    an unsampled receiver keeps its own lookups; samples outside the cone count as lit."""
    import numpy as np

    from usd_gs.pipeline.shot import _spread_samples
    from usd_gs.shadows.shot import Receivers

    class _G:
        def __init__(self, n):
            self.count = n

    drecv = Receivers(_G(10), {"/A": (0, 6), "/B": (6, 10)})
    sel = np.array([0, 3])  # /A sampled at its Gaussians 0 and 3
    nearest = np.array([0, 0, 1, 1, 1, 0])
    maps = {"/A": (sel, nearest), "/B": (np.arange(4), None)}
    idx = np.array([3, 7, 9])  # /A's sample 3, /B's Gaussians 1 and 3 (absolute indices)
    val = np.array([0.25, 0.5, 0.75])
    i, v = _spread_samples((idx, val), ["/A", "/B"], maps, drecv)
    assert i.tolist() == [2, 3, 4, 7, 9] and v.tolist() == [0.25, 0.25, 0.25, 0.5, 0.75]
    # nothing sampled: the lookups as they are
    same = _spread_samples((idx[1:], val[1:]), ["/B"], maps, drecv)
    assert same[0].tolist() == [7, 9] and same[1].tolist() == [0.5, 0.75]


def test_sampled_avatar_shadows_stay_close(tmp_path):
    """moving_receiver_samples on two 300-Gaussian avatars: at the default (4096, more than they
    hold) the output is that of 0 (every Gaussian looks up); at 64 it takes effect, and even on
    these random blobs (no surface for the nearest sample to follow; the bikers' figures are in
    docs/benchmarks.md) the relit colours stay within 2/255 of the full run's on average."""
    import json
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_far_field import dc_difference

    shot = _shot(tmp_path / "two.usda")
    outs = {}
    for name, cfg in (("full", {"moving_receiver_samples": 0}), ("default", {}),
                      ("sampled", {"moving_receiver_samples": 64})):
        c = tmp_path / f"{name}.json"
        c.write_text(json.dumps(cfg))
        outs[name] = tmp_path / f"{name}.lit.usdc"
        assert main(["process", str(shot), "-o", str(outs[name]), "--config", str(c), "-q"]) == 0
    assert stage_differences(outs["full"], outs["default"], [1, 2, 3]) == []
    d = dc_difference(outs["full"], outs["sampled"])
    assert stage_differences(outs["full"], outs["sampled"], [1, 2, 3]) and d.max() > 0.0
    assert np.mean(d) < 2.0 / 255, (np.mean(d) * 255, np.max(d) * 255)


@pytest.mark.parametrize("threads", [1, 2])
def test_run_tasks_runs_meanwhile_on_the_calling_thread_beside_the_tasks(threads):
    """``meanwhile`` runs once, on the caller's thread; the results keep the tasks' order; with two
    threads it runs while a task is still running (the task waits for it), with one before the tasks;
    an exception in it reaches the caller."""
    import threading

    from usd_gs.pipeline import shot

    before = numba.get_num_threads()
    if threads > numba.config.NUMBA_NUM_THREADS:
        pytest.skip("one CPU thread here: nothing runs side by side")
    numba.set_num_threads(threads)
    try:
        started, released = threading.Event(), threading.Event()
        seen = []

        def slow():
            started.set()
            if threads > 1:  # finishes only once meanwhile has run beside it
                assert released.wait(10)
            return "slow"

        def meanwhile():
            if threads > 1:
                started.wait(10)
            seen.append((threading.current_thread() is threading.main_thread(), started.is_set()))
            released.set()

        out = shot.run_tasks([slow, lambda: 1, lambda: 2], meanwhile)
        assert out == ["slow", 1, 2]
        assert seen == [(True, threads > 1)]

        def bad():
            raise RuntimeError("meanwhile failed")

        with pytest.raises(RuntimeError, match="meanwhile failed"):
            shot.run_tasks([lambda: 1, lambda: 2], bad)
    finally:
        numba.set_num_threads(before)


def test_run_tasks_starts_the_longest_tasks_first():
    """With ``costs``, the threads start on the tasks of unknown cost, then the longest; the results
    keep the tasks' order. Two threads: the first two tasks started are the unknown and the longest."""
    import threading

    from usd_gs.pipeline import shot

    before = numba.get_num_threads()
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one CPU thread here: nothing runs side by side")
    numba.set_num_threads(2)
    try:
        lock, started, both = threading.Lock(), [], threading.Event()

        def task(i):
            def run():
                with lock:
                    started.append(i)
                    if len(started) == 2:
                        both.set()
                assert both.wait(10)  # the first two run side by side before any other starts
                return i * 10
            return run

        out = shot.run_tasks([task(i) for i in range(5)], costs=[1.0, 5.0, None, 3.0, 0.5])
        assert out == [0, 10, 20, 30, 40]
        assert set(started[:2]) == {1, 2} and sorted(started) == [0, 1, 2, 3, 4]
    finally:
        numba.set_num_threads(before)


def test_tasks_without_a_cost_start_first_and_largest_first():
    """``run_tasks``' start order: the tasks that have not run yet (no cost: a shot's first frame)
    before the others, by their size proxy, largest first (ties as given); then by cost."""
    from usd_gs.pipeline import shot

    costs = [0.2, None, 0.9, None, None, 0.5]
    assert shot._start_order(6, costs, sizes=[0, 10, 0, 30, 10, 0]) == [3, 1, 4, 2, 5, 0]
    assert shot._start_order(6, costs) == [1, 3, 4, 2, 5, 0]
    assert shot._start_order(3, None, sizes=[1, 3, 2]) == [1, 2, 0]
    assert shot._start_order(3) == [0, 1, 2]


def test_normals_estimated_ahead_side_by_side_give_the_same_output(tmp_path, monkeypatch):
    """The relit prims' normals due at the first frame are estimated side by side before the
    frame's relighting inputs (``ShotProcessor._estimate_normals_ahead``): the two avatars' both,
    once; the output is that of estimating them one after the other where they are needed."""
    from usd_gs.pipeline import shot as shot_mod

    shot = _shot(tmp_path / "shot.usda")
    argv = ["process", str(shot), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "--lights", "stage",
            "--precision", "float", "--sh-tolerance", "0", "-q"]
    plain = shot_mod.ShotProcessor._estimate_normals_ahead
    ahead = []

    def spy(self, prims, frame):
        plain(self, prims, frame)
        ahead.append(sorted(self._normals_ahead))

    monkeypatch.setattr(shot_mod.ShotProcessor, "_estimate_normals_ahead", spy)
    assert main([*argv, "-o", str(tmp_path / "ahead.usdc")]) == 0
    assert ahead == [["/World/Avatar", "/World/Second"], [], []]
    monkeypatch.setattr(shot_mod.ShotProcessor, "_estimate_normals_ahead", lambda self, prims, frame: None)
    assert main([*argv, "-o", str(tmp_path / "inline.usdc")]) == 0
    assert stage_differences(tmp_path / "ahead.usdc", tmp_path / "inline.usdc", [1, 2, 3]) == []


def test_moving_casters_pack_and_bound_each_prim_once_for_every_task():
    """The shadow tasks share each moving caster's packing and the moving prims' bounding spheres:
    computed once by the first task that asks (here eight threads at once), equal to the direct
    ``prepare_occluders`` / ``prim_spheres`` / ``occluder_sphere`` values."""
    import threading

    import numpy as np

    from usd_gs.pipeline.shot import _MovingCasters
    from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders
    from usd_gs.shadows.shot import Receivers, occluder_sphere, prim_spheres
    from usd_gs.synthetic import random_gaussians

    cfg = DGSMConfig()
    sets = {"/A": random_gaussians(400, 0, seed=1), "/B": random_gaussians(300, 1, seed=2),
            "/C": random_gaussians(200, 0, seed=3)}  # /C casts but receives nothing
    sets["/B"].positions[:] += 2.0
    drecv = Receivers.build([(p, sets[p]) for p in ("/A", "/B")])
    calls = []

    def pack(q):
        calls.append(q)
        return prepare_occluders(sets[q], cfg)

    movers = _MovingCasters(["/A", "/B", "/C"], pack, sets, drecv, cfg.k_sigma)
    got = {}
    start = threading.Barrier(8)

    def task(i):
        start.wait()
        q = ["/A", "/B", "/C"][i % 3]
        got[i] = (q, movers.packed(q), movers.bound(q), movers.receiver_spheres())

    threads = [threading.Thread(target=task, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(calls) == ["/A", "/B", "/C"]  # each caster packed once
    spheres = prim_spheres(drecv, cfg.k_sigma)
    for q, packed, bound, receivers in got.values():
        want = prepare_occluders(sets[q], cfg)
        (occ, dir_dep, cov6), (occ_w, dir_dep_w, cov6_w) = packed, want
        assert np.array_equal(occ, occ_w) and np.array_equal(cov6, cov6_w) and dir_dep == dir_dep_w
        c, r = spheres[q] if q in spheres else occluder_sphere(sets[q], cfg.k_sigma)
        assert np.array_equal(bound[0], c) and bound[1] == r
        assert receivers.keys() == {"/A", "/B"} and all(
            np.array_equal(receivers[p][0], spheres[p][0]) and receivers[p][1] == spheres[p][1] for p in receivers)
    assert movers.bound("/C")[1] == occluder_sphere(sets["/C"], cfg.k_sigma)[1]


def test_reading_the_next_frame_ahead_gives_the_plain_reads(tmp_path, monkeypatch, capsys):
    """The moving prims of frame f + 1 are read beside frame f's shadow tasks: the output is the one
    of reading each frame at its start, and an error in frame 3's data stops the run as it did
    (exit 2, the same message)."""
    from pxr import Gf, Usd, UsdGeom

    import usd_gs.pipeline.shot as shot

    path = _shot(tmp_path / "shot.usda")
    argv = ["process", str(path), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "--lights", "stage",
            "--aovs", "transmittance,lightScale", "--precision", "float", "--sh-tolerance", "0", "-q"]
    served, plain_frame = [], shot.ShotProcessor._frame

    def frame(self, f, *a):
        if self._ahead is not None and self._ahead[0] == f and self._ahead[2] is None:
            served.append(f)
        return plain_frame(self, f, *a)

    with monkeypatch.context() as m:
        m.setattr(shot.ShotProcessor, "_frame", frame)
        assert main([*argv, "-o", str(tmp_path / "ahead.usdc")]) == 0
    assert served == [2.0, 3.0]
    with monkeypatch.context() as m:
        m.setattr(shot.ShotProcessor, "_read_ahead", lambda self, f: None)
        assert main([*argv, "-o", str(tmp_path / "plain.usdc")]) == 0
    assert stage_differences(tmp_path / "ahead.usdc", tmp_path / "plain.usdc", [1, 2, 3]) == []

    stage = Usd.Stage.Open(str(path))  # frame 3's translation not finite
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Second")).GetOrderedXformOps()[0].Set(
        Gf.Vec3d(float("nan"), 0, 0), Usd.TimeCode(3))
    stage.GetRootLayer().Export(str(tmp_path / "bad.usda"))
    bad = [argv[0], str(tmp_path / "bad.usda"), *argv[2:]]
    capsys.readouterr()
    assert main([*bad, "-o", str(tmp_path / "bad_ahead.usdc")]) == 2
    ahead_err = capsys.readouterr().err
    with monkeypatch.context() as m:
        m.setattr(shot.ShotProcessor, "_read_ahead", lambda self, f: None)
        assert main([*bad, "-o", str(tmp_path / "bad_plain.usdc")]) == 2
    plain_err = capsys.readouterr().err
    assert "/World/Second (time 3)" in ahead_err
    assert ahead_err.replace("bad_ahead", "X") == plain_err.replace("bad_plain", "X")
    assert not (tmp_path / "bad_ahead.usdc").exists()


def test_far_layers_of_two_probes_in_one_batch_give_the_same_output(tmp_path, monkeypatch):
    """Two relit avatars in different far-field cells and a static block 40 m away: the first frame
    renders both far layers in one batch task (``ShotProcessor._far_batches``), the later frames
    keep them (no batch); the output, probes included, is that of each probe rendering its own."""
    from dataclasses import replace

    from pxr import Gf, Usd, UsdGeom

    from usd_gs.pipeline import shot as shot_mod
    from usd_gs.relight import far_field
    from usd_gs.synthetic import random_gaussians
    from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim

    shot = _shot(tmp_path / "shot.usda")
    stage = Usd.Stage.Open(str(shot))
    far = random_gaussians(2000, degree=1, seed=11)
    far.positions[:, 0] += 40.0
    far.scales[:] = 0.2
    write_gaussian_prim(stage, "/World/FarBlock", replace(far, log_scales=None))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Second")).GetOrderedXformOps()[0].Set(Gf.Vec3d(-2.5, 0, 0.0),
                                                                                      Usd.TimeCode(1))
    save_stage_atomic(stage, shot)
    argv = ["process", str(shot), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "--lights", "stage",
            "--precision", "float", "--sh-tolerance", "0", "-q"]
    planned = []
    real = far_field.FarLayers.batch

    def spy(self, requests):
        got = real(self, requests)
        planned.append(None if got is None else len(got.plans))
        return got

    monkeypatch.setattr(far_field.FarLayers, "batch", spy)
    assert main([*argv, "-o", str(tmp_path / "batch.usdc")]) == 0
    assert planned == [2, None, None]
    monkeypatch.setattr(shot_mod.ShotProcessor, "_far_batches", lambda self, jobs: [])
    assert main([*argv, "-o", str(tmp_path / "own.usdc")]) == 0
    assert stage_differences(tmp_path / "batch.usdc", tmp_path / "own.usdc", [1, 2, 3]) == []
    probes = sorted(p.name for p in (tmp_path / "batch_probes").iterdir())
    assert probes and all((tmp_path / "batch_probes" / n).read_bytes() == (tmp_path / "own_probes" / n).read_bytes()
                          for n in probes)
