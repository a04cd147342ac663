"""Capture I/O figures (issue 14), whole processes side by side in one run (not a test).

1. ``usdgs import`` of the flowers LOD set, level 0 (542k Gaussians, 4 SOG chunks) to usdc,
   against PlayCanvas splat-transform converting the same files to INRIA PLY: wall and CPU
   seconds and peak RSS of each process (best of ``--repeat``, the two alternating), and the
   speed-ups (wall, and CPU for a loaded machine). ``--check`` also
   compares the two decodes (tests/capture_testutil.py tolerances).
2. Sequence import of the 50-frame monkey (``monkey_####.sog --frames 1-50``): wall seconds,
   peak RSS, output size, and which attributes were authored once (static).
3. ``usdgs export`` of 48 frames of a processed demo stage (``--processed``, the output of
   ``usdgs process stages/demo.usda``) as ``.splat``: seconds per frame.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_capture_io.py [--repeat 3] [--check] \\
        [--processed /tmp/x/demo.lit.usdc]

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


def run(cmd: list[str]) -> tuple[float, float, float]:
    """(wall s, peak RSS MB, CPU s = user + system) of one child process; raises on failure."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {err[-1500:]}")
    return wall, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def best(cmd: list[str], repeat: int) -> tuple[float, float, float]:
    """Best wall time, largest peak RSS and best CPU time over ``repeat`` runs."""
    runs = [run(cmd) for _ in range(repeat)]
    return min(r[0] for r in runs), max(r[1] for r in runs), min(r[2] for r in runs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--check", action="store_true", help="compare the flowers LOD 0 decodes too")
    ap.add_argument("--processed", default="/tmp/x/demo.lit.usdc",
                    help="processed demo stage for the export figure (skipped when missing)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    figures: dict[str, object] = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench_capture_"))
    try:
        # 1. flowers LOD 0
        lod = DATA / "scenes" / "flowers" / "lod-meta.json"
        ours_cmd = [*USDGS, "import", str(lod), "--lod", "0", "-o", str(tmp / "flowers.usdc"), "-q"]
        st = splat_transform()
        ref_cmd = [st, "-q", "-w", "-L", "0", str(lod), str(tmp / "flowers.ply")] if st else None
        runs = [(run(ours_cmd), run(ref_cmd) if ref_cmd else None) for _ in range(args.repeat)]
        ours = (min(r[0][0] for r in runs), max(r[0][1] for r in runs), min(r[0][2] for r in runs))
        figures.update(flowers_import_s=round(ours[0], 3), flowers_import_cpu_s=round(ours[2], 3),
                       flowers_import_peak_mb=round(ours[1], 1))
        if st:
            ref = (min(r[1][0] for r in runs), max(r[1][1] for r in runs), min(r[1][2] for r in runs))
            figures.update(splat_transform_s=round(ref[0], 3), splat_transform_cpu_s=round(ref[2], 3),
                           splat_transform_peak_mb=round(ref[1], 1), speedup_wall=round(ref[0] / ours[0], 2),
                           speedup_cpu=round(ref[2] / ours[2], 2))
        else:
            figures["splat_transform_s"] = "splat-transform not found (npm install --prefix .ci/node ...)"
        figures["flowers_usdc_mb"] = round((tmp / "flowers.usdc").stat().st_size / 2 ** 20, 1)
        # (the decode check runs last: a child's peak RSS on Linux starts from this process's)

        # 2. the monkey sequence
        pattern = DATA / "sequences" / "monkey" / "monkey_####.sog"
        out = tmp / "monkey.usdc"
        seq_cmd = [*USDGS, "import", str(pattern), "-o", str(out), "--frames", "1-50", "--fps", "24",
                   "--prim", "/Monkey", "--role", "avatar", "-q"]
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
