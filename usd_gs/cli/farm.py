"""Farm commands: ``usdgs lights`` (the shot-level light step), ``usdgs assemble`` (stitch
chunks made elsewhere) and the chunked form of ``usdgs process`` (``--chunk-size``,
``--workers``, ``--scheduler``)."""

from __future__ import annotations

import json
import math
import sys

from usd_gs.cli._args import add_role_options, print_lights, role_paths
from usd_gs.errors import UserError


def process_chunked(args, out: str, opts) -> int:
    """``usdgs process`` with any farm option: see ``usd_gs.farm.run``."""
    from usd_gs.farm.executor import stderr_report
    from usd_gs.farm.run import run_farm

    if args.scheduler and args.workers:
        raise UserError("--workers and --scheduler exclude each other (the scheduler's workers run the chunks)")
    if args.scheduler and not args.chunk_size:
        raise UserError("--scheduler needs --chunk-size (frames per task)")
    if args.retries < 0:
        raise UserError(f"--retries must be >= 0, got {args.retries}")
    chunk_size = args.chunk_size
    if chunk_size is None:
        from usd_gs.usd.frames import parse_frames
        from usd_gs.usd.stage import open_stage

        stage = open_stage(args.stage)
        n = len(parse_frames(opts.frames, stage.GetStartTimeCode(), stage.GetEndTimeCode()))
        chunk_size = math.ceil(n / (args.workers or 1))
    quiet = args.quiet or args.json
    summary = run_farm(args.stage, out, opts, chunk_size, args.clips_dir, workers=args.workers,
                       scheduler=args.scheduler, retries=args.retries, report=None if quiet else stderr_report)
    d = summary.as_dict()
    if args.json:
        json.dump(d, sys.stdout, indent=2)
        print()
    elif not args.quiet:
        c = d["chunks"]
        if summary.lights is not None:
            print_lights(summary.lights)
        fps = d["frames_per_second"]
        print(f"{d['frames']['count']} frame(s) in {c['total']} chunk(s) on {summary.backend}: "
              f"{len(c['computed'])} computed, {len(c['skipped'])} already finished"
              + (f", {len(c['removed_stale'])} stale removed" if c["removed_stale"] else "")
              + (f"; {fps:.2f} frames/s" if fps else ""))
        for w in summary.warnings:
            print(f"warning: {w}")
        print(f"wrote {summary.output} (value clips over {summary.clips_dir})")
    return 0


def cmd_lights(args) -> int:
    from pathlib import Path

    from usd_gs.farm.run import SHOT_FIRST_FRAME
    from usd_gs.pipeline.capture_lights import write_lights
    from usd_gs.pipeline.options import ProcessOptions
    from usd_gs.pipeline.shot import ShotProcessor
    from usd_gs.usd.lux import LIGHTS_ROOT
    from usd_gs.usd.output_layer import OutputLayer
    from usd_gs.usd.stage import check_usd_output_path

    check_usd_output_path(args.output)
    opts = ProcessOptions(frames=args.frames, lights=args.lights or "auto", allow_missing=args.allow_missing,
                          **role_paths(args))
    proc = ShotProcessor(args.stage, args.output, opts)
    lights = proc.shot_lights()
    if lights is None:
        raise UserError(f"{args.stage}: the stage has UsdLux lights; chunk runs use them as they are "
                        "(--lights stage), or pass --lights N to estimate N lights anyway")
    if not lights:
        raise UserError(f"{args.stage}: no lights could be estimated ({'; '.join(proc.warnings) or 'no scene'})")
    with OutputLayer.create(args.stage, args.output) as out:
        target = Path(args.output)
        sky = target.with_name(target.stem + "_sky.exr")
        write_lights(proc, out.stage, lights, sky, f"./{sky.name}")
        # the shot's first frame: chunk tasks anchor the avatars' normals there (usd_gs.farm.run)
        out.stage.GetPrimAtPath(LIGHTS_ROOT).SetCustomDataByKey(SHOT_FIRST_FRAME, float(proc.frames[0]))
    if not args.quiet:
        print_lights(lights)
        for line in proc.capture_lines:
            print(line)
        for w in proc.warnings:
            print(f"warning: {w}")
        print(f"wrote {args.output} (sublayers {args.stage}); run the chunks on it with --lights stage")
    return 0


def cmd_assemble(args) -> int:
    from usd_gs.farm.clips import assemble

    s = assemble(args.clips_dir, args.output, allow_gaps=args.allow_gaps)
    if not args.quiet:
        print(f"stitched {len(s.chunks)} chunk(s), {len(s.frames)} frame(s) "
              f"({s.frames[0]:g}-{s.frames[-1]:g}) into {s.output}; topology {s.topology}, manifest {s.manifest}")
    return 0


def register_lights(sub, formatter):
    p = sub.add_parser(
        "lights", formatter_class=formatter, help="estimate a shot's lights once (the serial step of a farm run)",
        description="Estimate the shot's dominant lights once over the frame range (as usdgs process does) and "
                    "write them as SphereLight prims under /UsdGs/Lights into a layer that sublayers the input. "
                    "Farm tasks then run 'usdgs process LIGHTS.usda --lights stage --frames A-B ...' so every "
                    "chunk sees identical lights.")
    p.add_argument("stage", help="input USD stage")
    p.add_argument("-o", "--output", required=True, help="lights layer to write (.usda/.usdc)")
    p.add_argument("--frames", help="frames the estimate is for (default: the stage's range)")
    p.add_argument("--lights", help="'auto' (open captures: sun and sky, closed: 2 point lights; refuses stages "
                                    "with lights), 'outdoor', 'indoor' or a number of point lights (default auto)")
    add_role_options(p)
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_lights)


def register_assemble(sub, formatter):
    p = sub.add_parser(
        "assemble", formatter_class=formatter, help="stitch finished chunks into one stage (value clips)",
        description="Stitch the finished chunks of DIR (chunk_*.usdc with their chunk_*.json entries, written by "
                    "'usdgs process --chunk-size N --clips-dir DIR', possibly by many farm tasks) into OUT: a root "
                    "layer that sublayers a topology layer and the input and carries the value clips, plus "
                    "<stem>.topology.usdc and <stem>.manifest.usdc. Refuses mixed, overlapping or stale chunks.")
    p.add_argument("clips_dir", metavar="DIR", help="folder with the chunks")
    p.add_argument("-o", "--output", required=True, help="stitched stage to write")
    p.add_argument("--allow-gaps", action="store_true",
                   help="stitch even when a chunk layer in DIR has no finished manifest entry (its frames are then "
                        "absent from OUT); by default that is an error naming the chunk and its frames")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_assemble)


REGISTRARS = [register_lights, register_assemble]
