"""Probe renders with a far static scene (issue 16): the far-field layer cache against drawing
everything, speed and error side by side in one run (not a test).

Shots: the default demo, and the demo plus a bricked block of 9x the room's Gaussians 40 m away
(``bench_process.make_large_shot``). Each runs ``usdgs process`` in this process for ``--frames``,
with the relit prims' probe renders and transfers (``ShotProcessor._probe_task``: the other moving
prims merged where far enough, ``usd_gs.relight.avatar.probe_transfer``) timed per call; the large
shot twice, with ``probe_far_radius`` 0 (every probe draws everything: the reference) and with the
default far field. Printed per run: s/frame of the whole job, probe
seconds per frame after frame 1 (frame 1 apart; far layers drawn together in a task of their own,
``usd_gs.relight.far_field.FarBatch``, count in their frame's probe time), far layers rendered; and the relit prims'
displayed DC colour against the reference run (max / mean / 99.9th percentile of |difference|,
all frames and prims). The demo has nothing beyond the radius: its output is the same with and
without the far field.

    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_far_field.py [--frames 1-8] [--workdir DIR]
        [--rounds R] [--threads T]

``--rounds R``: the demo and the far-field run R times each, alternating (this host's load moves
from minute to minute), with each round's ratio printed; ``--threads T``: kernel and task threads
(numba's count; 1: each probe task's time is its CPU time, not shared with the task beside it).
"""

from __future__ import annotations

import argparse
import collections
import json
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from bench_process import make_large_shot

C0 = 0.28209479177387814


def run(stage: Path, out: Path, frames: str, config: dict | None) -> dict:
    """One in-process ``usdgs process``: its summary plus probe-call times and far-layer renders."""
    import usd_gs.pipeline.shot as shot
    import usd_gs.relight.far_field as far_field
    from usd_gs.cli import main
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()  # (as the usdgs console script sets the process up)

    calls, fields, batches = [], [], []
    plain, init = shot.ShotProcessor._probe_task, far_field.FarField.__init__
    plans = far_field.FarLayers._render_plans
    inside = threading.local()

    def timed(*a, **k):  # (the probe task: the other prims' merges it makes, the render, the transfer)
        t = time.perf_counter()
        inside.probe = True
        try:
            return plain(*a, **k)
        finally:
            inside.probe = False
            calls.append(time.perf_counter() - t)

    def batched(self, batch):  # (far layers drawn together: in a probe task's time where one draws them)
        t, done = time.perf_counter(), len(calls)
        try:
            return plans(self, batch)
        finally:
            if not getattr(inside, "probe", False):
                batches.append((done, time.perf_counter() - t))

    def tracked(self, *a, **k):
        init(self, *a, **k)
        fields.append(self)

    args = ["process", str(stage), "-o", str(out), "--frames", frames, "--json"]
    if config:
        cfg = out.with_suffix(".config.json")
        cfg.write_text(json.dumps(config))
        args += ["--config", str(cfg)]
    shot.ShotProcessor._probe_task, far_field.FarField.__init__ = timed, tracked
    far_field.FarLayers._render_plans = batched
    try:
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert main(args) == 0
        summary = json.loads(buf.getvalue())
    finally:
        shot.ShotProcessor._probe_task, far_field.FarField.__init__ = plain, init
        far_field.FarLayers._render_plans = plans
    n = summary["frames"]["count"]
    per = len(calls) // n if n else 0
    first = sum(s for done, s in batches if done < per)  # (a batch task of the first frame)
    summary["probe_steady"] = (sum(calls[per:]) + sum(batches_s for _, batches_s in batches) - first) / max(1, n - 1)
    summary["probe_first"] = sum(calls[:per]) + first
    summary["far_renders"] = sum(f.renders for f in fields)
    return summary


def dc_difference(a: Path, b: Path) -> np.ndarray:
    """|displayed DC colour difference| of every relit prim's SH, every frame, between two outputs."""
    from pxr import Usd

    sa, sb = Usd.Stage.Open(str(a)), Usd.Stage.Open(str(b))
    out = []
    for prim in sa.Traverse():
        for name in ("radiance:sphericalHarmonicsCoefficientsh", "radiance:sphericalHarmonicsCoefficients"):
            at = prim.GetAttribute(name)
            if not at or not at.GetNumTimeSamples():
                continue
            bt = sb.GetPrimAtPath(prim.GetPath()).GetAttribute(name)
            k = (int(prim.GetAttribute("radiance:sphericalHarmonicsDegree").Get() or 0) + 1) ** 2
            for t in at.GetTimeSamples():
                va, vb = (np.asarray(x.Get(t), np.float64).reshape(-1, k, 3)[:, 0] for x in (at, bt))
                out.append(np.abs(C0 * (va - vb)).ravel())
            break
    return np.concatenate(out) if out else np.zeros(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="1-8")
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--demo", default="stages/demo.usda")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    if a.threads:
        import numba

        numba.set_num_threads(a.threads)
    work = Path(a.workdir or tempfile.mkdtemp(prefix="bench_far_"))
    work.mkdir(parents=True, exist_ok=True)
    large = make_large_shot(Path(a.demo).resolve(), work)
    runs = collections.OrderedDict()
    runs["large, far field off"] = run(large, work / "large_off.lit.usdc", a.frames, {"probe_far_radius": 0.0})
    ratios = []
    for r in range(a.rounds):
        runs["demo"] = run(Path(a.demo).resolve(), work / "demo.lit.usdc", a.frames, None)
        runs["large, far field"] = run(large, work / "large_far.lit.usdc", a.frames, None)
        ratios.append(runs["large, far field"]["probe_steady"] / runs["demo"]["probe_steady"])
        if a.rounds > 1:
            print(f"round {r + 1}: probe s/frame demo {runs['demo']['probe_steady']:.3f}, far field "
                  f"{runs['large, far field']['probe_steady']:.3f} ({ratios[-1]:.2f}x)", flush=True)
    if a.rounds > 1:
        print(f"far field / demo over {a.rounds} rounds: median {np.median(ratios):.2f}x, "
              f"min {min(ratios):.2f}x, max {max(ratios):.2f}x (the table: the last round)")
    runs.move_to_end("large, far field off")
    runs.move_to_end("large, far field")
    print(f"frames {a.frames}; threads {a.threads or 'default'}; probe = the relit prims' probe renders + transfers, "
          f"s/frame after frame 1")
    print(f"{'run':24s} {'s/frame':>8s} {'probe':>7s} {'probe f1':>9s} {'far layers':>11s}")
    for name, s in runs.items():
        print(f"{name:24s} {s['seconds_per_frame']:8.3f} {s['probe_steady']:7.3f} {s['probe_first']:9.2f} "
              f"{s['far_renders']:11d}")
    base = runs["demo"]["probe_steady"]
    print(f"probe time / demo's: far field off {runs['large, far field off']['probe_steady'] / base:.2f}x, "
          f"far field {runs['large, far field']['probe_steady'] / base:.2f}x (same run)")
    d = dc_difference(work / "large_far.lit.usdc", work / "large_off.lit.usdc")
    print(f"relit DC colour, far field vs off: max {d.max():.5f} ({255 * d.max():.2f}/255), mean {d.mean():.2e}, "
          f"p99.9 {np.quantile(d, 0.999):.5f}")


if __name__ == "__main__":
    main()
