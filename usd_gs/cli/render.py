"""``usdgs render``: preview renders of an input or processed stage (logic in ``usd_gs/render/preview.py``)."""

from __future__ import annotations

import math
import os
import re
import sys
import time

from usd_gs.errors import UserError

SEPARATOR = 4
"""Columns of white between the two halves of a ``--compare`` image."""

_HASHES = re.compile(r"#+")


def frame_path(pattern: str, frame: float) -> str:
    """``pattern`` with its run of '#' in the file name replaced by the frame number,
    zero-padded to the run's length (``out_####.png``, 1 -> ``out_0001.png``; fractional
    frames keep their fraction: 1.5 -> ``out_0001.5.png``). A pattern without '#' is
    returned as it is."""
    head, name = os.path.split(pattern)
    runs = list(_HASHES.finditer(name))
    if not runs:
        return pattern
    m = runs[-1]
    a = abs(float(frame))
    frac = "" if a.is_integer() else f"{a - math.floor(a):.6g}".lstrip("0")
    num = ("-" if frame < 0 else "") + f"{int(math.floor(a)):0{len(m.group())}d}" + frac
    return os.path.join(head, name[:m.start()] + num + name[m.end():])


def check_pattern(pattern: str, frames: list[float], exr: bool) -> None:
    """``UserError`` for an output pattern that cannot name every frame, has the wrong
    extension, or points into a missing directory."""
    head, name = os.path.split(pattern)
    runs = _HASHES.findall(name)
    if len(runs) > 1:
        raise UserError(f"-o {pattern}: the file name has {len(runs)} runs of '#'; use one (e.g. out_####.png)")
    if not runs and len(frames) > 1:
        raise UserError(f"-o {pattern}: {len(frames)} frames need a '#' frame-number pattern in the file name "
                        "(e.g. out_####.png)")
    ext = os.path.splitext(name)[1].lower()
    want = ".exr" if exr else ".png"
    if ext != want:
        raise UserError(f"-o {pattern}: output must end in {want}" + (" with --exr" if exr else
                                                                       " (or use --exr and .exr)"))
    parent = os.path.abspath(head or ".")
    if not os.path.isdir(parent):
        raise UserError(f"-o {pattern}: output directory {parent} does not exist")


