"""Lights for captures: open/closed decision, the sun from baked shadows, overcast, implausible emitters."""

import numpy as np
import pytest

from numba_kernels.reference.sun_shadow import transmittance_directions_numpy
from numba_kernels.sun_shadow import transmittance_directions
from usd_gs import sh3dgs
from usd_gs.demo.room import make_room
from usd_gs.evaluation.sun_scene import make_sun_scene
from usd_gs.gaussians import GaussianSet
from usd_gs.relight import sun_estimation as se
from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders

CENTRE = np.array([1.2, 0.9, 0.9])  # an avatar's region beside the statue-sized box, on the sunlit side


@pytest.fixture(scope="module")
def sunny():
    return make_sun_scene(sun_elevation_deg=50.0, sun_azimuth_deg=35.0, ratio=3.0, ground_half=2.5, spacing=0.08,
                          sky_samples=32, seed=1)


@pytest.fixture(scope="module")
def overcast():
    return make_sun_scene(overcast=True, ground_half=2.5, spacing=0.08, sky_samples=32, seed=1)


@pytest.fixture(scope="module")
def room():
    return make_room(density=60.0, seed=0)


def test_kernel_matches_reference(sunny):
    g = sunny.gaussians
    cast = g.subset(np.flatnonzero(sunny.part == 1))
    ground = np.flatnonzero(sunny.part == 0)
    pos = g.positions[ground].astype(np.float64)
    near = ground[np.argsort(np.linalg.norm(pos[:, [0, 2]] - [-0.6, 0.6], axis=1))[:40]]  # in the box's shadow
    pts = np.concatenate([g.positions[near], g.positions[ground[:10]]]).astype(np.float64)
    occ, dep, cov6 = prepare_occluders(cast, DGSMConfig())
    dirs = -np.array([sunny.sun, [0.2, 0.9, -0.3], [-0.6, 0.45, 0.6]])
    got = transmittance_directions(dirs, occ, dep, cov6, pts, k_sigma=6.0, cell=0.05)
    want = transmittance_directions_numpy(dirs, occ, dep, pts)
    assert (want < 0.5).sum() > 10  # some points are in a shadow
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_sun_direction_and_ratio_from_the_baked_shadow(sunny):
    est = se.estimate_sun(sunny.gaussians, CENTRE, "Y", ground_hint=0.0)
    assert est is not None and est.confident, est.line()
    assert se.angle_deg(est.direction, sunny.sun) < 3.0
    assert est.ratio == pytest.approx(sunny.ratio, rel=0.15)
    # the darkening of a full shadow is the sun's share of the lit ground's light: E_sun cos / (E_sun cos + E_sky)
    rc = sunny.ratio * float(sunny.sun[1])
    assert est.direct_share == pytest.approx(rc / (1 + rc), abs=0.04)
    # in display terms (what the shadow factor multiplies): the median ground colour lit, and without the sun
    rho = np.median(sunny.albedo[sunny.part == 0], axis=0) * sunny.exposure / np.pi
    lit = se.srgb_to_display(rho * (np.pi + sunny.e_sun * sunny.sun[1])) @ se.LUMA
    shade = se.srgb_to_display(rho * np.pi) @ se.LUMA
    assert est.darkening == pytest.approx(1 - shade / lit, abs=0.03)


def test_overcast_gives_no_confident_sun(overcast):
    est = se.estimate_sun(overcast.gaussians, CENTRE, "Y", ground_hint=0.0)
    assert est is not None
    assert not est.confident and est.score < se.CaptureConfig().score_threshold


def test_a_capture_without_a_sun_skips_the_fine_search(overcast, sunny):
    """No coarse direction reaches ``fine_min_score``: one fine build instead of the grids, and what
    the main job takes of a sunless estimate (no sun, the ground's colour) is the full search's."""
    quick = se.estimate_sun(overcast.gaussians, CENTRE, "Y", ground_hint=0.0)
    full = se.estimate_sun(overcast.gaussians, CENTRE, "Y", ground_hint=0.0,
                           config=se.CaptureConfig(fine_min_score=0.0))
    # the coarse directions and one fine build, against the grids' hundreds; no dense ratio pass
    assert full.timings["builds"] - quick.timings["builds"] > 50 and "ratio" not in quick.timings
    assert not quick.confident and not full.confident
    assert quick.score < se.CaptureConfig().fine_min_score and full.score < se.CaptureConfig().score_threshold
    np.testing.assert_array_equal(quick.sky.ground, full.sky.ground)
    # a sunny capture's coarse best is far above the bar: the full search runs (its direction is checked above)
    assert "ratio" in se.estimate_sun(sunny.gaussians, CENTRE, "Y", ground_hint=0.0).timings


