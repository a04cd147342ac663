"""Capture I/O figures (issue 14), whole processes side by side in one run (not a test).

1. ``usdgs import`` of the flowers LOD set, level 0 (542k Gaussians, 4 SOG chunks) to usdc,
   against PlayCanvas splat-transform converting the same files to INRIA PLY: wall and CPU
   seconds (median and best of ``--repeat``, the processes alternating) and peak RSS of each
   process, and the speed-ups of the medians (wall, and CPU for a loaded machine).
   ``--baseline DIR`` also runs another checkout's ``python -m usd_gs.cli`` (a before/after
   in the same run; its output is compared attribute by attribute with this checkout's).
   ``--check`` also compares the two decodes (tests/capture_testutil.py tolerances).
   ``--only-flowers`` skips figures 2 and 3.
   Each timed import command runs once untimed first, and the children run without
   ``PYTHONDONTWRITEBYTECODE`` (so Python's .pyc caches exist, as after a ``pip install``;
   a shell that sets it would time the compiling of every .py file on each start).
2. Sequence import of the 50-frame monkey (``monkey_####.sog --frames 1-50``): wall seconds,
   peak RSS, output size, and which attributes were authored once (static).
3. ``usdgs export`` of 48 frames of a processed demo stage (``--processed``, the output of
   ``usdgs process stages/demo.usda``) as ``.splat``: seconds per frame.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_capture_io.py [--repeat 3] [--check] \\
        [--processed /tmp/x/demo.lit.usdc] [--baseline ../old-checkout] [--only-flowers]

Writes nothing in the repository; temporary files go to a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
USDGS = [sys.executable, "-m", "usd_gs.cli"] if not (REPO / ".venv" / "bin" / "usdgs").exists() else \
    [str(REPO / ".venv" / "bin" / "usdgs")]


def splat_transform() -> str | None:
    for c in (os.environ.get("USDGS_SPLAT_TRANSFORM"), str(REPO / ".ci/node/node_modules/.bin/splat-transform"),
              shutil.which("splat-transform")):
        if c and os.path.isfile(c):
            return c
    return None


#: the children's environment: .pyc caches written and used (see the module docstring)
CHILD_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def run(cmd: list[str], cwd: str | None = None) -> tuple[float, float, float]:
    """(wall s, peak RSS MB, CPU s = user + system) of one child process; raises on failure."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=cwd, env=CHILD_ENV)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {err[-1500:]}")
    return wall, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def summary(runs: list[tuple[float, float, float]]) -> dict[str, float]:
    """Median and best wall and CPU seconds, largest peak RSS, of ``run`` results."""
    import statistics

    return {"s": statistics.median(r[0] for r in runs), "best_s": min(r[0] for r in runs),
            "cpu_s": statistics.median(r[2] for r in runs), "best_cpu_s": min(r[2] for r in runs),
            "peak_mb": max(r[1] for r in runs)}


def same_stage(a: Path, b: Path) -> str:
    """'identical' when every prim, authored attribute (value, metadata, time samples) and the
    stage metadata of two stages agree exactly; else the first difference."""
    import numpy as np
    from pxr import Usd

    sa, sb = Usd.Stage.Open(str(a)), Usd.Stage.Open(str(b))
    if sa.GetRootLayer().pseudoRoot.ListInfoKeys() != sb.GetRootLayer().pseudoRoot.ListInfoKeys():
        return "stage metadata keys differ"
    for key in sa.GetRootLayer().pseudoRoot.ListInfoKeys():
        if sa.GetRootLayer().pseudoRoot.GetInfo(key) != sb.GetRootLayer().pseudoRoot.GetInfo(key):
            return f"stage metadata '{key}' differs"
    pa, pb = list(sa.Traverse()), list(sb.Traverse())
    if [p.GetPath() for p in pa] != [p.GetPath() for p in pb]:
        return "prim paths differ"
    for x, y in zip(pa, pb, strict=True):
        if x.GetTypeName() != y.GetTypeName() or x.GetAppliedSchemas() != y.GetAppliedSchemas():
            return f"{x.GetPath()}: type or schemas differ"
        names = [at.GetName() for at in x.GetAuthoredAttributes()]
        if names != [at.GetName() for at in y.GetAuthoredAttributes()]:
            return f"{x.GetPath()}: authored attributes differ"
        for nm in names:
            u, v = x.GetAttribute(nm), y.GetAttribute(nm)
            if u.GetAllMetadata() != v.GetAllMetadata() or u.GetTimeSamples() != v.GetTimeSamples():
                return f"{x.GetPath()}.{nm}: metadata or time samples differ"
            for t in [Usd.TimeCode.Default(), *map(Usd.TimeCode, u.GetTimeSamples())]:
                p, q = u.Get(t), v.Get(t)
                if u.GetTypeName().isArray:
                    p, q = np.asarray(p), np.asarray(q)
                    if p.dtype != q.dtype or p.shape != q.shape or p.tobytes() != q.tobytes():
                        return f"{x.GetPath()}.{nm}: values differ"
                elif p != q:
                    return f"{x.GetPath()}.{nm}: {p!r} != {q!r}"
    return "identical"


def best(cmd: list[str], repeat: int) -> tuple[float, float, float]:
    """Best wall time, largest peak RSS and best CPU time over ``repeat`` runs."""
    runs = [run(cmd) for _ in range(repeat)]
    return min(r[0] for r in runs), max(r[1] for r in runs), min(r[2] for r in runs)


