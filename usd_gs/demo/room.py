"""A generated, pre-lit room of scene Gaussians with two lamp emitters (pure numpy).

Coordinates: **Y-up, metres**. The room is the box ``[-sx/2, sx/2] x [0, sy] x [-sz/2, sz/2]``
(floor at y = 0). Surfaces are rectangles covered by flat Gaussians on a jittered grid
(local z axis = surface normal pointing into the room / out of the furniture, sigma
in-plane = ``0.6 * spacing``, along the normal ``thickness_ratio`` times that). Optional
:class:`DetailRegion` boxes give the surfaces inside them a higher density (smaller, denser
Gaussians, as a capture has on the surfaces it saw up close): each surface rectangle is cut
into the part inside the box and up to four strips around it, each sampled on its own
jittered grid, so the pieces tile the rectangle without gaps or overlaps. Parts:
floor, four walls, ceiling (optional), furniture boxes (a table with legs, a sofa, a
shelf) and the lamp emitters.

Surface colours are "baked" like a capture of a lit room: linear albedo (with a plank
pattern on the floor and small per-Gaussian noise) times
``ambient + sum_lamps intensity * colour * max(0, N.L) / r^2 * visible``, where
``visible`` is a hard shadow test of the segment to the lamp against the furniture boxes;
clipped to [0, 1]. Lamp emitters are compact clusters of tiny, bright Gaussians (linear
colour = lamp colour * ``emitter_gain``, luminance about 3..8) that a light estimator
should find. Colours are stored as SH DC in the 3DGS convention
``DC = (colour - 0.5) / C0``; bands 1..``sh_degree`` are zero (diffuse scene).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usd_gs import sh3dgs
from usd_gs.gaussians import GaussianSet, matrix_to_quaternion

PART_FLOOR, PART_WALL, PART_CEILING, PART_FURNITURE, PART_LAMP = 0, 1, 2, 3, 4
PART_NAMES = {PART_FLOOR: "floor", PART_WALL: "wall", PART_CEILING: "ceiling",
              PART_FURNITURE: "furniture", PART_LAMP: "lamp"}


@dataclass
class Lamp:
    """A point-like emitter: ``position`` (3,) metres, ``color`` (3,) linear RGB (max 1),
    ``intensity`` (radiant scale: irradiance at 1 m is ``intensity * color``)."""

    position: np.ndarray
    color: np.ndarray
    intensity: float


@dataclass
class Box:
    """Axis-aligned furniture box, ``lo``/``hi`` (3,) corners in metres, linear ``albedo`` (3,)."""

    name: str
    lo: np.ndarray
    hi: np.ndarray
    albedo: np.ndarray


@dataclass(frozen=True)
class DetailRegion:
    """An axis-aligned box (``lo``, ``hi``: (3,) metres): the parts of the room's surface
    rectangles inside it are sampled at ``density`` Gaussians per m^2 instead of the room's."""

    lo: tuple
    hi: tuple
    density: float


@dataclass
class RoomScene:
    """The generated room: ``gaussians`` (all parts, float32), ``part`` (N,) int8 part ids
    (``PART_*``), ``albedo`` (N, 3) float32 linear diffuse albedo before lighting (0 for the
    emitters; ground truth for relighting checks), ``lamps``, the furniture ``boxes``,
    ``size`` (3,) metres, ``ambient`` and the per-part ``counts`` by name."""

    gaussians: GaussianSet
    part: np.ndarray
    albedo: np.ndarray
    lamps: list[Lamp]
    boxes: list[Box]
    size: np.ndarray
    ambient: float
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def lamp_mask(self) -> np.ndarray:
        return self.part == PART_LAMP


# ----------------------------------------------------------------------------- geometry
def _frame(normal: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """3x3 rotation with columns (tangent, normal x tangent, normal)."""
    n = normal / np.linalg.norm(normal)
    t = tangent - np.dot(tangent, n) * n
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n], axis=1)