def test_open_and_closed_decisions(sunny, room):
    d_open = se.classify_capture(sunny.gaussians, CENTRE, "Y")
    assert d_open.is_open and d_open.empty_share > 0.9 and not d_open.compact
    d_room = se.classify_capture(room.gaussians, np.array([-1.6, 0.9, -0.4]), "Y")
    assert not d_room.is_open and d_room.empty_share < 0.05 and len(d_room.compact) == 2


def test_empty_sky_share_near_first(sunny, room, monkeypatch):
    """The open/closed render draws the near Gaussians first: a closed room with a block of
    Gaussians 40 m away gets share 0 from the near render alone (the far block is not drawn);
    an open scene with the same far block and a room whose ceiling is cut open draw everything,
    and every share equals the plain render's."""
    far_block = GaussianSet.concatenate([room.gaussians, room.gaussians])
    far_block.positions[:] += np.float32([40.0, 0.0, 0.0])
    drawn = []
    render = se.render_cube_faces

    def spy(g, centre, size, mask=None, order=None, **kw):
        drawn.append(g.count if order is None and mask is None else int(np.count_nonzero(mask) if order is None
                                                                           else len(order)))
        return render(g, centre, size, mask=mask, order=order, **kw)

    monkeypatch.setattr(se, "render_cube_faces", spy)
    inside = np.array([-1.6, 0.9, -0.4])
    closed = GaussianSet.concatenate([room.gaussians, far_block])
    assert se.empty_sky_share(closed, inside, "Y", near_radius=15.0) == 0.0
    assert drawn == [room.gaussians.count]  # the room alone decided it
    assert se.empty_sky_share(closed, inside, "Y") == 0.0
    top = room.gaussians.positions[:, 1].max()
    cut = room.gaussians.subset(np.flatnonzero(room.gaussians.positions[:, 1] < top - 0.05))  # no ceiling
    for g, c in ((GaussianSet.concatenate([sunny.gaussians, far_block]), CENTRE),
                 (GaussianSet.concatenate([cut, far_block]), inside)):
        drawn.clear()
        got = se.empty_sky_share(g, c, "Y", near_radius=15.0)
        want = se.empty_sky_share(g, c, "Y")
        assert got == want > 0.05 and drawn[-2:] == [g.count, g.count]


def _cluster(centre, n=48, radius=0.06, gain=6.0, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.asarray(centre) + d * (radius * rng.uniform(0, 1, n) ** (1 / 3))[:, None]
    sh = np.zeros((n, 4, 3), np.float32)
    sh[:, 0] = (gain - 0.5) / sh3dgs.C0
    return GaussianSet(pos, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), radius / 3), np.full(n, 0.9), sh)


def test_mirror_image_and_hidden_patch_are_rejected(room):
    lamp = room.lamps[0].position
    mirror = lamp * np.array([1.0, -1.0, 1.0])  # the lamp's reflection under a glossy floor (y = 0)
    behind = np.array([4.4, 1.5, 0.0])  # a bright patch behind the x = +4 wall
    scene = GaussianSet.concatenate([room.gaussians, _cluster(mirror), _cluster(behind, seed=1)])
    cands = se.emitter_candidates(scene, np.array([-1.6, 0.9, -0.4]), 6)
    positions = np.array([c.position for c in cands])
    for p in (lamp, mirror, behind):
        assert np.min(np.linalg.norm(positions - p, axis=1)) < 0.1  # paper 3.1 finds all three
    pts = se.region_points(np.array([-1.6, 0.9, -0.4]), "Y", 0.5)
    se.plausible_emitters(scene, cands, pts, "Y", floor_height=0.0)
    by = {tuple(np.round(p, 1)): c for p in (lamp, mirror, behind)
          for c in cands if np.linalg.norm(c.position - p) < 0.1}
    assert by[tuple(np.round(lamp, 1))].rejected == ""
    assert "below the floor" in by[tuple(np.round(mirror, 1))].rejected
    assert "hidden" in by[tuple(np.round(behind, 1))].rejected
    assert by[tuple(np.round(behind, 1))].visibility < 0.2


def _tiny_stage(path, scene):
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
    from usd_gs.usd.schema import apply_role

    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    apply_role(write_gaussian_prim(stage, "/World/Scene", scene, keep_raw=False), "scene")
    rng = np.random.default_rng(0)
    n = 400
    pos = np.array([-1.6, 0.9, -0.4]) + rng.uniform(-1, 1, (n, 3)) * [0.2, 0.8, 0.15]
    sh = np.zeros((n, 1, 3), np.float32)
    av = GaussianSet(pos, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), 0.03), np.full(n, 0.8), sh)
    apply_role(write_gaussian_prim(stage, "/World/Avatar", av, keep_raw=False), "avatar")
    save_stage_atomic(stage, path)


