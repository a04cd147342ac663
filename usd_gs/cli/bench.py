"""``usdgs bench``: the shadow ablations and the DGSM speed-versus-error sweep against the mesh
pseudo ground truth, as a markdown report with plots (``usd_gs/evaluation/ablation.py``,
``usd_gs/evaluation/report.py``).

Stages: with ``--stage`` the given processed stages; otherwise the demo shots are generated
into ``<report dir>/stages`` and processed there on the benchmark frames (``--quick``: the
quick demo, 2 frames at 480 px; default: the default demo on 4 frames at 960 px plus the
quick demo on 2 frames at 480 px).
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

QUICK_FRAMES = "1,5"
FULL_FRAMES = "1,13,25,37"


def _prepare_demo(folder: Path, quick: bool, frames: str, log) -> str:
    """Generate the (quick) demo shot under ``folder`` and process it on ``frames``; the processed stage's path."""
    from usd_gs.demo.stage import QUICK, DemoOptions, make_demo
    from usd_gs.pipeline.options import ProcessOptions
    from usd_gs.pipeline.shot import ShotProcessor

    root = folder / ("quick" if quick else "demo") / "demo.usda"
    out = root.with_name("demo.lit.usdc")
    t = time.perf_counter()
    make_demo(str(root), QUICK if quick else DemoOptions(), None, log=None)
    log(f"made {root} in {time.perf_counter() - t:.1f} s")
    t = time.perf_counter()
    ShotProcessor(str(root), str(out), ProcessOptions(frames=frames)).run(progress=False)
    log(f"processed {out} (frames {frames}) in {time.perf_counter() - t:.1f} s")
    return str(out)


def bench_stage(path: str, label: str, key: str, frames, width: int, quick: bool, radius: float, log) -> dict:
    from usd_gs.evaluation.ablation import culling_timings, run_variants, variants
    from usd_gs.evaluation.shadow_stage import default_eval_frames, frame_inputs, open_eval_stage
    from usd_gs.usd.frames import parse_frames

    ctx = open_eval_stage(path, width=width)
    a, b = ctx.frames_range
    fl = parse_frames(frames, a, b) if frames else default_eval_frames(ctx, 4)
    fis = [frame_inputs(ctx, f) for f in fl]
    log(f"{label}: {path}, frames {fl}")
    rows = run_variants(fis, variants(quick), radius, ctx.up_axis, log)
    cull = culling_timings(fis[0])
    fi = fis[0]
    return {"label": label, "key": key, "stage": path, "frames": fl, "camera": ctx.camera_path,
            "image": [fi.camera.width, fi.camera.height], "caster_count": fi.caster.count,
            "receiver_count": fi.receivers.gaussians.count,
            "lights": ", ".join(f"{lt.name.rsplit('/', 1)[-1]} at ({', '.join(f'{x:.2f}' for x in lt.position)})"
                                for lt in fi.lights),
            "variants": rows, "culling": cull}


def run_bench(quick: bool, out_dir: Path, stages=None, frames=None, width=None, radius: float = 2.0,
              log=print) -> dict:
    import numba

    from usd_gs.evaluation.report import _pyplot

    _pyplot()  # fail early, before minutes of work, when matplotlib is missing
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    plan = []
    if stages:
        for i, s in enumerate(stages):
            plan.append((s, f"stage {Path(s).name}", f"stage{i}", frames, width or 960))
    else:
        folder = out_dir / "stages"
        if not quick:
            plan.append((_prepare_demo(folder, False, FULL_FRAMES, log), "demo (default)", "demo", FULL_FRAMES,
                         width or 960))
        plan.append((_prepare_demo(folder, True, QUICK_FRAMES, log), "quick demo", "quick", QUICK_FRAMES,
                     width or 480))
    res = [bench_stage(p, label, key, fr, w, quick, radius, log) for p, label, key, fr, w in plan]
    return {"command": "usdgs " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("usdgs") else "usdgs bench",
            "machine": {"cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(), "load_start": load0,
                        "load_end": os.getloadavg()[0], "platform": platform.platform()},
            "roi_radius": radius, "stages": res, "seconds": time.perf_counter() - t0}


def cmd_bench(args) -> int:
    from usd_gs.evaluation.report import write_report

    out_dir = Path(args.output)
    say = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    results = run_bench(args.quick, out_dir, args.stage, args.frames, args.width, args.radius, say)
    results["command"] = "usdgs bench" + (" --quick" if args.quick else "") + f" -o {args.output}" + \
        "".join(f" --stage {s}" for s in args.stage or ())
    report = write_report(results, out_dir)
    from usd_gs.io.atomic import atomic_output

    with atomic_output(out_dir / "results.json") as tmp:
        tmp.write_text(json.dumps(results, indent=1), encoding="utf-8")
    if args.json:
        json.dump(results, sys.stdout, indent=1)
        print()
    else:
        print(f"wrote {report} ({results['seconds']:.1f} s)")
    return 0


def register_bench(sub, formatter):
    p = sub.add_parser(
        "bench", formatter_class=formatter, help="shadow ablations and the DGSM speed/error sweep (markdown + plots)",
        description="Runs the ablations of paper 4.4 (footprint sampling, opacity-to-absorption mappings, "
                    "octahedral vs cube-map atlas, ROI and tile culling) and the DGSM speed-versus-error sweep "
                    "(atlas side, K, samples), each scored with SAE / SM-IoU / BF against the mesh pseudo ground "
                    "truth of 'usdgs eval', and writes report.md, results.json and time-vs-error plots (Pareto "
                    "front marked) to the report folder. Without --stage it generates and processes the demo "
                    "shots there first. Needs matplotlib (pip install 'usd-gs[bench]').")
    p.add_argument("--quick", action="store_true", help="the quick demo only, a trimmed sweep (about a minute)")
    p.add_argument("-o", "--output", default="bench_report", help="report folder (created)")
    p.add_argument("--stage", action="append", metavar="PATH", help="bench this processed stage instead (repeatable)")
    p.add_argument("--frames", help="frames of --stage stages (default: 4 spread over the range)")
    p.add_argument("--width", type=int, help="image width (default 960, 480 for the quick demo)")
    p.add_argument("--radius", type=float, default=2.0, help="ROI half-size R in metres")
    p.add_argument("--json", action="store_true", help="print the results as JSON (progress goes to stderr)")
    p.set_defaults(handler=cmd_bench)


REGISTRARS = [register_bench]
