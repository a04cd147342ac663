"""The ``usdgs demo make`` subcommand: generate the demo stage (``usd_gs.demo.stage``)."""

from __future__ import annotations

import argparse
import os

QUICK_HELP = "tiny demo for tests: 8 frames, 5k avatar Gaussians, room density 60, biker/guitar subsampled"


def _size(n: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"  # pragma: no cover


def cmd_demo_make(args) -> int:
    from dataclasses import replace

    from usd_gs.demo.stage import QUICK, DemoOptions, make_demo

    if args.outdoor:
        return _make_outdoor(args)
    args.output = args.output or "stages/demo.usda"
    base = QUICK if args.quick else DemoOptions()
    changes = {k: v for k, v in (("frames", args.frames), ("avatar_gaussians", args.avatar_gaussians),
                                 ("room_density", args.room_density), ("seed", args.seed)) if v is not None}
    if args.room_detail_density is not None:
        changes["room_detail_density"] = args.room_detail_density or None
    if args.monkey:
        changes["monkey"] = True
    if getattr(args, "rigged_avatar", False):
        changes["rigged_avatar"] = True
    opts = replace(base, **changes)
    log = None if args.quiet else (lambda msg: print(msg, flush=True))
    if log:
        log(f"usdgs demo make: writing {args.output} ({opts.frames} frames)")
    result = make_demo(args.output, opts, args.data, log=log)
    if not args.quiet:
        for path, n in result.counts.items():
            print(f"  {path}: {n:,} Gaussians")
        print(f"  /World/CesiumMan_guide: posed mesh (purpose guide); /World/Camera; {result.frames} frames at 24 fps")
        total = 0
        for f in result.files():
            size = os.path.getsize(f)
            total += size
            print(f"  {os.path.relpath(f)}: {_size(size)}")
        print(f"wrote {os.path.relpath(result.root)}: {len(result.files())} files, {_size(total)} in "
              f"{result.seconds:.1f} s")
    return 0


def _make_outdoor(args) -> int:
    from usd_gs.demo.outdoor import OutdoorOptions, make_outdoor_demo

    changes = {k: v for k, v in (("frames", args.frames), ("avatar_gaussians", args.avatar_gaussians),
                                 ("seed", args.seed)) if v is not None}
    if args.quick:
        changes = {"frames": 8, "avatar_gaussians": 5000, "biker_gaussians": 8000, **changes}
    opts = OutdoorOptions(**changes)
    out = args.output or "stages/outdoor.usda"
    log = None if args.quiet else (lambda msg: print(msg, flush=True))
    if log:
        log(f"usdgs demo make --outdoor: writing {out} ({opts.frames} frames)")
    result = make_outdoor_demo(out, opts, args.data, log=log)
    if not args.quiet:
        for path, n in result.counts.items():
            print(f"  {path}: {n:,} Gaussians")
        total = sum(os.path.getsize(f) for f in result.files())
        print(f"wrote {os.path.relpath(result.root)}: {len(result.files())} files, {_size(total)} in "
              f"{result.seconds:.1f} s (no lights authored: 'usdgs process' estimates the sun)")
    return 0


def register_demo(sub, formatter):
    p = sub.add_parser("demo", formatter_class=formatter, help="generate the demo stage",
                       description="Demo data. 'usdgs demo make' generates the demo stage from the shared test "
                                   "data (../shared/data beside the checkout).")
    dsub = p.add_subparsers(dest="demo_command", metavar="ACTION")
    p.set_defaults(handler=lambda _args: (p.print_help(), 2)[1])
    # Defaults are spelled out in the help texts (--quick changes them), so no "(default: None)".
    m = dsub.add_parser("make", formatter_class=argparse.RawDescriptionHelpFormatter,
                        help="write stages/demo.usda and its data layers",
                        description="Generate the demo stage: a room of scene Gaussians with two lamp emitters "
                                    "(ground truth in /World customData), the CesiumMan glTF walking as skinned "
                                    "Gaussians (plus its posed mesh as a guide), the biker capture moving along "
                                    "a path, the guitar capture as an inserted object, and a camera. Writes a "
                                    "small text root layer and binary layers in <stem>_data/ beside it. "
                                    "Deterministic: the same options give byte-identical files.")
    m.add_argument("-o", "--output", default=None,
                   help="root layer to write (default stages/demo.usda, with --outdoor stages/outdoor.usda; "
                        "folders are created); the data layers go to <stem>_data/ beside it")
    m.add_argument("--outdoor", action="store_true",
                   help="the outdoor shot instead: the sunlit seal capture (scenes/luma-seal.splat, turned Y-up) "
                        "with the biker and CesiumMan walking past the statue, no lights authored (24 frames; "
                        "--frames, --avatar-gaussians, --seed, --quick apply)")
    m.add_argument("--frames", type=int, default=None, help="frame count at 24 fps (default 48; --quick: 8)")
    m.add_argument("--avatar-gaussians", type=int, default=None,
                   help="Gaussians on CesiumMan (default 30000; --quick: 5000)")
    m.add_argument("--room-density", type=float, default=None,
                   help="room Gaussians per square metre of surface (default 800, about 200k; --quick: 60)")
    m.add_argument("--room-detail-density", type=float, default=None,
                   help="Gaussians per square metre where CesiumMan's shadows fall (default 6400, about 105k "
                        "more; 0: none, the --quick default)")
    m.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    m.add_argument("--data", default=None,
                   help="folder holding humans/CesiumMan.glb and splats/{biker,guitar}.ply "
                        "(default: shared/data found beside the checkout or the current directory)")
    m.add_argument("--quick", action="store_true", help=QUICK_HELP)
    m.add_argument("--monkey", action="store_true",
                   help="also add /World/Monkey: the SOG flipbook sequences/monkey (50 frames, looped) as a "
                        "time-sampled avatar on the floor (usd_gs/demo/monkey.py)")
    m.add_argument("--rigged-avatar", action="store_true",
                   help="also add /World/TPoseAvatar: humans/tpose_avatar.ply bound to the MakeHuman skeleton "
                        "(usdgs rig) walking on the spot with humans/makehuman_walk1.bvh (usd_gs/demo/rig.py)")
    m.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    m.set_defaults(handler=cmd_demo_make)


REGISTRARS = [register_demo]
