"""The I/O subcommands: ``import``, ``export``, ``inspect`` and ``validate``."""

from __future__ import annotations

import math
import os
import re
import sys

from usd_gs.errors import UserError

READ_HELP = ".ply, .compressed.ply, .splat, .spz, .sog, meta.json, lod-meta.json or a SOG folder"


def read_gaussian_file(path: str, lod: int | None = None, empty=None):
    """Read any capture ``usdgs import`` accepts (``usd_gs.io.formats.read_capture``)."""
    from usd_gs.io.formats import read_capture

    return read_capture(path, lod=lod, empty=empty)


def default_prim_path(input_path: str) -> str:
    """``/<stem>`` with characters that USD does not allow in names replaced by '_'.

    Capture suffixes (``.compressed.ply``, ``.sog``...) and frame tokens are left out; a SOG
    ``meta.json``/``lod-meta.json`` is named after its folder."""
    base = os.path.basename(os.path.normpath(input_path))
    if base.lower() in ("meta.json", "lod-meta.json"):
        base = os.path.basename(os.path.dirname(os.path.abspath(input_path))) or base
    for suffix in (".compressed.ply",):
        if base.lower().endswith(suffix):
            base = base[: -len(suffix)]
    stem = os.path.splitext(base)[0]
    stem = re.sub(r"[#]+|%0?\d*d", "", stem).rstrip("_.-") or stem
    stem = re.sub(r"[^A-Za-z0-9_]", "_", stem) or "Gaussians"
    if stem[0].isdigit():
        stem = "_" + stem
    return "/" + stem


# ----------------------------------------------------------------------------- import
def _import_sequence(args, stage, path) -> str:
    from usd_gs.io.sequence import parse_frames, read_sequence, sequence_paths
    from usd_gs.usd.schema import apply_role
    from usd_gs.usd.sequence_prim import write_sequence_prim

    if args.brick_size is not None:
        raise UserError("--brick-size does not apply to a frame sequence")
    frames = parse_frames(args.frames) if args.frames else None
    paths = sequence_paths(args.input, frames)  # fails on the first missing file before any read
    info = write_sequence_prim(stage, str(path), read_sequence(args.input, (paths[0][0], paths[-1][0]), args.lod),
                               keep_raw=not args.no_raw, precision=args.precision, fps=args.fps)
    if args.role:
        apply_role(stage.GetPrimAtPath(path), args.role)
    counts = (f"{info.counts[0]:,}" if min(info.counts) == max(info.counts)
              else f"{min(info.counts):,}..{max(info.counts):,}")
    return (f"{path} with {len(info.frames)} frames {info.frames[0]}-{info.frames[-1]} at {args.fps:g} fps, "
            f"{counts} Gaussians per frame, SH degree {info.sh_degree}, {args.precision} precision; "
            f"animated: {', '.join(info.animated) or 'none'}")


class _Background:
    """Run ``fn(*args)`` in a daemon thread; :meth:`result` joins and returns or re-raises."""

    def __init__(self, fn, *args):
        import threading

        self._out = None
        self._exc = None

        def run():
            try:
                self._out = fn(*args)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller in result()
                self._exc = exc

        self._thread = threading.Thread(target=run, daemon=True, name="usdgs-read")
        self._thread.start()

    def result(self):
        self._thread.join()
        if self._exc is not None:
            raise self._exc
        return self._out


def _early_vt_arrays(path: str, lod: int | None) -> list:
    """``(shape, Vt array)`` for the arrays a SOG input decodes into, sized from its manifests and
    allocated with pxr alone, before numpy loads (so the decode can start as soon as numpy is
    there); [] when the manifests do not parse (the reader then reports why)."""
    from usd_gs.io.sog_files import decoded_shapes, manifest_size
    from usd_gs.usd.vt_alloc import new_vt_array

    size = manifest_size(path, lod)
    return [] if size is None else [(shape, new_vt_array(shape)) for shape in decoded_shapes(*size)]