def test_lights_outdoor_on_a_closed_room_is_refused(room, tmp_path, capsys):
    from usd_gs.cli import main

    src = tmp_path / "room.usdc"
    _tiny_stage(src, room.gaussians)
    out = tmp_path / "out.usdc"
    assert main(["process", str(src), "-o", str(out), "--lights", "outdoor", "-q"]) == 2
    err = capsys.readouterr().err
    assert "--lights outdoor" in err and "closed" in err and "sky above the horizon" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["room.usdc"]


def test_capture_lights_block_by_block_are_the_same(room, monkeypatch):
    """The shot's light estimate with the scene's bricks as ``PointBlocks`` (the pipeline's path): a
    closed room (its rows split into four prims) with two copies of it 40 m away (two more prims)
    and a bright patch behind a wall; the candidates, the open/closed decision, the floor and the
    closed capture's lights (with their rejections and visibilities) are those of the row-by-row
    tests, bit for bit, and the blocks were used (their spheres computed, the far prims never
    tested row by row)."""
    from usd_gs.pipeline.capture_lights import closed_capture_lights
    from usd_gs.point_blocks import PointBlocks, block_starts

    g = room.gaussians
    far = [GaussianSet.concatenate([g]) for _ in range(2)]
    far[0].positions[:] += np.float32([40.0, 0.0, 0.0])
    far[1].positions[:] += np.float32([0.0, 0.0, -40.0])
    behind = _cluster(np.array([4.4, 1.5, 0.0]), seed=1)
    cuts = np.linspace(0, g.count, 5).astype(int)
    prims = [g.subset(slice(a, b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True)] + far + [behind]
    scene = GaussianSet.concatenate(prims)
    ends = np.cumsum([p.count for p in prims])
    blocks = PointBlocks(block_starts(list(zip(np.r_[0, ends[:-1]], ends, strict=True))))
    centre, up = np.array([-1.6, 0.9, -0.4]), se.up_vector("Y")
    cfg = se.CaptureConfig()

    plain_cands = se.emitter_candidates(scene, centre, 6, values_checked=True)
    cands = se.emitter_candidates(scene, centre, 6, values_checked=True, blocks=blocks)
    assert repr(cands) == repr(plain_cands) and len(cands) == 6
    decision = se.classify_capture(scene, centre, "Y", config=cfg, candidates=cands, blocks=blocks)
    plain_decision = se.classify_capture(scene, centre, "Y", config=cfg, candidates=plain_cands)
    assert not decision.is_open and decision.empty_share == plain_decision.empty_share < 0.05
    args = (scene, up, centre, cfg.receiver_radius, 0.0, cfg.ground_search, cfg.flat_cos, cfg.ground_band / 3)
    floor = se.ground_height(*args, blocks=blocks)
    assert floor == se.ground_height(*args) and abs(floor) < 0.05  # the room's floor is y = 0

    tested = []  # rows tested one by one by the capsule kernels (where the estimate's modules call them)
    import usd_gs.point_blocks as point_blocks

    for module, name in ((se, "within_capsule"), (point_blocks, "within_capsule"),
                         (point_blocks, "within_capsule_scaled")):
        kernel = getattr(module, name)
        monkeypatch.setattr(module, name, lambda p, *a, _k=kernel, **kw: tested.append(len(p)) or _k(p, *a, **kw))
    lights = closed_capture_lights(scene, centre, cands, 2, "Y", floor=floor, decision=decision,
                                   values_checked=True, blocks=blocks)
    assert tested == [] and blocks._spheres is not None
    plain = closed_capture_lights(scene, centre, plain_cands, 2, "Y", floor=floor, decision=plain_decision,
                                  values_checked=True)
    assert tested  # (the row-by-row path took the kernels the blocks avoid)
    assert [(lt.name, lt.position.tolist(), lt.intensity) for lt in lights.lights] == \
        [(lt.name, lt.position.tolist(), lt.intensity) for lt in plain.lights]
    assert len(lights.lights) == 2 and lights.lines == plain.lines
    assert [(c.position.tolist(), c.rejected, c.visibility) for c in lights.rejected] == \
        [(c.position.tolist(), c.rejected, c.visibility) for c in plain.rejected]
    assert any("hidden" in c.rejected for c in lights.rejected)  # the patch behind the wall