def _rectangle(origin, edge_u, edge_v, normal, spacing: float, rng: np.random.Generator):
    """Jittered-grid samples on the rectangle ``origin + a*edge_u + b*edge_v`` (a, b in [0, 1]).

    Returns (points (n, 3), rotation (3, 3) shared by all, uv (n, 2) metres along the edges).
    """
    origin, edge_u, edge_v = (np.asarray(a, np.float64) for a in (origin, edge_u, edge_v))
    lu, lv = np.linalg.norm(edge_u), np.linalg.norm(edge_v)
    nu, nv = max(1, int(np.ceil(lu / spacing))), max(1, int(np.ceil(lv / spacing)))
    a = (np.arange(nu)[:, None] + 0.5 + rng.uniform(-0.35, 0.35, (nu, nv))) / nu
    b = (np.arange(nv)[None, :] + 0.5 + rng.uniform(-0.35, 0.35, (nu, nv))) / nv
    a, b = a.reshape(-1), b.reshape(-1)
    pts = origin + a[:, None] * edge_u + b[:, None] * edge_v
    rot = _frame(np.asarray(normal, np.float64), edge_u)
    return pts, rot, np.stack([a * lu, b * lv], axis=1)


def _snap(x: float, cell: float, up: bool) -> float:
    """``x`` (>= 0) rounded down (or up) to a whole number of ``cell`` (within 1e-9 of one: that one)."""
    k = x / cell
    r = round(k)
    if abs(k - r) < 1e-9:
        return r * cell
    return (np.ceil(k) if up else np.floor(k)) * cell


def _split_rectangle(origin, edge_u, edge_v, spacing: float, regions) -> list[tuple]:
    """Pieces ``(origin, edge_u, edge_v, spacing)`` tiling the rectangle ``origin + a edge_u +
    b edge_v`` (a, b in [0, 1]; edges along world axes): for the first region whose box meets
    the rectangle's plane and area, the part inside the box (its cut lines snapped outwards to
    whole cells of ``spacing``) gets ``min(spacing, 1 / sqrt(density))`` and the strips around
    it keep ``spacing``; every piece is split again by the remaining regions."""
    o, eu, ev = (np.asarray(a, np.float64) for a in (origin, edge_u, edge_v))
    if not regions:
        return [(o, eu, ev, spacing)]
    r, rest = regions[0], regions[1:]
    lo, hi = np.asarray(r.lo, np.float64), np.asarray(r.hi, np.float64)
    iu, iv = int(np.argmax(np.abs(eu))), int(np.argmax(np.abs(ev)))
    inorm = 3 - iu - iv
    lu, lv = abs(eu[iu]), abs(ev[iv])
    if not lo[inorm] <= o[inorm] <= hi[inorm]:
        return _split_rectangle(o, eu, ev, spacing, rest)

    def cut(axis, e, length):  # the box's extent along one edge, metres from the origin, clipped and snapped
        ends = sorted(((lo[axis] - o[axis]) / e[axis] * length, (hi[axis] - o[axis]) / e[axis] * length))
        c0 = _snap(min(max(ends[0], 0.0), length), spacing, up=False)
        c1 = min(_snap(min(max(ends[1], 0.0), length), spacing, up=True), length)
        return c0, c1

    u0, u1 = cut(iu, eu, lu)
    v0, v1 = cut(iv, ev, lv)
    if u1 - u0 <= 1e-9 or v1 - v0 <= 1e-9:
        return _split_rectangle(o, eu, ev, spacing, rest)
    du, dv = eu / lu, ev / lv
    inner = min(spacing, 1.0 / np.sqrt(r.density))
    pieces = [(0.0, u0, 0.0, lv, spacing), (u1, lu, 0.0, lv, spacing), (u0, u1, 0.0, v0, spacing),
              (u0, u1, v1, lv, spacing), (u0, u1, v0, v1, inner)]
    out = []
    for a0, a1, b0, b1, sp in pieces:
        if a1 - a0 > 1e-9 and b1 - b0 > 1e-9:
            out += _split_rectangle(o + a0 * du + b0 * dv, (a1 - a0) * du, (b1 - b0) * dv, sp, rest)
    return out