def _start_sog_decode(path: str, lod: int | None, prefetch=None, made=()):
    """For a SOG input: its manifests read here (``prefetch``: the
    :class:`~usd_gs.io.sog_files.SogPrefetch` started before numpy was imported, whose image
    bytes and pixels are used), then its images decoded in a background thread
    (libwebp and numpy release the GIL) into the Vt arrays that will be written, while this
    thread imports pxr.Sdf and makes the output layer. Returns ``(the _Background reader, the
    usd_gs.extent.ExtentOfParts its decoding threads fill)``, or ``(None, None)`` for other
    formats (read after the imports).

    pxr's imports must not overlap with another thread's calls into pxr (seen: 'cannot import
    name TimeCodeArray from pxr.Vt'), and the garbage collector must not run pxr destructors in
    the reader meanwhile: so pxr.Vt is imported and the output arrays are allocated here (the
    reader waits for them after its first images), the modules the decode uses are loaded
    before it starts, and the collector is off until :func:`_join`."""
    from usd_gs.io.formats import capture_kind

    if capture_kind(path) != "sog":
        return None, None
    import contextlib
    import gc

    from usd_gs.extent import ExtentOfParts
    from usd_gs.io.sog import load_webp_codec, open_sog
    from usd_gs.io.sog_files import decoded_shapes
    from usd_gs.usd.bulk import VtBackedPool

    opened = open_sog(path, lod, prefetch)
    load_webp_codec()
    pool = VtBackedPool()
    extent = ExtentOfParts(3.0)  # each unit's extent in its decoding thread
    gc.disable()
    reader = _Background(opened.decode, None, pool, extent.add)  # decodes the first images while the pool fills
    try:
        pool.fill(decoded_shapes(opened.count, opened.sh_degree), made)
    except BaseException:
        with contextlib.suppress(BaseException):
            _join(reader)  # (the collector back on)
        raise
    return reader, extent


def _join(reader):
    """The reader's :class:`GaussianSet`; the garbage collector back on."""
    import gc

    try:
        return reader.result()
    finally:
        gc.enable()


