"""Deciding the role of every Gaussian prim of a shot: scene, avatar or object.

Order (the main job's contract):

1. ``usdgs:role`` authored on the prim (``UsdGsRoleAPI``) when it is not ``auto``;
2. otherwise the command-line lists ``--scene`` / ``--avatar`` / ``--object``;
3. otherwise ``auto``: a prim whose Gaussians or transform vary in time is dynamic:
   an ``avatar`` when its name looks like a person (:data:`AVATAR_NAME_HINT`), else an
   ``object``; a static prim is ``scene``.

A flag that contradicts an authored role is reported as a warning (the authored role wins).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from usd_gs.errors import UserError
from usd_gs.usd.schema import RoleInfo

#: Prim names that mark a dynamic prim as an avatar under ``auto``.
AVATAR_NAME_HINT = re.compile(
    r"avatar|human|person|people|man\b|man_|woman|girl|boy|character|actor|body|biker|walker|dancer|player|"
    r"cesiumman", re.IGNORECASE)


@dataclass(frozen=True)
class ResolvedRole:
    """The role a prim plays in this run and where that decision came from.

    ``source`` is 'schema', 'flag' or 'auto'; the shadow/relight switches come from the
    role schema attributes (fallback true).
    """

    path: str
    role: str
    source: str
    dynamic: bool
    casts_shadows: bool
    receives_shadows: bool
    relight: bool

    @property
    def is_caster(self) -> bool:
        return self.casts_shadows

    @property
    def is_dynamic_role(self) -> bool:
        return self.role in ("avatar", "object")

    @property
    def per_frame(self) -> bool:
        """Processed at every frame (read, cast per frame, relit): time-varying prims and every
        avatar or object, also one that holds a single pose (an inserted static character)."""
        return self.dynamic or self.is_dynamic_role


def resolve_roles(infos, scene_paths=(), avatar_paths=(), object_paths=()) -> tuple[list[ResolvedRole], list[str]]:
    """Resolve roles for ``infos`` (``usd_io.GaussianPrimInfo``, one per Gaussian prim).

    Returns (roles in the order of ``infos``, warnings). A flag naming a path that is not a
    Gaussian prim of the stage, or one path in two lists, raises ``UserError``.
    """
    known = {i.path for i in infos}
    flags: dict[str, str] = {}
    for role, paths in (("scene", scene_paths), ("avatar", avatar_paths), ("object", object_paths)):
        for p in paths or ():
            p = str(p)
            if p not in known:
                listed = ", ".join(sorted(known)) or "none"
                raise UserError(f"--{role} {p}: not a ParticleField3DGaussianSplat prim of the stage "
                                f"(Gaussian prims: {listed})")
            if p in flags and flags[p] != role:
                raise UserError(f"{p}: given both as --{flags[p]} and --{role}")
            flags[p] = role
    out, warnings = [], []
    for info in infos:
        authored: RoleInfo = info.role
        name = info.path.rsplit("/", 1)[-1]
        if authored.role != "auto":
            role, source = authored.role, "schema"
            if info.path in flags and flags[info.path] != role:
                warnings.append(f"{info.path}: --{flags[info.path]} ignored, usdgs:role is authored as '{role}'")
        elif info.path in flags:
            role, source = flags[info.path], "flag"
        elif info.animated:
            role, source = ("avatar" if AVATAR_NAME_HINT.search(name) else "object"), "auto"
        else:
            role, source = "scene", "auto"
        out.append(ResolvedRole(info.path, role, source, bool(info.animated), authored.casts_shadows,
                                authored.receives_shadows, authored.relight))
    return out, warnings


def role_table(roles: list[ResolvedRole], counts: dict[str, int] | None = None, group_min: int = 4) -> str:
    """A printable table: prim, role, source, dynamic, casts, receives, relight (and count).

    ``group_min`` or more sibling prims with identical settings (e.g. the bricks of one
    capture) are shown as one row ``<parent>/* (N prims)`` with their summed count.
    """
    groups: dict[tuple, list[ResolvedRole]] = {}
    for r in roles:
        key = (r.path.rsplit("/", 1)[0], r.role, r.source, r.dynamic, r.casts_shadows, r.receives_shadows, r.relight)
        groups.setdefault(key, []).append(r)
    rows_src = []
    for key, members in groups.items():
        if len(members) >= group_min:
            rows_src.append((f"{key[0]}/* ({len(members)} prims)", members[0], [m.path for m in members]))
        else:
            rows_src.extend((m.path, m, [m.path]) for m in members)
    head = ["prim", "role", "from", "dynamic", "casts", "receives", "relight"] + (["count"] if counts else [])

    def yn(v):
        return "yes" if v else "no"

    rows = [[name, r.role, r.source, yn(r.dynamic), yn(r.casts_shadows), yn(r.receives_shadows), yn(r.relight)]
            + ([f"{sum(counts.get(p, 0) for p in paths):,}"] if counts else []) for name, r, paths in rows_src]
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(lines)