def _box_faces(lo, hi, with_bottom: bool = False):
    """(origin, edge_u, edge_v, outward normal) of the faces of an axis-aligned box."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    d = hi - lo
    ex, ey, ez = np.array([d[0], 0, 0]), np.array([0, d[1], 0]), np.array([0, 0, d[2]])
    faces = [
        (np.array([lo[0], hi[1], lo[2]]), ex, ez, np.array([0.0, 1.0, 0.0])),   # top
        (lo.copy(), ex, ey, np.array([0.0, 0.0, -1.0])),                         # back (-z)
        (np.array([lo[0], lo[1], hi[2]]), ex, ey, np.array([0.0, 0.0, 1.0])),   # front (+z)
        (lo.copy(), ez, ey, np.array([-1.0, 0.0, 0.0])),                         # -x
        (np.array([hi[0], lo[1], lo[2]]), ez, ey, np.array([1.0, 0.0, 0.0])),   # +x
    ]
    if with_bottom:
        faces.append((lo.copy(), ex, ez, np.array([0.0, -1.0, 0.0])))
    return faces


def default_boxes(size) -> list[Box]:
    """Table (top + 4 legs), sofa (seat, back, two arms) and a shelf, placed for ``size``."""
    sx, _, sz = (float(v) for v in size)
    hx, hz = sx / 2, sz / 2
    wood, fabric, shelf = np.array([0.45, 0.28, 0.15]), np.array([0.20, 0.32, 0.45]), np.array([0.60, 0.55, 0.48])
    boxes = [Box("table_top", np.array([0.2, 0.72, -1.0]), np.array([1.8, 0.78, 0.0]), wood)]
    for i, (x, z) in enumerate([(0.25, -0.95), (1.69, -0.95), (0.25, -0.11), (1.69, -0.11)]):
        boxes.append(Box(f"table_leg{i}", np.array([x, 0.0, z]), np.array([x + 0.06, 0.72, z + 0.06]), wood))
    z_back = hz - 0.25
    boxes += [
        Box("sofa_seat", np.array([-3.0, 0.0, z_back - 0.9]), np.array([-1.0, 0.45, z_back]), fabric),
        Box("sofa_back", np.array([-3.0, 0.0, z_back]), np.array([-1.0, 0.9, z_back + 0.2]), fabric),
        Box("sofa_arm_l", np.array([-3.2, 0.0, z_back - 0.9]), np.array([-3.0, 0.65, z_back + 0.2]), fabric),
        Box("sofa_arm_r", np.array([-1.0, 0.0, z_back - 0.9]), np.array([-0.8, 0.65, z_back + 0.2]), fabric),
        Box("shelf", np.array([hx - 0.4, 0.0, -1.0]), np.array([hx - 0.05, 1.9, 0.2]), shelf),
    ]
    return boxes


def _shadowed(points: np.ndarray, lamp: np.ndarray, boxes: list[Box]) -> np.ndarray:
    """(n,) bool: the open segment point -> lamp hits one of ``boxes`` (slab test)."""
    d = lamp - points
    hit = np.zeros(points.shape[0], bool)
    par = d == 0  # segment parallel to a slab: inside it (closed) for all t, or never
    safe = np.where(par, 1.0, d)
    for b in boxes:
        t1, t2 = (b.lo - points) / safe, (b.hi - points) / safe
        in_slab = (points >= b.lo) & (points <= b.hi)
        near = np.where(par, np.where(in_slab, -np.inf, np.inf), np.minimum(t1, t2))
        far = np.where(par, np.where(in_slab, np.inf, -np.inf), np.maximum(t1, t2))
        tmin, tmax = near.max(axis=1), far.min(axis=1)
        hit |= (tmax >= np.maximum(tmin, 1e-6)) & (tmin < 1.0 - 1e-6)
    return hit


# ----------------------------------------------------------------------------- the room
def make_room(size=(8.0, 3.0, 8.0), density: float = 800.0, seed: int = 0,
              lamp_positions=((-2.0, 2.4, -2.0), (2.5, 2.2, 1.5)),
              lamp_colors=((1.0, 0.82, 0.6), (0.75, 0.85, 1.0)), lamp_intensities=(5.0, 4.0),
              sh_degree: int = 1, ceiling: bool = True, ambient: float = 0.2, thickness_ratio: float = 0.1,
              emitter_count: int = 48, emitter_radius: float = 0.06, emitter_gain: float = 6.0,
              shadows: bool = True, boxes: list[Box] | None = None, detail: list[DetailRegion] | tuple = (),
              label: str = "room") -> RoomScene:
    """Generate the room (see module docstring). ``density`` is Gaussians per square metre
    of surface (default 800: ~190k Gaussians for the 8 x 3 x 8 m room with ceiling);
    ``detail``: :class:`DetailRegion` boxes with a higher density (none: the room is uniform).
    Deterministic for ``seed``. Lamps must lie inside the room and outside the furniture."""
    size = np.asarray(size, np.float64)
    if size.shape != (3,) or np.any(size <= 0):
        raise ValueError(f"size must be three positive lengths in metres, got {size.tolist()}")
    if not density > 0:
        raise ValueError(f"density must be > 0 Gaussians per m^2, got {density}")
    detail = tuple(detail)
    for r in detail:
        if not (r.density > 0 and np.all(np.asarray(r.hi, np.float64) >= np.asarray(r.lo, np.float64))):
            raise ValueError(f"detail region {r}: density must be > 0 and hi >= lo")
    rng = np.random.default_rng(seed)
    sx, sy, sz = size
    hx, hz = sx / 2, sz / 2
    spacing = 1.0 / np.sqrt(density)
    boxes = default_boxes(size) if boxes is None else boxes
    lamp_positions = np.asarray(lamp_positions, np.float64).reshape(-1, 3)
    lamp_colors = np.asarray(lamp_colors, np.float64).reshape(-1, 3)
    lamp_intensities = np.asarray(lamp_intensities, np.float64).reshape(-1)
    if not len(lamp_colors) == len(lamp_intensities) == len(lamp_positions):
        raise ValueError(f"{len(lamp_positions)} lamp positions but {len(lamp_colors)} lamp colours and "
                         f"{len(lamp_intensities)} intensities")
    lo_room, hi_room = np.array([-hx, 0.0, -hz]), np.array([hx, sy, hz])
    for i, p in enumerate(lamp_positions):
        if np.any(p <= lo_room) or np.any(p >= hi_room):
            raise ValueError(f"lamp {i} at {p.tolist()} is not inside the room {lo_room.tolist()}..{hi_room.tolist()}")
        if any(np.all((p > b.lo) & (p < b.hi)) for b in boxes):
            raise ValueError(f"lamp {i} at {p.tolist()} is inside a furniture box")

    # (origin, edge_u, edge_v, normal, part, albedo) for every rectangle.
    rects = [((-hx, 0, -hz), (sx, 0, 0), (0, 0, sz), (0, 1, 0), PART_FLOOR, np.array([0.55, 0.40, 0.26]))]
    wall = np.array([0.80, 0.78, 0.72])
    rects += [
        ((-hx, 0, -hz), (sx, 0, 0), (0, sy, 0), (0, 0, 1), PART_WALL, wall),
        ((-hx, 0, hz), (sx, 0, 0), (0, sy, 0), (0, 0, -1), PART_WALL, wall),
        ((-hx, 0, -hz), (0, 0, sz), (0, sy, 0), (1, 0, 0), PART_WALL, wall * np.array([0.95, 1.0, 1.05])),
        ((hx, 0, -hz), (0, 0, sz), (0, sy, 0), (-1, 0, 0), PART_WALL, wall * np.array([1.05, 1.0, 0.92])),
    ]
    if ceiling:
        rects.append(((-hx, sy, -hz), (sx, 0, 0), (0, 0, sz), (0, -1, 0), PART_CEILING, np.array([0.9, 0.9, 0.9])))
    for b in boxes:
        for o, eu, ev, nrm in _box_faces(b.lo, b.hi, with_bottom=b.lo[1] > 1e-6):
            rects.append((o, eu, ev, nrm, PART_FURNITURE, b.albedo))

    pts_l, rot_l, alb_l, part_l, nrm_l, sp_l = [], [], [], [], [], []
    pieces = []  # (rectangle, piece origin, piece edges, spacing): the pieces tile each rectangle
    for rect in rects:
        o, eu, ev = rect[:3]
        pieces += [(rect, po, pu, pv, sp) for po, pu, pv, sp in _split_rectangle(o, eu, ev, spacing, detail)]
    for (o, _eu, _ev, nrm, part, albedo), po, pu, pv, sp in pieces:
        pts, rot, uv = _rectangle(po, pu, pv, nrm, sp, rng)
        n = len(pts)
        # uv from the whole rectangle's origin (the plank pattern is continuous across pieces)
        off = np.asarray(po, np.float64) - np.asarray(o, np.float64)
        uv = uv + np.array([off @ pu / np.linalg.norm(pu), off @ pv / np.linalg.norm(pv)])
        alb = np.tile(albedo, (n, 1))
        if part == PART_FLOOR:  # planks 0.2 m wide along x, each a slightly different wood tone
            plank = np.floor(uv[:, 1] / 0.2).astype(np.int64)
            tone = 1.0 + 0.12 * np.sin(plank * 12.9898 + 78.233 * seed) * np.cos(plank * 4.1414)
            alb = alb * tone[:, None]
        alb = alb * (1.0 + 0.05 * rng.standard_normal((n, 1))) + 0.015 * rng.standard_normal((n, 3))
        pts_l.append(pts)
        rot_l.append(np.broadcast_to(rot, (n, 3, 3)))
        alb_l.append(np.clip(alb, 0.02, 0.98))
        part_l.append(np.full(n, part, np.int8))
        nrm_l.append(np.broadcast_to(np.asarray(nrm, np.float64), (n, 3)))
        sp_l.append(np.full(n, sp))
    pts = np.concatenate(pts_l)
    rot = np.concatenate(rot_l)
    alb = np.concatenate(alb_l)
    part = np.concatenate(part_l)
    nrm = np.concatenate(nrm_l)

    # Baked diffuse lighting.
    irr = np.full((len(pts), 3), ambient)
    for lp, lc, li in zip(lamp_positions, lamp_colors, lamp_intensities, strict=True):
        d = lp - pts
        r2 = np.einsum("ni,ni->n", d, d)
        ndl = np.maximum(np.einsum("ni,ni->n", nrm, d) / np.sqrt(r2), 0.0)
        vis = ~_shadowed(pts + 1e-4 * nrm, lp, boxes) if shadows else np.ones(len(pts), bool)
        irr += (li * ndl * vis / r2)[:, None] * lc
    color = np.clip(alb * irr, 0.0, 1.0)
    sigma = 0.6 * np.concatenate(sp_l)
    scales = np.stack([sigma, sigma, thickness_ratio * sigma], axis=1)
    opac = np.full(len(pts), 0.97)

    # Emitters: tiny bright Gaussians in a ball around each lamp.
    e_pos, e_col = [], []
    for lp, lc in zip(lamp_positions, lamp_colors, strict=True):
        dirs = rng.standard_normal((emitter_count, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        rad = emitter_radius * rng.uniform(0, 1, emitter_count) ** (1 / 3)
        e_pos.append(lp + dirs * rad[:, None])
        e_col.append(np.tile(lc * emitter_gain, (emitter_count, 1)) * rng.uniform(0.9, 1.1, (emitter_count, 1)))
    ne = emitter_count * len(lamp_positions)
    e_pos = np.concatenate(e_pos) if ne else np.zeros((0, 3))
    e_col = np.concatenate(e_col) if ne else np.zeros((0, 3))
    e_sigma = np.full((ne, 3), emitter_radius / 3)

    all_pos = np.concatenate([pts, e_pos])
    all_rot = np.concatenate([matrix_to_quaternion(rot), np.tile([1.0, 0.0, 0.0, 0.0], (ne, 1))])
    all_scale = np.concatenate([scales, e_sigma])
    all_opac = np.concatenate([opac, np.full(ne, 0.9)])
    all_col = np.concatenate([color, e_col])
    all_part = np.concatenate([part, np.full(ne, PART_LAMP, np.int8)])
    sh = np.zeros((len(all_pos), sh3dgs.num_coeffs(sh_degree), 3), np.float32)
    sh[:, 0] = (all_col - 0.5) / sh3dgs.C0
    g = GaussianSet(all_pos, all_rot, all_scale, all_opac, sh, label=label)
    lamps = [Lamp(p.copy(), c.copy(), float(i)) for p, c, i in zip(lamp_positions, lamp_colors, lamp_intensities,
                                                                     strict=True)]
    counts = {name: int(np.sum(all_part == k)) for k, name in PART_NAMES.items()}
    all_alb = np.concatenate([alb, np.zeros((ne, 3))]).astype(np.float32)
    return RoomScene(g, all_part, all_alb, lamps, list(boxes), size, float(ambient), counts)