def _no_blas_threads() -> None:
    """Before numpy is first imported in this process: OpenBLAS with one thread unless the user
    set ``OPENBLAS_NUM_THREADS``. ``import`` does no linear algebra, and OpenBLAS's worker
    threads spin for a while after numpy loads, taking a core from the decoding threads."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def cmd_import(args) -> int:
    from usd_gs.io.sog_files import SogPrefetch, looks_like_sog
    from usd_gs.usd.stage import check_usd_output_path, prim_path

    check_usd_output_path(args.output)
    if os.path.abspath(args.output) == os.path.abspath(args.input):
        raise UserError(f"{args.output}: output would overwrite the input")
    if args.lod is not None and args.lod < 0:
        raise UserError(f"--lod {args.lod}: must be >= 0 (0 is the finest level)")
    _no_blas_threads()
    # a SOG's images are read and decoded from here on, while numpy and pxr are imported
    prefetch = SogPrefetch(args.input, args.lod) if looks_like_sog(args.input) else None
    made = _early_vt_arrays(args.input, args.lod) if prefetch is not None else []
    from usd_gs.io.sequence import is_pattern
    sequence = is_pattern(args.input)
    if args.frames and not sequence:
        raise UserError(f"{args.input}: --frames needs a frame pattern such as name_####.sog or name_%04d.ply")
    reader, extent = (None, None) if sequence else _start_sog_decode(args.input, args.lod, prefetch, made)
    try:
        path = prim_path(args.prim or default_prim_path(args.input))
        from usd_gs.usd.bulk import vt_backed_empty
        from usd_gs.usd.gaussian_layer import new_layer, save_stage_atomic, write_gaussian_layer

        root = path.GetPrefixes()[0]
        layer = new_layer(up_axis=args.up_axis, meters_per_unit=args.meters_per_unit, default_prim=root.name)
    finally:
        gaussians = None if reader is None else _join(reader)
    extent = None if reader is None else extent.box(gaussians.count)
    if sequence:
        what = _import_sequence(args, _stage_on(layer), path)
        if args.y_down:
            _turn_y_down(layer, path, args.up_axis)
        save_stage_atomic(layer, args.output)
        if not args.quiet:
            print(f"wrote {args.output}: {what}")
        return 0
    # The readers reject NaN/Inf, zero quaternions and out-of-range values naming the
    # field and element, so no second validation pass is needed here. A SOG decodes straight
    # into the Vt arrays that are written (usd_gs.usd.bulk.vt_backed_empty).
    if gaussians is None:
        gaussians = read_gaussian_file(args.input, args.lod, vt_backed_empty)
    bricks = ""
    if args.brick_size is not None:
        from usd_gs.usd.bricks import write_bricked

        n = len(write_bricked(_stage_on(layer), str(path), gaussians, args.brick_size, keep_raw=not args.no_raw,
                              precision=args.precision, role=args.role))
        bricks = f" in {n} bricks"
    else:
        # one prim in a new layer: written with Sdf alone (pxr.Usd is imported only for --role);
        # the same specs as write_gaussian_prim on a stage (tests/test_import_layer.py)
        write_gaussian_layer(layer, str(path), gaussians, keep_raw=not args.no_raw, precision=args.precision,
                             checked=True, extent=extent)
        if args.role:
            from usd_gs.usd.schema import apply_role

            stage = _stage_on(layer)  # (held: a prim of a freed stage is expired)
            apply_role(stage.GetPrimAtPath(path), args.role)
    if args.y_down:
        _turn_y_down(layer, path, args.up_axis)
    save_stage_atomic(layer, args.output)
    if not args.quiet:
        print(f"wrote {args.output}: {path} with {gaussians.count:,} Gaussians{bricks}, SH degree "
              f"{gaussians.sh_degree}, {args.precision} precision")
    from usd_gs.cli import hold

    hold(layer, gaussians, made)  # freed by the process's end, not here (quick_exit)
    return 0


def _turn_y_down(layer, path, up_axis: str) -> None:
    """``--y-down``: an ``xformOp:rotateX:yDown`` on the prim at ``path`` (the bricks' parent) that
    turns a Y-down capture up: 180 degrees for a Y-up stage (+Y down becomes +Y up), -90 for a Z-up
    one (-Y, the capture's up, becomes +Z). The Gaussian data is not changed."""
    from pxr import UsdGeom

    stage = _stage_on(layer)
    xf = UsdGeom.Xformable(stage.GetPrimAtPath(path))
    xf.AddRotateXOp(opSuffix="yDown").Set(180.0 if up_axis == "Y" else -90.0)


def _stage_on(layer):
    """A stage whose root layer is ``layer`` (what it authors goes there)."""
    from pxr import Usd

    return Usd.Stage.Open(layer)


def register_import(sub, formatter):
    p = sub.add_parser("import", formatter_class=formatter,
                       help="convert a 3DGS capture (.ply, .compressed.ply, .splat, .spz, SOG) or a frame "
                            "sequence into a USD stage",
                       description="Convert a 3DGS capture into a USD stage holding one "
                                   "UsdVol.ParticleField3DGaussianSplat prim. Formats: INRIA .ply (SH degree "
                                   "0..3), PlayCanvas .compressed.ply, antimatter15 .splat, Niantic .spz, SOG "
                                   "(bundled .sog, a meta.json folder, or a LOD set lod-meta.json: --lod picks "
                                   "the level). An input with a frame token (name_####.sog, name_%04d.ply) is a "
                                   "sequence: one prim with one time sample per frame (attributes equal in every "
                                   "frame are authored once); counts may change between frames. The raw PLY "
                                   "log-scales, opacity logits and extra fields are kept as usdgs: attributes so "
                                   "'usdgs export' gives the PLY back bit for bit. The data is not rotated: "
                                   "--up-axis only sets the stage's upAxis metadata, and --y-down turns a "
                                   "Y-down capture up with a transform on the prim.")
    p.add_argument("input", help=f"input capture ({READ_HELP}), or a frame pattern of them")
    p.add_argument("-o", "--output", required=True, help="output stage (.usd/.usdc binary, .usda text)")
    p.add_argument("--prim", help="prim path of the Gaussians (default: /<input file stem>)")
    p.add_argument("--role", choices=("auto", "scene", "avatar", "object"),
                   help="apply UsdGsRoleAPI with this usdgs:role (default: not applied, role auto)")
    p.add_argument("--lod", type=int, metavar="N",
                   help="level of a SOG LOD set (0 = finest; default: the finest level whose chunks are all "
                        "present)")
    p.add_argument("--frames", metavar="A-B",
                   help="frames of a sequence pattern (default: every frame found on disk); a missing file "
                        "is an error")
    p.add_argument("--fps", type=float, default=24.0, help="frames per second of a sequence (timeCodesPerSecond)")
    p.add_argument("--up-axis", choices=("Y", "Z"), default="Y", help="stage upAxis metadata")
    p.add_argument("--meters-per-unit", type=float, default=1.0, help="stage metersPerUnit metadata")
    p.add_argument("--y-down", action="store_true",
                   help="the capture is Y-down (OpenCV/COLMAP cameras: many .splat, .ply and PlayCanvas SOG "
                        "captures show upside down; check with 'usdgs render'): author "
                        "xformOp:rotateX:yDown on the prim, 180 degrees for --up-axis Y, -90 for Z (the Gaussian "
                        "data is kept as it is; 'usdgs export --local' gives it back)")
    p.add_argument("--precision", choices=("float", "half"), default="float",
                   help="author the float attributes or their half (*h) variants")
    p.add_argument("--brick-size", type=int, metavar="N",
                   help="split into spatial bricks of at most N Gaussians: an Xform at --prim with children "
                        "Brick_0000... (shadows then re-author only the bricks they touch)")
    p.add_argument("--no-raw", action="store_true",
                   help="do not keep the raw PLY values (smaller file; round trip no longer bit-exact)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_import, quick_exit=True)


# ----------------------------------------------------------------------------- export
def _export_prims(stage, args, time):
    """The Gaussian prims to export at ``time``: the --prim ones, else every one that is
    visible then and has purpose default or render (guides and proxies are left out)."""
    from pxr import UsdGeom

    from usd_gs.usd.gaussian_prim import find_gaussian_prims
    from usd_gs.usd.stage import gaussian_prim

    if args.prim:
        return [gaussian_prim(stage, text, args.stage) for text in args.prim]
    shown = (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)
    return [p for p in find_gaussian_prims(stage)
            if UsdGeom.Imageable(p).ComputeVisibility(time) != UsdGeom.Tokens.invisible
            and UsdGeom.Imageable(p).ComputePurpose() in shown]


def _is_static(prim) -> bool:
    """True when nothing that ``read_gaussian_prim`` uses can vary in time: no attribute of the
    prim might be time-varying (samples or clips), no skeleton binding, and no transform of it or
    an ancestor might be time-varying. Such prims are read once per export."""
    from pxr import UsdGeom

    if any(a.ValueMightBeTimeVarying() for a in prim.GetAttributes()):
        return False
    if any(r.GetName().startswith("skel:") for r in prim.GetRelationships()):
        return False
    p = prim
    while p and not p.IsPseudoRoot():
        xf = UsdGeom.Xformable(p)
        if xf and xf.TransformMightBeTimeVarying():
            return False
        p = p.GetParent()
    return True


def _export_frames(stage, args) -> list:
    """``[(time code, output path)]``."""
    from pxr import Usd

    from usd_gs.io.sequence import frame_path, is_pattern, parse_frames
    from usd_gs.usd.stage import time_code

    pattern = is_pattern(args.output)
    if args.frames:
        if args.time is not None:
            raise UserError("give --time or --frames, not both")
        a, b = parse_frames(args.frames)
        if b > a and not pattern:
            raise UserError(f"{args.output}: several frames need a frame token in the output name "
                            "(out_####.splat or out_%04d.ply)")
        return [(Usd.TimeCode(float(f)), frame_path(args.output, f)) for f in range(a, b + 1)]
    if pattern and args.time is None:
        a, b = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        if stage.HasAuthoredTimeCodeRange() and b >= a:
            frames = range(math.floor(a), math.floor(b) + 1)
            return [(Usd.TimeCode(float(f)), frame_path(args.output, f)) for f in frames]
    tc = time_code(args.time)
    t = tc.GetValue() if not (tc.IsDefault() or tc.IsEarliestTime()) else 0
    return [(tc, frame_path(args.output, int(round(t))) if pattern else args.output)]


def cmd_export(args) -> int:
    from usd_gs.gaussians import GaussianSet
    from usd_gs.io.checks import check_exportable
    from usd_gs.io.formats import WRITE_EXTS, write_capture
    from usd_gs.usd.gaussian_prim import read_gaussian_prim
    from usd_gs.usd.stage import open_stage

    ext = os.path.splitext(args.output)[1].lower()
    if ext not in WRITE_EXTS:
        raise UserError(f"{args.output}: output must end in {', '.join(WRITE_EXTS)} (got '{ext or 'no extension'}')")
    parent = os.path.dirname(os.path.abspath(args.output))
    if not os.path.isdir(parent):
        raise UserError(f"{args.output}: output directory {parent} does not exist")
    stage = open_stage(args.stage)
    frames = _export_frames(stage, args)
    prims = _export_prims(stage, args, frames[0][0])
    if args.local and len(prims) != 1:
        raise UserError("--local needs exactly one Gaussian prim (prim-local spaces cannot be merged)")
    total = 0
    static: dict = {}  # prim path -> Gaussians of prims that cannot change between frames
    for i, (tc, out) in enumerate(frames):
        if i and not args.prim:
            prims = _export_prims(stage, args, tc)  # visibility may be animated
        if not prims:
            raise UserError(f"{args.stage}: no visible Gaussian prim to export at time {tc.GetValue():g}")
        sets = []
        for prim in prims:
            key = prim.GetPath()
            if key in static:
                sets.append(static[key])
                continue
            g = read_gaussian_prim(prim, tc, world=not args.local)
            if len(frames) > 1 and _is_static(prim):
                static[key] = g
            sets.append(g)
        for s in sets:
            check_exportable(s)  # opacities outside [0, 1]: refused, the element named (issue #17)
        g = sets[0] if len(sets) == 1 else GaussianSet.concatenate(sets, label=args.stage)
        write_capture(out, g)
        total += g.count
    if not args.quiet:
        space = "prim-local" if args.local else "world"
        names = ", ".join(str(p.GetPath()) for p in prims[:4]) + (" ..." if len(prims) > 4 else "")
        if len(frames) == 1:
            print(f"wrote {frames[0][1]}: {total:,} Gaussians from {names} ({space} space)")
        else:
            print(f"wrote {len(frames)} files {frames[0][1]} .. {frames[-1][1]}: {total:,} Gaussians in all "
                  f"from {len(prims)} prim(s) {names} ({space} space)")
    return 0


def register_export(sub, formatter):
    p = sub.add_parser("export", formatter_class=formatter,
                       help="write Gaussian prims to .ply, .splat, .spz or .sog files for splat viewers",
                       description="Write the Gaussians of the listed prims (default: every visible Gaussian prim, "
                                   "merged) in world space (the prims' transforms applied; --local for one prim "
                                   "in its own space) to an INRIA .ply, an antimatter15 .splat, an .spz or a "
                                   "bundled .sog (SH degree 0 only), one file per frame. On an output of "
                                   "'usdgs process' the processed (shadowed, relit) SH is what is written. With "
                                   "--frames A-B (or a frame token in -o and no --time: the stage's whole time "
                                   "range) the output name needs a frame token: out_####.splat.")
    p.add_argument("stage", help="input USD stage")
    p.add_argument("--prim", action="append",
                   help="a ParticleField3DGaussianSplat prim to export (repeatable; default: every visible Gaussian "
                        "prim)")
    p.add_argument("--time", default=None,
                   help="time code: a number, 'default' or 'earliest' (default: earliest, the first frame)")
    p.add_argument("--frames", metavar="A-B", help="export frames A..B, one file each")
    p.add_argument("--local", action="store_true", help="export in prim-local space (one prim only)")
    p.add_argument("-o", "--output", required=True, help="output .ply, .splat, .spz or .sog (with '####' for frames)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_export)


# ----------------------------------------------------------------------------- inspect
def _fmt_bounds(lo, hi) -> str:
    if lo is None or hi is None:
        return "-"
    return "[" + ", ".join(f"{a:.3g}" for a in lo) + "] .. [" + ", ".join(f"{b:.3g}" for b in hi) + "]"


def inspect_rows(stage, time) -> list[dict]:
    """One dict per Gaussian prim: path, count, sh_degree, role, precision, time range, bounds."""
    from usd_gs.usd.gaussian_prim import describe_gaussian_prim, find_gaussian_prims

    rows = []
    for prim in find_gaussian_prims(stage):
        info = describe_gaussian_prim(prim, time)
        ts = info.time_samples
        rows.append({
            "path": info.path, "count": info.count, "sh_degree": info.sh_degree,
            "role": info.role.role + ("" if info.role.applied else "*"),
            "precision": info.precision,
            "time_samples": "-" if not ts else f"{ts[0]:g}..{ts[1]:g}",
            "bounds": _fmt_bounds(*(info.world_bounds or (None, None))),
        })
    return rows


def cmd_inspect(args) -> int:
    import json

    from usd_gs.usd.stage import open_stage, time_code

    stage = open_stage(args.stage)
    rows = inspect_rows(stage, time_code(args.time))
    if args.json:
        json.dump(rows, sys.stdout, indent=2)
        print()
        return 0
    up = stage.GetMetadata("upAxis")
    mpu = stage.GetMetadata("metersPerUnit")
    print(f"{args.stage}: upAxis {up}, metersPerUnit {mpu:g}, time codes "
          f"{stage.GetStartTimeCode():g}..{stage.GetEndTimeCode():g}, {len(rows)} Gaussian prim(s)")
    from usd_gs.usd.gaussian_prim import retyped_gaussian_prims, retyped_message
    from usd_gs.usd.stage import root_metadata_warnings

    for w in [retyped_message(*r) for r in retyped_gaussian_prims(stage)] + root_metadata_warnings(stage, args.stage):
        print(f"warning: {w}")
    if not rows:
        return 0
    cols = [("path", "prim"), ("count", "count"), ("sh_degree", "SH"), ("role", "role"),
            ("precision", "storage"), ("time_samples", "time samples"), ("bounds", "world bounds (min .. max)")]
    cells = [[f"{r[k]:,}" if k == "count" else str(r[k]) for k, _ in cols] for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, (_, h) in enumerate(cols)]
    print("  ".join(h.ljust(w) for (_, h), w in zip(cols, widths, strict=True)))
    for c in cells:
        print("  ".join(v.ljust(w) for v, w in zip(c, widths, strict=True)))
    if any(r["role"].endswith("*") for r in rows):
        print("* role not authored (UsdGsRoleAPI not applied): decided automatically by 'usdgs process'")
    return 0


def register_inspect(sub, formatter):
    p = sub.add_parser("inspect", formatter_class=formatter, help="list the Gaussian prims of a stage",
                       description="Print a table of every ParticleField3DGaussianSplat prim: path, particle "
                                   "count, SH degree, role, float/half storage, time-sample range and world "
                                   "bounds of the centres.")
    p.add_argument("stage", help="USD stage")
    p.add_argument("--time", default=None,
                   help="time code for counts and bounds: a number, 'default' or 'earliest' (default: earliest)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_inspect)


# ----------------------------------------------------------------------------- validate
def cmd_validate(args) -> int:
    from usd_gs.usd.stage import open_stage, root_metadata_warnings
    from usd_gs.usd.validate import validate_stage

    stage = open_stage(args.stage)
    problems = validate_stage(stage)
    for p in problems:
        elem = "" if p.element is None else f"[{p.element}]"
        print(f"{p.prim_path}.{p.attribute}{elem}: {p.message}")
    if not args.quiet:  # (valid USD either way: said, not counted as a problem)
        for w in root_metadata_warnings(stage, args.stage):
            print(f"warning: {w}")
    if problems:
        print(f"{args.stage}: {len(problems)} problem(s)", file=sys.stderr)
        return 1
    if not args.quiet:
        print(f"{args.stage}: ok")
    return 0


def register_validate(sub, formatter):
    p = sub.add_parser("validate", formatter_class=formatter, help="check Gaussian prims against the rules",
                       description="Check every ParticleField3DGaussianSplat prim against NVIDIA's VG.035 "
                                   "rules (values present, lengths, opacity range, positive scales, unit "
                                   "quaternions, SH degree, interpolation and elementSize) plus NaN/Inf and "
                                   "transform checks, at every time sample. Exit code 1 when any fails; each "
                                   "problem is listed as prim.attribute[first bad element]: message. Also warns "
                                   "(without failing) where the root layer leaves metersPerUnit or upAxis to a "
                                   "sublayer or reference that says otherwise.")
    p.add_argument("stage", help="USD stage")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing when the stage is valid")
    p.set_defaults(handler=cmd_validate)


REGISTRARS = [register_import, register_export, register_inspect, register_validate]
