"""The generated room: part counts, geometry, baked lighting, emitters, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from usd_gs import sh3dgs
from usd_gs.colorspace import LUMA
from usd_gs.demo.room import (
    PART_CEILING,
    PART_FLOOR,
    PART_FURNITURE,
    PART_LAMP,
    PART_WALL,
    DetailRegion,
    _shadowed,
    _split_rectangle,
    default_boxes,
    make_room,
)

SPACING = 0.125  # density 64 per m^2: exact binary fractions, so the grid counts are exact


@pytest.fixture(scope="module")
def room():
    return make_room(density=64.0, seed=0)


def _colors(scene):
    return 0.5 + sh3dgs.C0 * scene.gaussians.sh[:, 0].astype(np.float64)


def test_counts_per_part(room):
    # Grid counts: ceil(length / spacing) per edge of every rectangle.
    assert room.counts["floor"] == 64 * 64
    assert room.counts["ceiling"] == 64 * 64
    assert room.counts["wall"] == 4 * 64 * 24
    expect_furn = 0
    for b in default_boxes((8, 3, 8)):
        dx, dy, dz = (max(1, int(np.ceil(length / SPACING))) for length in b.hi - b.lo)
        expect_furn += dx * dz + 2 * dx * dy + 2 * dz * dy + (dx * dz if b.lo[1] > 0 else 0)
    assert room.counts["furniture"] == expect_furn
    assert room.counts["lamp"] == 2 * 48
    assert room.gaussians.count == sum(room.counts.values()) == room.part.size
    assert room.gaussians.sh_degree == 1
    assert np.all(room.gaussians.sh[:, 1:] == 0)
    assert room.gaussians.problems() == []


def test_default_size_is_moderate():
    scene = make_room()
    assert 150_000 <= scene.gaussians.count <= 300_000  # measured 199,612


def test_everything_inside_the_room(room):
    p = room.gaussians.positions
    assert np.all(p >= np.array([-4, 0, -4]) - 1e-6)
    assert np.all(p <= np.array([4, 3, 4]) + 1e-6)
    # Floor at y = 0, ceiling at y = 3, walls on the box faces.
    assert np.all(p[room.part == PART_FLOOR, 1] == 0)
    assert np.all(p[room.part == PART_CEILING, 1] == 3)
    w = p[room.part == PART_WALL]
    on_face = (np.abs(np.abs(w[:, 0]) - 4) < 1e-6) | (np.abs(np.abs(w[:, 2]) - 4) < 1e-6)
    assert np.all(on_face)
    # Furniture Gaussians lie on the surface of one of the boxes.
    f = p[room.part == PART_FURNITURE].astype(np.float64)
    on_box = np.zeros(len(f), bool)
    for b in default_boxes((8, 3, 8)):
        inside = np.all((f >= b.lo - 1e-5) & (f <= b.hi + 1e-5), axis=1)
        on_surf = np.any((np.abs(f - b.lo) < 1e-5) | (np.abs(f - b.hi) < 1e-5), axis=1)
        on_box |= inside & on_surf
    assert np.all(on_box)


def test_surface_orientation(room):
    g = room.gaussians
    r = g.rotation_matrices()
    axis = np.argmin(g.scales, axis=1)
    normal = r[np.arange(g.count), :, axis]
    floor = room.part == PART_FLOOR
    np.testing.assert_allclose(normal[floor], np.tile([0.0, 1.0, 0.0], (floor.sum(), 1)), atol=1e-6)
    ceil = room.part == PART_CEILING
    np.testing.assert_allclose(normal[ceil], np.tile([0.0, -1.0, 0.0], (ceil.sum(), 1)), atol=1e-6)
    wall = room.part == PART_WALL
    assert np.all(np.abs(normal[wall, 1]) < 1e-6)
    # Wall normals point into the room (towards the centre line).
    centre = np.array([0.0, 1.5, 0.0])
    assert np.all(np.sum(normal[wall] * (centre - g.positions[wall]), axis=1) > 0)
    # Flat: sigma in-plane ~ spacing, normal sigma a tenth of it.
    np.testing.assert_allclose(g.scales[floor, 0], 0.6 * SPACING, rtol=1e-6)
    np.testing.assert_allclose(g.scales[floor, 2], 0.06 * SPACING, rtol=1e-6)


def test_lamps_are_the_brightest_compact_clusters(room):
    lum = _colors(room) @ LUMA
    lamp = room.part == PART_LAMP
    assert lum[lamp].min() > 3.0 and lum[lamp].max() < 8.0
    assert lum[~lamp].max() <= 1.0 + 1e-6
    assert lum[lamp].min() > lum[~lamp].max()
    p = room.gaussians.positions[lamp].astype(np.float64)
    for i, l in enumerate(room.lamps):
        cluster = p[i * 48:(i + 1) * 48]
        assert np.linalg.norm(cluster - l.position, axis=1).max() <= 0.06 + 1e-6
    np.testing.assert_allclose(room.lamps[0].position, [-2, 2.4, -2])
    np.testing.assert_allclose(room.lamps[1].position, [2.5, 2.2, 1.5])


def test_baked_lighting_matches_point_light_formula():
    scene = make_room(density=16.0, seed=1, shadows=False)
    g = scene.gaussians
    r = g.rotation_matrices()
    normal = r[:, :, 2]
    surf = scene.part != PART_LAMP
    p = g.positions.astype(np.float64)[surf]
    n = normal[surf]
    irr = np.full((len(p), 3), scene.ambient)
    for lamp in scene.lamps:
        d = lamp.position - p
        dist = np.linalg.norm(d, axis=1)
        irr += (lamp.intensity * np.maximum(np.sum(n * d, axis=1) / dist, 0) / dist**2)[:, None] * lamp.color
    expect = np.clip(scene.albedo[surf] * irr, 0, 1)
    np.testing.assert_allclose(_colors(scene)[surf], expect, atol=2e-5)
    # The floor right under lamp 0 is brighter than the far corner.
    lum = _colors(scene)[surf] @ LUMA
    floor = scene.part[surf] == PART_FLOOR
    d_lamp = np.linalg.norm(p[:, [0, 2]] - [-2, -2], axis=1)
    d_corner = np.linalg.norm(p[:, [0, 2]] - [3.9, -3.9], axis=1)
    assert lum[floor & (d_lamp < 0.3)].mean() > 2 * lum[floor & (d_corner < 0.3)].mean()


def test_furniture_casts_shadows():
    boxes = default_boxes((8, 3, 8))
    top = boxes[0]  # table top, x 0.2..1.8, y 0.72..0.78, z -1..0
    lamp = np.array([1.0, 2.0, -0.5])
    pts = np.array([[1.0, 0.0, -0.5], [3.0, 0.0, 3.0], [1.0, 1.0, -0.5], [1.0, 0.78 + 1e-4, -0.5]])
    np.testing.assert_array_equal(_shadowed(pts, lamp, [top]), [True, False, False, False])
    # Segment parallel to the x slab planes, starting on one of them: still a clean answer.
    np.testing.assert_array_equal(_shadowed(np.array([[0.2, 0.0, -0.5]]), np.array([0.2, 2.0, -0.5]), [top]),
                                  [True])
    # In the default room the table top casts lamp 0's shadow around the central projection
    # of its centre (1, 0.75, -0.5) from lamp 0 (-2, 2.4, -2) onto the floor: (2.364, 0, 0.182).
    lit = make_room(density=64.0, seed=0, shadows=False)
    shad = make_room(density=64.0, seed=0, shadows=True)
    p = shad.gaussians.positions.astype(np.float64)
    floor = shad.part == PART_FLOOR
    lamp0 = shad.lamps[0]
    d = lamp0.position - p
    dist = np.linalg.norm(d, axis=1)
    term0 = shad.albedo * ((lamp0.intensity * d[:, 1] / dist**3)[:, None] * lamp0.color)  # N = +Y
    c_lit, c_shad = _colors(lit), _colors(shad)
    spot = floor & (np.linalg.norm(p[:, [0, 2]] - [2.364, 0.182], axis=1) < 0.3)
    assert spot.sum() > 15
    np.testing.assert_allclose(c_lit[spot] - c_shad[spot], term0[spot], atol=2e-5)
    # Shadows only ever remove light; far from all furniture nothing changes.
    assert np.all(c_shad[floor] <= c_lit[floor] + 1e-6)
    free = floor & (p[:, 0] < -3.5) & (p[:, 2] < -3.5)
    np.testing.assert_array_equal(c_shad[free], c_lit[free])


def test_deterministic_for_a_seed(room):
    again = make_room(density=64.0, seed=0)
    for name in ("positions", "orientations", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(again.gaussians, name), getattr(room.gaussians, name))
    np.testing.assert_array_equal(again.part, room.part)
    other = make_room(density=64.0, seed=1)
    assert not np.array_equal(other.gaussians.positions, room.gaussians.positions)


def test_bad_input():
    with pytest.raises(ValueError, match="lamp 0 .* not inside the room"):
        make_room(density=4.0, lamp_positions=((0.0, 3.5, 0.0),), lamp_colors=((1, 1, 1),), lamp_intensities=(1,))
    with pytest.raises(ValueError, match="inside a furniture box"):
        make_room(density=4.0, lamp_positions=((-2.0, 0.2, 3.0), (0, 1, 0)))
    with pytest.raises(ValueError, match="1 lamp positions but 2 lamp colours"):
        make_room(density=4.0, lamp_positions=((0.0, 2.0, 0.0),))
    with pytest.raises(ValueError, match="density"):
        make_room(density=0.0)


def test_split_rectangle_tiles_it():
    # Floor 8 x 8 m from (-4, 0, -4); box x in [-1.1, 0.3] (snapped out to whole 0.125 m cells:
    # [-1.125, 0.375]), z beyond the far edge (clipped at 4); a second box misses the plane.
    regions = [DetailRegion((-1.1, -0.1, 1.0), (0.3, 0.1, 9.0), 1600.0), DetailRegion((0, 1, 0), (1, 2, 1), 1e4)]
    pieces = _split_rectangle((-4, 0, -4), (8, 0, 0), (0, 0, 8), SPACING, regions)
    assert sum(np.linalg.norm(u) * np.linalg.norm(v) for _, u, v, _ in pieces) == pytest.approx(64.0)
    dense = [(o, u, v) for o, u, v, sp in pieces if sp == pytest.approx(0.025)]
    assert len(dense) == 1 and len(pieces) == 4  # the strip beyond z = 4 is empty
    o, u, v = dense[0]
    np.testing.assert_allclose(o, [-1.125, 0.0, 1.0])
    np.testing.assert_allclose(o + u + v, [0.375, 0.0, 4.0])
    # Pieces do not overlap: sampled points fall in exactly one piece.
    q = np.random.default_rng(0).uniform([-4, 0, -4], [4, 0, 4], (5000, 3))
    inside = [np.all((q >= np.minimum(o, o + u + v) - 1e-12) & (q <= np.maximum(o, o + u + v) + 1e-12), axis=1)
              for o, u, v, _ in pieces]
    assert np.all(np.sum(inside, axis=0) == 1)


def test_detail_region_density_and_no_gaps(room):
    box = DetailRegion((-2.0, -0.1, -1.0), (0.0, 0.1, 1.0), 1024.0)  # 32^2 per m^2, spacing 1/32 m
    dense = make_room(density=64.0, seed=0, detail=[box])
    g = dense.gaussians
    p = g.positions.astype(np.float64)
    floor = dense.part == PART_FLOOR
    inbox = floor & (p[:, 0] > -2) & (p[:, 0] < 0) & (p[:, 2] > -1) & (p[:, 2] < 1)
    assert inbox.sum() == 64 * 64  # 2 m x 2 m at 32 per metre and edge
    np.testing.assert_allclose(g.scales[inbox, 0], 0.6 / 32, rtol=1e-6)
    np.testing.assert_allclose(g.scales[floor & ~inbox, 0], 0.6 * SPACING, rtol=1e-6)
    # Only the floor changed: the other parts (walls, furniture) are outside the box.
    assert dense.counts["floor"] == room.counts["floor"] - 16 * 16 + 64 * 64
    assert {k: v for k, v in dense.counts.items() if k != "floor"} == \
        {k: v for k, v in room.counts.items() if k != "floor"}
    # No gap where the pieces meet: the floor's alpha coverage along the box's border is about
    # as high as anywhere on the uniform floor (measured min 0.64 vs 0.72; a missing row of
    # cells would leave ~0.2).
    rng = np.random.default_rng(1)
    k = 1500
    band = np.concatenate([
        np.stack([rng.uniform(-2.2, 0.2, k), rng.choice([-1.0, 1.0], k) + rng.uniform(-0.1, 0.1, k)], 1),
        np.stack([rng.choice([-2.0, 0.0], k) + rng.uniform(-0.1, 0.1, k), rng.uniform(-1.2, 1.2, k)], 1)])
    assert _floor_coverage(dense, band).min() > 0.8 * _floor_coverage(room, rng.uniform(-3.9, 3.9, (2 * k, 2))).min()
    with pytest.raises(ValueError, match="detail region"):
        make_room(density=64.0, detail=[DetailRegion((0, 0, 0), (1, 1, 1), 0.0)])


def _floor_coverage(scene, xz):
    """Alpha coverage ``1 - prod(1 - o g)`` of the floor Gaussians (in-plane, isotropic) at (M, 2) x/z points."""
    from scipy.spatial import cKDTree

    m = scene.part == PART_FLOOR
    c = scene.gaussians.positions[m][:, [0, 2]].astype(np.float64)
    s = scene.gaussians.scales[m, 0].astype(np.float64)
    o = scene.gaussians.opacities[m].astype(np.float64)
    out = np.empty(len(xz))
    for i, nb in enumerate(cKDTree(c).query_ball_point(xz, 3 * s.max())):
        nb = np.asarray(nb, np.int64)
        out[i] = 1.0 - np.prod(1.0 - o[nb] * np.exp(-0.5 * np.sum((c[nb] - xz[i]) ** 2, axis=1) / s[nb] ** 2))
    return out
