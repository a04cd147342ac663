"""``usdgs process``: the main job."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from usd_gs.cli._args import add_role_options, build_options, print_lights
from usd_gs.errors import UserError


def is_missing_demo(path) -> bool:
    """True for a ``stages/demo.usda`` that does not exist yet in this project's ``stages/``
    folder (the one holding ``make_example.py``): the demo shot is generated, not checked in."""
    p = Path(path)
    return (not p.exists() and p.name == "demo.usda" and p.parent.name == "stages"
            and (p.parent / "make_example.py").is_file())


def make_missing_demo(path, quiet: bool) -> None:
    """Generate the default demo shot at ``path`` (what ``usdgs demo make`` writes), printing
    one line first unless ``quiet``; ``UserError`` when ../shared/data is missing."""
    from usd_gs.demo.stage import DemoOptions, make_demo

    if not quiet:
        print(f"{path} does not exist yet: generating the demo shot from the shared captures "
              "(the same as 'usdgs demo make')", flush=True)
    make_demo(str(path), DemoOptions(), None, log=None)


def cmd_process(args) -> int:
    from usd_gs.pipeline.shot import ShotProcessor, default_output_path
    from usd_gs.usd.roles import role_table
    from usd_gs.usd.stage import check_usd_output_path

    if is_missing_demo(args.stage):  # a fresh checkout: `usdgs process stages/demo.usda` just works
        make_missing_demo(args.stage, args.quiet or args.json)
    out = args.output or default_output_path(args.stage)
    check_usd_output_path(out)
    opts = build_options(args)
    quiet = args.quiet or args.json
    for name in ("chunk_size", "workers"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise UserError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.clips_dir and os.path.exists(args.clips_dir) and not os.path.isdir(args.clips_dir):
        raise UserError(f"--clips-dir {args.clips_dir}: is a file, not a folder")
    if args.chunk_size or args.workers or args.scheduler or args.clips_dir:
        from usd_gs.cli.farm import process_chunked

        return process_chunked(args, out, opts)
    proc = ShotProcessor(args.stage, out, opts)
    summary = proc.run(progress=not quiet and sys.stderr.isatty() or args.progress)
    if args.json:
        json.dump(summary.as_dict(), sys.stdout, indent=2)
        print()
        return 0
    if args.quiet:
        return 0
    d = summary.as_dict()
    print(role_table(summary.roles, proc.counts))
    print_lights(summary.lights)
    for line in proc.capture_lines:
        print(line)
    for w in summary.warnings:
        print(f"warning: {w}")
    print("timings (s): " + ", ".join(f"{k} {v:.2f}" for k, v in d["timings_s"].items()))
    fps = d["frames_per_second"]
    print(f"{len(summary.frames)} frame(s), {d['seconds_per_frame']:.3f} s/frame"
          + (f" ({fps:.2f} frames/s)" if fps else ""))
    if summary.affected:
        most = sorted(summary.affected.items(), key=lambda kv: (-kv[1], kv[0]))
        shown = ", ".join(f"{p} {n}" for p, n in most[:6]) + (f", ... ({len(most) - 6} more)" if len(most) > 6 else "")
        print(f"authored: {len(most)} prim(s) over {len(summary.frames)} frame(s); frames per prim: {shown}")
    else:
        print("authored: nothing (no prim was shadowed or relit)")
    print(f"wrote {summary.output} ({summary.output_bytes / 1e6:.1f} MB with {summary.probe_files} probe textures)")
    return 0


def register_process(sub, formatter):
    p = sub.add_parser(
        "process", formatter_class=formatter, help="shadows and relighting for every frame of a shot",
        description="Estimate lights (or use the stage's UsdLux lights), build Deep Gaussian Shadow Maps from the "
                    "avatars and objects, attenuate the scene's colours in their shadows, fit an SH environment "
                    "probe at each avatar and relight it. Results go to a new layered stage that sublayers the "
                    "input (the input is never written): the shadowed and relit SH (half precision by default), "
                    "/UsdGs/Lights and /UsdGs/Probes, plus lat-long EXR probe textures in <output stem>_probes/; "
                    "diagnostic primvars with --aovs.")
    p.add_argument("stage", help="input USD stage")
    p.add_argument("-o", "--output", help="output stage (default: <stem>.lit.usdc beside the input)")
    p.add_argument("--frames", help="frames: A-B, A:B:STEP, N, or a comma list (default: the stage's range)")
    p.add_argument("--lights", help="'auto' (the stage's UsdLux lights, else estimated from the capture: open "
                                    "captures get a sun from their baked shadows plus a sky dome, closed ones 2 "
                                    "plausible point lights), 'outdoor' / 'indoor' (estimate as an open / closed "
                                    "capture), 'stage' (UsdLux lights only) or N (estimate N point lights) "
                                    "(default: auto)")
    p.add_argument("--lights-per-frame", action="store_true", help="re-estimate lights at every frame")
    add_role_options(p)
    p.add_argument("--aovs", metavar="NAMES",
                   help="also write these diagnostic primvars, comma-separated: transmittance (primvars:usdgs:"
                        "transmittance, what 'usdgs eval --matte stage' reads), lightScale (primvars:usdgs:lightScale, "
                        "the relighting factor) (default: none; the shadowed and relit SH carry both)")
    p.add_argument("--precision", choices=("half", "float"),
                   help="precision of the SH written: half (radiance:sphericalHarmonicsCoefficientsh, the float "
                        "attribute blocked in the output layer; default) or float")
    p.add_argument("--bake-skinning", action="store_true",
                   help="also author the skinned Gaussians of UsdSkel-bound prims as time samples in the output "
                        "layer and block their binding there (for viewers without UsdSkel support for splats)")
    p.add_argument("--sh-tolerance", type=float, metavar="C",
                   help="hold an SH sample while no display colour moves by C or more (0..0.1; default 1/512, half "
                        "an 8-bit step; 0 writes every change)")
    p.add_argument("--direct-fraction", type=float,
                   help="share of a receiver's colour that is direct light and can be shadowed (default: measured "
                        "from the capture's own shadows for an estimated sun, from the intensities of authored "
                        "DistantLights against the DomeLight, else 1)")
    p.add_argument("--probe-points", type=int, metavar="K",
                   help="relighting: parallax-corrected SH probes per avatar, blended by distance (default 8; "
                        "1 = the paper's single probe at the centroid)")
    p.add_argument("--probe-supersample", type=int, metavar="S",
                   help="relighting: draw the probe cube render at S x its size and filter it down (default 1; 2 "
                        "integrates small lamps over each texel: +1-2 dB on the known-light ground truth at the "
                        "bench size, about 10-15 ms more per relit prim and frame)")
    p.add_argument("--color-space", choices=("srgb", "linear"),
                   help="relighting: the Gaussians' colours are display-referred sRGB (default; light is summed and "
                        "divided on decoded linear values) or linear already")
    p.add_argument("--transfer-degree", type=int, metavar="D",
                   help="relighting: SH degree of the lighting transfer (default 4; the written probe stays degree 3)")
    p.add_argument("--atlas-size", type=int, help="DGSM octahedral atlas side in pixels, a multiple of 8 in 8..16384 "
                                                  "(default 512)")
    p.add_argument("--sampling", choices=("center", "stencil7", "mc"),
                   help="receiver footprint sampling (default center: sharper and 8x cheaper than the paper's mc "
                        "against the demo's mesh pseudo ground truth; see usdgs bench)")
    p.add_argument("--n-samples", type=int, help="Monte Carlo footprint samples per receiver (default 8)")
    p.add_argument("--seed", type=int, help="seed of the footprint sampling (default 0)")
    p.add_argument("--no-roi", action="store_true", help="disable the receiver ROI (slow; for ablations)")
    p.add_argument("--no-tile-culling", action="store_true", help="disable light-space tile culling (slow)")
    p.add_argument("--config", help="JSON file with options (names as above with '_')")
    p.add_argument("--progress", action="store_true", help="show the progress bar even when not on a terminal")
    f = p.add_argument_group("farm runs (frame chunks stitched as value clips; see README 'Farm runs')")
    f.add_argument("--chunk-size", type=int, metavar="N",
                   help="frames per chunk: one layer per chunk in --clips-dir, OUT stitches them (default: all "
                        "frames in one chunk when only --clips-dir/--workers/--scheduler is given)")
    f.add_argument("--clips-dir", metavar="DIR", help="chunk layers, their manifest entries and the run's shot "
                                                      "cache (shot_cache_<key>.npz: what every chunk computes from "
                                                      "the shot's first frame, read by later chunks; safe to delete) "
                                                      "(default: <output stem>_clips/ beside the output); "
                                                      "re-running skips finished chunks")
    f.add_argument("--workers", type=int, metavar="N", help="run the chunks in N local processes")
    f.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="submit the chunks to a running dask.distributed scheduler (pip install 'usd-gs[farm]')")
    f.add_argument("--retries", type=int, default=2, help="resubmit a failed chunk this many times")
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    g.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(handler=cmd_process)


REGISTRARS = [register_process]