def parse_background(text: str) -> tuple[float, float, float]:
    """'R,G,B' (floats, display-referred like the splat colours) -> a tuple; ``UserError`` otherwise."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise UserError(f"--background '{text}': expected three numbers R,G,B") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise UserError(f"--background '{text}': expected three finite numbers R,G,B")
    return vals


def write_exr_rgba(path: str, rgb, alpha) -> None:
    """Linear float32 RGBA OpenEXR (ZIP compression), no colour transform; written atomically."""
    import numpy as np
    import OpenEXR

    from usd_gs.io.atomic import atomic_output

    rgba = np.ascontiguousarray(np.concatenate([rgb, alpha[..., None]], axis=-1), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_output(path) as tmp, OpenEXR.File(header, {"RGBA": rgba}) as f:
        f.write(str(tmp))


def cmd_render(args) -> int:
    from usd_gs.render.preview import input_stage, render_stage_frame, resolve_camera, side_by_side
    from usd_gs.render.rasterize import write_png
    from usd_gs.usd.frames import outside_warning, parse_frames
    from usd_gs.usd.stage import open_stage

    t_start = time.perf_counter()
    from usd_gs.resources import check_limit, check_memory

    check_limit("width", args.width)
    background = parse_background(args.background)
    exr = args.exr or os.path.splitext(args.output)[1].lower() == ".exr"
    stage = open_stage(args.stage)
    start = stage.GetStartTimeCode()
    frames = parse_frames(args.frames, start, start) if args.frames is not None else [start]
    check_pattern(args.output, frames, exr)
    before = input_stage(stage) if args.compare else None
    say = (lambda *a: None) if args.quiet else print
    outside = (outside_warning(frames, start, stage.GetEndTimeCode(), args.stage)
               if stage.HasAuthoredTimeCodeRange() else None)
    if outside and not args.quiet:  # (an 'usdgs process' output spans the frames it processed)
        print(f"warning: {outside}", file=sys.stderr)
    if before is not None and not stage.GetPrimAtPath("/UsdGs") and not args.quiet:
        # 'usdgs process' always writes /UsdGs (lights, probes); an input stage with data sublayers has none
        print(f"warning: {args.stage} has no /UsdGs prim, so it may not be an 'usdgs process' output; comparing "
              f"with its first sublayer {before.GetRootLayer().realPath}", file=sys.stderr)

    fixed = None
    if args.camera is None:
        # resolved once when the stage has no camera: a look-at framing every frame, so it does not move
        from usd_gs.render.preview import camera_prims

        if not camera_prims(stage):
            fixed = resolve_camera(stage, None, frames[0], args.width, bounds_frames=frames)
    read_s = render_s = write_s = 0.0
    for i, f in enumerate(frames):
        cam = fixed or resolve_camera(stage, args.camera, f, args.width)
        if i == 0:
            check_limit("width", cam.height, "--width (the image height from the camera's aspect)")
            # the rasteriser's per-pixel buffers (colour, alpha, depth, tiles), twice for --compare
            check_memory(cam.width * cam.height * 64.0 * (2 if before is not None else 1),
                         f"render {cam.width}x{cam.height}", "--width")
        res = render_stage_frame(stage, f, cam, background=background)
        read_s += res.read_s
        render_s += res.render_s
        rgb, alpha = res.rgb, res.alpha
        extra = ""
        if before is not None:
            left = render_stage_frame(before, f, cam, background=background)
            read_s += left.read_s
            render_s += left.render_s
            rgb = side_by_side(left.rgb, rgb, SEPARATOR, 1.0)
            alpha = side_by_side(left.alpha, alpha, SEPARATOR, 1.0)
            extra = f" (left: input, {left.count:,} Gaussians)"
        t0 = time.perf_counter()
        path = frame_path(args.output, f)
        if exr:
            write_exr_rgba(path, rgb, alpha)
        else:
            write_png(path, rgb)
        write_s += time.perf_counter() - t0
        say(f"frame {f:g}: {res.count:,} Gaussians from {len(res.prims)} prim(s){extra}, "
            f"{cam.width}x{cam.height}, render {res.render_s:.2f} s -> {path}")
    total = time.perf_counter() - t_start
    n = len(frames)
    say(f"{n} frame(s) in {total:.2f} s ({total / n:.2f} s/frame): read {read_s:.2f} s, render {render_s:.2f} s, "
        f"write {write_s:.2f} s")
    return 0


def register_render(sub, formatter):
    p = sub.add_parser(
        "render", formatter_class=formatter, help="preview renders of a stage's Gaussians (PNG or EXR)",
        description="Render the visible ParticleField3DGaussianSplat prims of a stage (world space at each frame; "
                    "guide/proxy purpose and invisible prims skipped) with the CPU splat rasteriser. Works on an "
                    "input stage or on the output of 'usdgs process' (which shows the shadows and relighting). "
                    "Camera: --camera, else the stage's first UsdGeom.Camera in path order, else a look-at camera "
                    "framing the Gaussians' centres over the rendered frames, all but the outermost 1 % on each axis "
                    "(a capture's stray splats do not push it away; 16:9, 50 degrees vertical field of view, "
                    "looking from front-right-above). PNGs hold the 3DGS display-referred "
                    "colours as they are (no sRGB curve); --exr writes the same values as float RGBA.")
    p.add_argument("stage", help="USD stage (an input, or the output of 'usdgs process')")
    p.add_argument("-o", "--output", required=True,
                   help="output file pattern; a run of '#' is replaced by the zero-padded frame number "
                        "(out_####.png -> out_0001.png); needed when rendering more than one frame")
    p.add_argument("--camera", metavar="PATH", help="UsdGeom.Camera prim (default: the first camera in the stage, "
                                                    "else a look-at camera framing the Gaussians)")
    p.add_argument("--frames", help="frames: A-B, A:B:STEP, N, or a comma list (default: the stage's start frame)")
    p.add_argument("--width", type=int, default=960,
                   help="image width in pixels (1..16384); height from the camera aperture")
    p.add_argument("--background", default="0,0,0", metavar="R,G,B", help="background colour")
    p.add_argument("--exr", action="store_true", help="write linear float32 RGBA OpenEXR instead of PNG")
    p.add_argument("--compare", action="store_true",
                   help="for a processed stage: input (its first sublayer) on the left, processed on the right, "
                        f"{SEPARATOR} white columns between")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_render)


REGISTRARS = [register_render]
