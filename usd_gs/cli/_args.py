"""Argument helpers shared by several commands: role options, ``--config`` loading into
``ProcessOptions``, and the printed table of a shot's lights."""

from __future__ import annotations


def add_role_options(p) -> None:
    """--avatar/--object/--scene: roles given on the command line (``usdgs process`` and ``usdgs lights``)."""
    p.add_argument("--avatar", action="append", metavar="PATH", help="treat this prim as an avatar (repeatable)")
    p.add_argument("--object", action="append", metavar="PATH", help="treat this prim as an inserted object")
    p.add_argument("--scene", action="append", metavar="PATH", help="treat this prim as scene")


def role_paths(args) -> dict:
    """The ``ProcessOptions`` keyword arguments of the role options."""
    return {"scene_paths": tuple(args.scene or ()), "avatar_paths": tuple(args.avatar or ()),
            "object_paths": tuple(args.object or ())}


def build_options(args):
    """``ProcessOptions`` from ``--config`` (if given) with the options given on the command line winning."""
    from dataclasses import replace

    from usd_gs.pipeline.options import ProcessOptions, dgsm_config, load_config, process_kwargs

    cfg = load_config(args.config) if args.config else {}
    dgsm_kw = {k: getattr(args, k) for k in ("atlas_size", "n_samples", "sampling", "seed")
               if getattr(args, k, None) is not None}
    if args.no_roi:
        dgsm_kw["use_roi"] = False
    if args.no_tile_culling:
        dgsm_kw["use_tile_culling"] = False
    kw = process_kwargs(cfg)
    for k in ("frames", "lights", "direct_fraction", "probe_points", "transfer_degree", "probe_supersample",
              "precision", "sh_tolerance", "color_space"):
        v = getattr(args, k, None)
        if v is not None:
            kw[k] = v
    if getattr(args, "aovs", None) is not None:
        kw["aovs"] = tuple(a.strip() for a in args.aovs.split(",") if a.strip())
    if isinstance(kw.get("aovs"), list):  # from a JSON config
        kw["aovs"] = tuple(kw["aovs"])
    if args.lights_per_frame:
        kw["lights_per_frame"] = True
    if getattr(args, "bake_skinning", False):
        kw["bake_skinning"] = True
    if getattr(args, "allow_missing", False):
        kw["allow_missing"] = True
    return ProcessOptions(dgsm=replace(dgsm_config(cfg), **dgsm_kw), **role_paths(args), **kw)


def print_lights(lights) -> None:
    """One line per light: kind, where (position of a point light, direction of a distant one),
    intensity, estimation score and source."""
    print(f"lights ({len(lights)}):")
    for lt in lights:
        where = (f"at ({lt.position[0]:.2f}, {lt.position[1]:.2f}, {lt.position[2]:.2f})" if lt.kind == "point"
                 else "environment" if lt.kind == "dome"
                 else f"along ({lt.direction[0]:.2f}, {lt.direction[1]:.2f}, {lt.direction[2]:.2f})")
        score = "" if lt.score is None else f", score {lt.score:.3g}"
        kind = f"rect {lt.width:.2f} x {lt.height:.2f}" if lt.form == "rect" else lt.kind
        print(f"  {lt.name}: {kind} {where}, intensity {lt.intensity:.3g}{score} [{lt.source}]")
