"""Relighting + shadow time per frame against the number of moving avatars (issue 16): 1, 2, 4, 8
bikers in the demo room, one run (not a test).

Each shot sublayers the default demo's room (``stages/demo_data/room.usdc``: 304,893 Gaussians, its
two lamps estimated as in the demo) and references the demo's animated biker (152,746 Gaussians)
N times, each copy under an Xform offset on a ring of 1.3 m radius around the room's centre (so they
shadow each other and share the lamps). ``usdgs process`` runs in this process for ``--frames``;
per frame the shadow pass (every light's moving-caster DGSMs, self-shadows, static-scene lookups
and the probe renders, which run beside them) and the relighting (``_relight_jobs``,
``_relight_pass``) are timed, not reading or authoring. Printed per N: the
mean over frames 2.. (frame 1 apart: it builds the shot's caches) of shadows + relighting, its
ratio to N = 1, and the whole job's s/frame.

With ``--exact-count N`` / ``--merge-count N`` (4 by default, 0: skip) N avatars run again with
every moving receiver Gaussian looking up the other avatars' shadows (``moving_receiver_samples``
0) / with every Gaussian of the other avatars drawn in each probe (``probe_merge_cell`` 0), and
their time and the default's relit colour difference from them are printed; ``--rounds R`` adds
R - 1 more pairs of runs (the default, then that setting), alternating (this host's load moves a
single run's figures more than such a setting does). ``--table-rounds R`` runs the counts R times,
alternating, and prints each round's ratios to N = 1 and their median.

    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_avatar_count.py [--frames 1-6] [--counts 1,2,4,8]
        [--table-rounds R]
    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_avatar_count.py --tasks --frames 1-4 --counts 1,4
        [--config FILE] [--alone]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def make_shot(demo_data: Path, n: int, folder: Path, only: int | None = None) -> Path:
    """A shot of the demo room and ``n`` bikers (module docstring), or with ``only`` the biker at
    that place of the ``n``-ring alone; returns its root layer."""
    from pxr import Gf, Sdf, Usd, UsdGeom

    src = Sdf.Layer.FindOrOpen(str(demo_data.parent / "demo.usda"))
    path = folder / (f"bikers_{n}.usda" if only is None else f"biker_{only}_of_{n}.usda")
    stage = Usd.Stage.CreateNew(str(path))
    for key in ("upAxis", "metersPerUnit", "timeCodesPerSecond", "startTimeCode", "endTimeCode", "framesPerSecond"):
        if src.pseudoRoot.HasInfo(key):
            stage.GetRootLayer().pseudoRoot.SetInfo(key, src.pseudoRoot.GetInfo(key))
    stage.GetRootLayer().subLayerPaths.append(str(demo_data / "room.usdc"))
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    for i in range(n) if only is None else [only]:
        ring = UsdGeom.Xform.Define(stage, f"/World/Ring{i}")
        a = 2.0 * math.pi * i / max(n, 1)
        offset = (0.0, 0.0, 0.0) if i == 0 else (1.3 * math.cos(a) - 1.3, 0.0, 1.3 * math.sin(a))
        ring.AddTranslateOp().Set(Gf.Vec3d(*offset))
        biker = stage.DefinePrim(f"/World/Ring{i}/Biker")
        biker.GetReferences().AddReference(str(demo_data / "biker.usdc"), "/World/Biker")
    stage.GetRootLayer().Save()
    return path


def run(stage: Path, out: Path, frames: str, config: Path | None = None) -> dict:
    """One in-process ``usdgs process``: the summary plus per-frame shadow and relight seconds."""
    import usd_gs.pipeline.shot as shot
    from usd_gs.cli import main
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()  # (as the usdgs console script sets the process up)

    per_frame: list[float] = []
    names = ("_shadow_pass", "_relight_jobs", "_relight_pass")  # shadows (and probes), relighting
    plain = {name: getattr(shot.ShotProcessor, name) for name in names + ("_frame",)}

    def timed(name):
        def call(self, *a, **k):
            t = time.perf_counter()
            try:
                return plain[name](self, *a, **k)
            finally:
                per_frame[-1] += time.perf_counter() - t
        return call

    def frame(self, *a, **k):
        per_frame.append(0.0)
        return plain["_frame"](self, *a, **k)

    for name in names:
        setattr(shot.ShotProcessor, name, timed(name))
    shot.ShotProcessor._frame = frame
    try:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            extra = ["--config", str(config)] if config else []
            assert main(["process", str(stage), "-o", str(out), "--frames", frames, "--json", *extra]) == 0
        summary = json.loads(buf.getvalue())
    finally:
        for name, f in plain.items():
            setattr(shot.ShotProcessor, name, f)
    summary["frame_seconds"] = per_frame
    return summary


def run_tasks_serial(stage: Path, out: Path, frames: str, config: Path | None = None) -> dict:
    """One in-process ``usdgs process`` on one thread with the shadow pass's tasks run one after the
    other: ``{task function name: s/frame}`` over frames 2.. (each task's own time: moving-caster
    DGSMs ``_caster_task``, the static scene's shadows on moving receivers ``_scene_task``, the
    probe renders and transfers ``_probe_task``), plus ``FRAME``, the whole frame."""
    import numba

    import usd_gs.pipeline.shot as shot
    from usd_gs.cli import main
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()  # (as the usdgs console script sets the process up)

    seconds: dict = {}
    frame_no = [0]

    def serial(tasks, meanwhile=None, costs=None, sizes=None):  # (in the given order: costs, sizes only reorder)
        if meanwhile is not None:
            meanwhile()
        out = []
        for task in tasks:
            t = time.perf_counter()
            out.append(task())
            if frame_no[0] > 1:
                inner = getattr(task, "__wrapped__", task)  # (the shadow pass times its tasks: shot._timed)
                name = getattr(getattr(inner, "func", inner), "__name__", "other")
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t
        return out

    plain_run, plain_frame, threads = shot.run_tasks, shot.ShotProcessor._frame, numba.get_num_threads()

    def frame(self, *a, **k):
        frame_no[0] += 1
        t = time.perf_counter()
        try:
            return plain_frame(self, *a, **k)
        finally:
            if frame_no[0] > 1:
                seconds["FRAME"] = seconds.get("FRAME", 0.0) + time.perf_counter() - t

    shot.run_tasks, shot.ShotProcessor._frame = serial, frame
    numba.set_num_threads(1)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            extra = ["--config", str(config)] if config else []
            assert main(["process", str(stage), "-o", str(out), "--frames", frames, "-q", *extra]) == 0
    finally:
        shot.run_tasks, shot.ShotProcessor._frame = plain_run, plain_frame
        numba.set_num_threads(threads)
    steady = max(frame_no[0] - 1, 1)
    return {k: v / steady for k, v in seconds.items() if k != "<lambda>"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="1-6")
    ap.add_argument("--counts", default="1,2,4,8")
    ap.add_argument("--demo-data", default=str(REPO / "stages" / "demo_data"))
    ap.add_argument("--exact-count", type=int, default=4,
                    help="also run this many avatars with every moving receiver Gaussian looking up the other "
                         "avatars' shadows (moving_receiver_samples 0) and print the relit colour difference "
                         "(0: skip)")
    ap.add_argument("--merge-count", type=int, default=4,
                    help="also run this many avatars with every Gaussian of the other avatars drawn in each probe "
                         "(probe_merge_cell 0) and print its time and the relit colour difference (0: skip)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="pairs of runs (the default, then the other setting) for --exact-count / --merge-count: "
                         "the first after the main table, the others alternating")
    ap.add_argument("--table-rounds", type=int, default=1,
                    help="run the counts this many times, alternating (each round's ratios and their median printed)")
    ap.add_argument("--config", type=Path, default=None, help="a usdgs process --config file for every run")
    ap.add_argument("--tasks", action="store_true",
                    help="instead: each shadow-pass task timed on one thread, one after the other (s/frame over "
                         "frames 2..), per avatar count")
    ap.add_argument("--alone", action="store_true",
                    help="with --tasks: also each biker of the ring alone, at its place, and the sum of their "
                         "times (what the avatars cost without each other)")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_avatars_"))
    counts = [int(c) for c in a.counts.split(",")]
    if a.tasks:
        print(f"frames {a.frames}; one thread, tasks one after the other; s/frame over frames 2..")
        for n in counts:
            t = run_tasks_serial(make_shot(Path(a.demo_data), n, work), work / f"bikers_{n}.tasks.lit.usdc", a.frames,
                                 a.config)
            print(f"{n} avatar(s): " + ", ".join(f"{k} {v:.3f}" for k, v in sorted(t.items(), key=lambda kv: -kv[1])))
            if a.alone and n > 1:
                total: dict = {}
                for i in range(n):
                    t1 = run_tasks_serial(make_shot(Path(a.demo_data), n, work, only=i),
                                          work / f"biker_{i}_of_{n}.tasks.lit.usdc", a.frames, a.config)
                    print(f"  biker {i} of {n} alone: " + ", ".join(f"{k} {v:.3f}" for k, v in sorted(t1.items())))
                    for k, v in t1.items():
                        total[k] = total.get(k, 0.0) + v
                print(f"  the {n} alone, summed: " + ", ".join(
                    f"{k} {v:.3f} (together {t.get(k, 0.0) / v:.2f}x)" for k, v in sorted(total.items()) if v > 0))
        return
    shots = {n: make_shot(Path(a.demo_data), n, work) for n in counts}
    ratios = {n: [] for n in counts}
    for r in range(a.table_rounds):
        rows = []
        for n in counts:
            s = run(shots[n], work / f"bikers_{n}.lit.usdc", a.frames, a.config)
            steady = s["frame_seconds"][1:] or s["frame_seconds"]
            rows.append((n, sum(steady) / len(steady), s["seconds_per_frame"], s["frame_seconds"][0]))
        for n, steady, _, _ in rows:
            ratios[n].append(steady / rows[0][1])
        if a.table_rounds > 1:
            print(f"round {r + 1}: " + ", ".join(f"{n} avatar(s) {steady:.3f} s/frame ({steady / rows[0][1]:.2f}x)"
                                                  for n, steady, _, _ in rows), flush=True)
    if a.table_rounds > 1:
        print(f"x N=1 over {a.table_rounds} rounds (median, min, max): " + ", ".join(
            f"{n}: {np.median(v):.2f} ({min(v):.2f}-{max(v):.2f})" for n, v in ratios.items())
              + " (the table: the last round)")
    base = rows[0][1]
    print(f"frames {a.frames}; per frame: shadows (incl. probe renders) + relighting, mean over frames 2..")
    print(f"{'avatars':>7s} {'s/frame':>8s} {'x N=1':>6s} {'x N':>6s} {'frame 1':>8s} {'job s/frame':>12s}")
    for n, steady, job, first in rows:
        print(f"{n:7d} {steady:8.3f} {steady / base:6.2f} {steady / base / n:6.2f} {first:8.2f} {job:12.3f}")
    for n, config, what in ((a.exact_count, {"moving_receiver_samples": 0},
                             "every moving receiver Gaussian looking up (moving_receiver_samples 0)"),
                            (a.merge_count, {"probe_merge_cell": 0},
                             "every Gaussian of the other avatars drawn in each probe (probe_merge_cell 0)")):
        if n in counts:
            against(work, n, a.frames, config, what, base, a.rounds)


def _steady(s: dict) -> float:
    steady = s["frame_seconds"][1:] or s["frame_seconds"]
    return sum(steady) / len(steady)


def against(work: Path, n: int, frames: str, config: dict, what: str, base: float, rounds: int = 1) -> None:
    """Run ``n`` avatars again with ``config`` and print its time and the default's relit colour
    difference from it; then ``rounds - 1`` more pairs (the default, then ``config``), alternating,
    each pair's shadows + relighting s/frame."""
    from bench_far_field import dc_difference

    cfg = work / f"{next(iter(config))}.json"
    cfg.write_text(json.dumps(config))
    out = work / f"bikers_{n}.{next(iter(config))}.lit.usdc"
    s = run(work / f"bikers_{n}.usda", out, frames, cfg)
    steady = s["frame_seconds"][1:] or s["frame_seconds"]
    d = dc_difference(work / f"bikers_{n}.lit.usdc", out)
    print(f"{n} avatars, {what}: {sum(steady) / len(steady):.3f} s/frame ({sum(steady) / len(steady) / base:.2f}x "
          f"N=1); relit DC colour of the default against it ({d.size:,} values): max {255 * d.max():.2f}/255, mean "
          f"{255 * d.mean():.4f}/255, 99.9th percentile {255 * np.percentile(d, 99.9):.3f}/255, "
          f"{int((d > 1 / 255).sum())} above 1/255, {int((d > 4 / 255).sum())} above 4/255")
    for r in range(2, rounds + 1):
        mine = _steady(run(work / f"bikers_{n}.usda", work / f"bikers_{n}.round.lit.usdc", frames))
        theirs = _steady(run(work / f"bikers_{n}.usda", out, frames, cfg))
        print(f"  round {r}: default {mine:.3f} s/frame, {next(iter(config))} {config[next(iter(config))]} "
              f"{theirs:.3f} ({mine / theirs:.3f}x)")


if __name__ == "__main__":
    main()
