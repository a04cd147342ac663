"""``usdgs rig``: bind a captured Gaussian avatar to a skeleton (logic in ``usd_gs/demo/rig.py``)."""

from __future__ import annotations

import time
import warnings

from usd_gs.errors import UserError


def cmd_rig(args) -> int:
    import importlib.util

    from usd_gs.demo.rig import parse_matrix, rig_avatar

    missing = [m for m in ("scipy", "trimesh") if importlib.util.find_spec(m) is None]
    if missing:
        raise UserError(f"usdgs rig needs {' and '.join(missing)} (pip install 'usd-gs[rig]')")
    t0 = time.perf_counter()
    if args.influences < 1:
        raise UserError(f"--influences must be >= 1, got {args.influences}")
    if not args.max_distance > 0:
        raise UserError(f"--max-distance must be > 0, got {args.max_distance}")
    if not args.fps > 0:
        raise UserError(f"--fps must be > 0, got {args.fps}")
    matrix = parse_matrix(args.align_matrix) if args.align_matrix else None
    say = (lambda *a: None) if args.quiet else print
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = rig_avatar(args.avatar, args.skin, args.output, skeleton=args.skeleton, weights=args.weights,
                         motion=args.motion, joint_map=args.joint_map, up=args.up, facing=args.facing,
                         align_matrix=matrix, influences=args.influences, max_distance=args.max_distance,
                         fps=args.fps, motion_up=args.motion_up, icp_iterations=args.icp_iterations,
                         skinning_method=args.skinning_method, log=say)
    for w in caught:
        if not args.quiet:
            print(f"warning: {w.message}")
    for note in res.notes:
        say(f"  note: {note}")
    share = "" if res.stretched_share is None else \
        f"; {100 * res.stretched_share:.1f} % of the Gaussians change scale by > 20 % (mean over frames)"
    say(f"rigged {res.count:,} Gaussians to {res.joints} joints, {res.frames} frame(s) -> {res.output} "
        f"in {time.perf_counter() - t0:.2f} s{share}")
    return 0


def register_rig(sub, formatter):
    p = sub.add_parser(
        "rig", formatter_class=formatter, help="bind a Gaussian avatar to a skeleton (UsdSkel) and animate it",
        description="Align a captured Gaussian avatar (T-pose) with a rigged mesh, transfer its skinning weights "
                    "to every Gaussian (closest surface point, barycentric blend; Gaussians far from the surface "
                    "take the nearest vertex's weights, counted in a warning) and write a UsdSkel stage: "
                    "/Avatar (SkelRoot), /Avatar/Skeleton, /Avatar/Skeleton/Motion (SkelAnimation from --motion: "
                    "a BVH retargeted by joint names, or a glTF's own animation) and /Avatar/Gaussians, the "
                    "bind-pose Gaussians with UsdSkel.BindingAPI (every usdgs command reads them skinned). "
                    "Needs scipy and trimesh.")
    p.add_argument("avatar", help="the avatar's Gaussians: .ply or a USD stage (its first Gaussian prim)")
    p.add_argument("--skin", required=True, help="rigged mesh: a skinned .glb, or a MakeHuman .obj (with --skeleton "
                                                 "and --weights)")
    p.add_argument("--skeleton", metavar="FILE.mhskel", help="MakeHuman skeleton for an .obj skin")
    p.add_argument("--weights", metavar="FILE.mhw", help="MakeHuman skinning weights for an .obj skin")
    p.add_argument("--motion", metavar="FILE", help="motion: .bvh (retargeted by joint names) or .glb; default: the "
                                                    "skin's own glTF animation, else the bind pose (one frame)")
    p.add_argument("--joint-map", metavar="MAP",
                   help="BVH -> skeleton joint names: a .json object or 'bvh:skel,bvh2:skel2' (default: the "
                        "built-in MakeHuman and CMU maps, or equal names, whichever matches most)")
    p.add_argument("--up", default="+y", help="the avatar's up axis (+y, -y, +z, -z, +x, -x)")
    p.add_argument("--facing", default="auto", help="the avatar's front (+z, -z, +x, -x, or auto: where the toes "
                                                    "point)")
    p.add_argument("--align-matrix", metavar="M",
                   help="explicit avatar -> rig-space similarity: 16 numbers, row-major 4x4 acting on column "
                        "vectors, or a .json 4x4 list; replaces the automatic fit (rig space: metres, Y-up, "
                        "facing +Z, feet at y = 0)")
    p.add_argument("--icp-iterations", type=int, default=10, help="similarity ICP iterations after the coarse fit")
    p.add_argument("--influences", type=int, default=4, help="joint influences per Gaussian")
    p.add_argument("--max-distance", type=float, default=0.05,
                   help="metres: Gaussians farther from the skin take the nearest vertex's weights")
    p.add_argument("--motion-up", default="auto", help="the BVH's up axis (+y, +z or auto)")
    p.add_argument("--fps", type=float, default=24.0, help="time codes per second of the output")
    p.add_argument("--skinning-method", choices=("lbs", "dq"), default="lbs",
                   help="linear blend skinning, or dual quaternions (primvars:skel:skinningMethod dualQuaternion: "
                        "no volume loss where joints twist)")
    p.add_argument("-o", "--output", required=True, help="output stage (.usda, .usd, .usdc)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(handler=cmd_rig)


REGISTRARS = [register_rig]
