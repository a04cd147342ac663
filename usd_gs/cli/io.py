"""The I/O subcommands: ``import``, ``export``, ``inspect`` and ``validate``."""

from __future__ import annotations

import os
import re
import sys

from usd_gs.errors import UserError

READERS = {".ply": "ply", ".spz": "spz"}


def read_gaussian_file(path: str):
    """Read a ``.ply`` (INRIA 3DGS) or ``.spz`` file into a ``GaussianSet``."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in READERS:
        raise UserError(f"{path}: unsupported input type '{ext or 'no extension'}' (expected .ply or .spz)")
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    if ext == ".ply":
        from usd_gs.io.ply import read_ply
        return read_ply(path)
    from usd_gs.io.spz import read_spz
    return read_spz(path)


def default_prim_path(input_path: str) -> str:
    """``/<stem>`` with characters that USD does not allow in names replaced by '_'."""
    stem = re.sub(r"[^A-Za-z0-9_]", "_", os.path.splitext(os.path.basename(input_path))[0]) or "Gaussians"
    if stem[0].isdigit():
        stem = "_" + stem
    return "/" + stem


# ----------------------------------------------------------------------------- import
def cmd_import(args) -> int:
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
    from usd_gs.usd.schema import apply_role
    from usd_gs.usd.stage import check_usd_output_path, prim_path

    check_usd_output_path(args.output)
    path = prim_path(args.prim or default_prim_path(args.input))
    if os.path.abspath(args.output) == os.path.abspath(args.input):
        raise UserError(f"{args.output}: output would overwrite the input")
    # The readers reject NaN/Inf, zero quaternions and out-of-range values naming the
    # field and element, so no second validation pass is needed here.
    gaussians = read_gaussian_file(args.input)
    root = path.GetPrefixes()[0]
    stage = new_stage(up_axis=args.up_axis, meters_per_unit=args.meters_per_unit, default_prim=root.name)
    bricks = ""
    if args.brick_size is not None:
        from usd_gs.usd.bricks import write_bricked

        n = len(write_bricked(stage, str(path), gaussians, args.brick_size, keep_raw=not args.no_raw,
                              precision=args.precision, role=args.role))
        bricks = f" in {n} bricks"
    else:
        prim = write_gaussian_prim(stage, str(path), gaussians, keep_raw=not args.no_raw, precision=args.precision)
        if args.role:
            apply_role(prim, args.role)
    save_stage_atomic(stage, args.output)
    if not args.quiet:
        print(f"wrote {args.output}: {path} with {gaussians.count:,} Gaussians{bricks}, SH degree "
              f"{gaussians.sh_degree}, {args.precision} precision")
    return 0


def register_import(sub, formatter):
    p = sub.add_parser("import", formatter_class=formatter,
                       help="convert a 3DGS .ply or .spz file into a USD stage",
                       description="Convert an INRIA 3DGS .ply (SH degree 0..3) or a Niantic .spz file into a "
                                   "USD stage holding one UsdVol.ParticleField3DGaussianSplat prim. The raw PLY "
                                   "log-scales, opacity logits and extra fields are kept as usdgs: attributes so "
                                   "'usdgs export' gives the PLY back bit for bit. The data is not rotated: "
                                   "--up-axis only sets the stage's upAxis metadata.")
    p.add_argument("input", help="input .ply or .spz file")
    p.add_argument("-o", "--output", required=True, help="output stage (.usd/.usdc binary, .usda text)")
    p.add_argument("--prim", help="prim path of the Gaussians (default: /<input file stem>)")
    p.add_argument("--role", choices=("auto", "scene", "avatar", "object"),
                   help="apply UsdGsRoleAPI with this usdgs:role (default: not applied, role auto)")
    p.add_argument("--up-axis", choices=("Y", "Z"), default="Y", help="stage upAxis metadata")
    p.add_argument("--meters-per-unit", type=float, default=1.0, help="stage metersPerUnit metadata")
    p.add_argument("--precision", choices=("float", "half"), default="float",
                   help="author the float attributes or their half (*h) variants")
    p.add_argument("--brick-size", type=int, metavar="N",
                   help="split into spatial bricks of at most N Gaussians: an Xform at --prim with children "
                        "Brick_0000... (shadows then re-author only the bricks they touch)")
    p.add_argument("--no-raw", action="store_true",
                   help="do not keep the raw PLY values (smaller file; round trip no longer bit-exact)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_import)


# ----------------------------------------------------------------------------- export
def cmd_export(args) -> int:
    from usd_gs.io.ply import write_ply
    from usd_gs.usd.gaussian_prim import read_gaussian_prim
    from usd_gs.usd.stage import gaussian_prim, open_stage, time_code

    if os.path.splitext(args.output)[1].lower() != ".ply":
        raise UserError(f"{args.output}: output must be a .ply file")
    stage = open_stage(args.stage)
    prim = gaussian_prim(stage, args.prim, args.stage)
    gaussians = read_gaussian_prim(prim, time_code(args.time), world=not args.local)
    write_ply(args.output, gaussians)
    if not args.quiet:
        space = "prim-local" if args.local else "world"
        print(f"wrote {args.output}: {gaussians.count:,} Gaussians from {args.prim} ({space} space)")
    return 0


def register_export(sub, formatter):
    p = sub.add_parser("export", formatter_class=formatter, help="write one Gaussian prim to an INRIA .ply",
                       description="Write the Gaussians of one prim at one time code to an INRIA 3DGS .ply, "
                                   "in world space (the prim's transforms applied) unless --local.")
    p.add_argument("stage", help="input USD stage")
    p.add_argument("--prim", required=True, help="path of the ParticleField3DGaussianSplat prim")
    p.add_argument("--time", default=None,
                   help="time code: a number, 'default' or 'earliest' (default: earliest, the first frame)")
    p.add_argument("--local", action="store_true", help="export in prim-local space")
    p.add_argument("-o", "--output", required=True, help="output .ply")
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
    from usd_gs.usd.stage import open_stage
    from usd_gs.usd.validate import validate_stage

    stage = open_stage(args.stage)
    problems = validate_stage(stage)
    for p in problems:
        elem = "" if p.element is None else f"[{p.element}]"
        print(f"{p.prim_path}.{p.attribute}{elem}: {p.message}")
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
                                   "problem is listed as prim.attribute[first bad element]: message.")
    p.add_argument("stage", help="USD stage")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing when the stage is valid")
    p.set_defaults(handler=cmd_validate)


REGISTRARS = [register_import, register_export, register_inspect, register_validate]