class _Done(Exception):
    """The figures asked for are measured."""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--check", action="store_true", help="compare the flowers LOD 0 decodes too")
    ap.add_argument("--processed", default="/tmp/x/demo.lit.usdc",
                    help="processed demo stage for the export figure (skipped when missing)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    ap.add_argument("--baseline", help="another checkout of usd-gs: its import runs too (before/after)")
    ap.add_argument("--only-flowers", action="store_true", help="figure 1 only")
    args = ap.parse_args()
    figures: dict[str, object] = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench_capture_"))
    try:
        # 1. flowers LOD 0
        lod = DATA / "scenes" / "flowers" / "lod-meta.json"
        ours_cmd = [*USDGS, "import", str(lod), "--lod", "0", "-o", str(tmp / "flowers.usdc"), "-q"]
        st = splat_transform()
        ref_cmd = [st, "-q", "-w", "-L", "0", str(lod), str(tmp / "flowers.ply")] if st else None
        base_cmd = None
        if args.baseline:
            base = Path(args.baseline).resolve()
            # run in that checkout (python -m puts the working directory first on sys.path)
            base_cmd = ["env", f"PYTHONPATH={base}", sys.executable, "-m", "usd_gs.cli", "import", str(lod),
                        "--lod", "0", "-o", str(tmp / "flowers_baseline.usdc"), "-q"]
        cmds = {"ours": ours_cmd, "splat_transform": ref_cmd, "baseline": base_cmd}
        runs: dict[str, list] = {k: [] for k, c in cmds.items() if c}
        for k in runs:  # untimed: writes the .pyc caches, warms the file cache
            run(cmds[k], cwd=str(base) if k == "baseline" else None)
        for _ in range(args.repeat):
            for k in runs:
                runs[k].append(run(cmds[k], cwd=str(base) if k == "baseline" else None))
        res = {k: summary(v) for k, v in runs.items()}
        names = {"ours": "flowers_import", "splat_transform": "splat_transform", "baseline": "baseline_import"}
        for k, r in res.items():
            figures.update({f"{names[k]}_{m}": round(v, 3) for m, v in r.items()})
        if st:
            figures.update(speedup_wall=round(res["splat_transform"]["s"] / res["ours"]["s"], 2),
                           speedup_cpu=round(res["splat_transform"]["cpu_s"] / res["ours"]["cpu_s"], 2))
        else:
            figures["splat_transform_s"] = "splat-transform not found (npm install --prefix .ci/node ...)"
        if base_cmd:
            figures.update(speedup_vs_baseline_wall=round(res["baseline"]["s"] / res["ours"]["s"], 2),
                           speedup_vs_baseline_cpu=round(res["baseline"]["cpu_s"] / res["ours"]["cpu_s"], 2))
        figures["flowers_usdc_mb"] = round((tmp / "flowers.usdc").stat().st_size / 2 ** 20, 1)
        # (the decode check runs last: a child's peak RSS on Linux starts from this process's)

        if args.only_flowers:
            raise _Done
        # 2. the monkey sequence
        pattern = DATA / "sequences" / "monkey" / "monkey_####.sog"
        out = tmp / "monkey.usdc"
        seq_cmd = [*USDGS, "import", str(pattern), "-o", str(out), "--frames", "1-50", "--fps", "24",
                   "--prim", "/Monkey", "--role", "avatar", "-q"]
        run(seq_cmd)  # untimed (.pyc caches)
        seq = best(seq_cmd, args.repeat)
        from pxr import Usd  # after the timed runs (see the peak-RSS note above)

        mstage = Usd.Stage.Open(str(out))
        prim = mstage.GetPrimAtPath("/Monkey")
        static = sorted(a.GetName() for a in prim.GetAttributes() if a.HasAuthoredValue() and
                        a.GetNumTimeSamples() == 0 and a.GetName() not in ("radiance:sphericalHarmonicsDegree",))
        figures.update(monkey_import_s=round(seq[0], 3), monkey_import_cpu_s=round(seq[2], 3),
                       monkey_import_peak_mb=round(seq[1], 1),
                       monkey_usdc_mb=round(out.stat().st_size / 2 ** 20, 1),
                       monkey_inputs_mb=round(sum(p.stat().st_size for p in pattern.parent.glob("*.sog")) / 2 ** 20,
                                              1),
                       monkey_static_attributes=static)

        # 3. export of a processed demo shot
        processed = Path(args.processed)
        if processed.exists():
            stage = Usd.Stage.Open(str(processed))
            a, b = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
            b = min(b, a + 47)
            exp_cmd = [*USDGS, "export", str(processed), "--frames", f"{a}-{b}", "-o", str(tmp / "shot_####.splat"),
                       "-q"]
            wall, peak, _ = run(exp_cmd)
            n = b - a + 1
            figures.update(export_frames=n, export_s_per_frame=round(wall / n, 3), export_peak_mb=round(peak, 1),
                           export_splat_mb_per_frame=round((tmp / f"shot_{a:04d}.splat").stat().st_size / 2 ** 20, 1))
        else:
            figures["export_s_per_frame"] = f"skipped: {processed} not found (usdgs process stages/demo.usda -o ...)"
    except _Done:
        pass
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        if base_cmd:  # after the timed runs (see the peak-RSS note above)
            figures["baseline_output"] = same_stage(tmp / "flowers_baseline.usdc", tmp / "flowers.usdc")
        if args.check and st:
            sys.path.insert(0, str(REPO / "tests"))
            from capture_testutil import assert_same_decode

            from usd_gs.io.ply import read_ply
            from usd_gs.io.sog import read_sog

            assert_same_decode(read_sog(lod, lod=0), read_ply(tmp / "flowers.ply"), "flowers LOD 0")
            figures["flowers_decode_check"] = "equal within the test tolerances"
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for k, v in figures.items():
        print(f"{k:28s} {v}")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
