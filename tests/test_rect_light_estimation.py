"""Closed captures: bright planar emitters (windows, panels) become RectLights (issue 18).

A generated closed room (``usd_gs.demo.room.make_room``) with one compact lamp and a bright
panel on the x = +4 wall: the estimate has one RectLight on the panel (centre, normal, sides)
plus the lamp as a point light; a mirrored copy of the panel below the floor is rejected with
its reason; the room without a panel gets no RectLight and its two point lights as before.
"""

import math

import numpy as np
import pytest

from numba_kernels.light_estimation import linked_clusters
from numba_kernels.reference import light_estimation as reference
from usd_gs import sh3dgs
from usd_gs.demo.room import make_room
from usd_gs.gaussians import GaussianSet
from usd_gs.pipeline.capture_lights import closed_capture_lights, lights_evidence
from usd_gs.relight import sun_estimation as se
from usd_gs.relight.light_estimation import estimate_rect_lights

CENTRE = np.array([-1.6, 0.9, -0.4])  # the avatars' region
LAMP = (-2.0, 2.4, -2.0)
PANEL_CENTRE = np.array([0.5, 1.6, -3.97])  # 3 cm in front of the z = -4 wall
PANEL_W, PANEL_H = 1.2, 0.8  # along x, along y
PANEL_NORMAL = np.array([0.0, 0.0, 1.0])  # into the room


def _panel(centre, width=PANEL_W, height=PANEL_H, luminance=3.0, spacing=0.05, seed=0):
    """Flat Gaussians on a jittered grid over a width x height rectangle in the z = const plane."""
    rng = np.random.default_rng(seed)
    nu, nv = int(round(width / spacing)), int(round(height / spacing))
    gu, gv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    u = (gu.ravel() + 0.5 + rng.uniform(-0.2, 0.2, gu.size)) * spacing - width / 2
    v = (gv.ravel() + 0.5 + rng.uniform(-0.2, 0.2, gv.size)) * spacing - height / 2
    n = u.size
    pos = np.asarray(centre) + np.stack([u, v, rng.normal(0, 0.002, n)], axis=1)
    sh = np.zeros((n, 4, 3), np.float32)
    rgb = np.array([0.95, 1.0, 1.05]) * luminance * rng.uniform(0.97, 1.03, (n, 1))
    sh[:, 0] = (rgb - 0.5) / sh3dgs.C0
    scales = np.tile([0.6 * spacing, 0.6 * spacing, 0.003], (n, 1))
    return GaussianSet(pos, np.tile([1.0, 0, 0, 0], (n, 1)), scales, np.full(n, 0.95), sh)


@pytest.fixture(scope="module")
def one_lamp_room():
    return make_room(density=60.0, seed=0, lamp_positions=(LAMP,), lamp_colors=((1.0, 0.82, 0.6),),
                     lamp_intensities=(5.0,))


def _lights(scene, k):
    cands = se.emitter_candidates(scene, CENTRE, max(k + 4, 6))
    return closed_capture_lights(scene, CENTRE, cands, k, "Y", 1.0, floor=0.0)


def test_linked_clusters_match_reference():
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(0, 1, (300, 3)), rng.uniform(3, 3.5, (80, 3))])
    for r in (0.05, 0.12, 0.3):
        got = linked_clusters(pts, r)
        np.testing.assert_array_equal(got, reference.linked_clusters(pts, r))
    assert np.unique(linked_clusters(pts, 0.3)).size == 2  # the two blobs, each one cluster


def test_panel_becomes_a_rect_light_and_the_lamp_a_point_light(one_lamp_room):
    scene = GaussianSet.concatenate([one_lamp_room.gaussians, _panel(PANEL_CENTRE)])
    cap = _lights(scene, 2)
    rects = [lt for lt in cap.lights if lt.form == "rect"]
    points = [lt for lt in cap.lights if lt.form != "rect"]
    assert len(rects) == 1 and len(points) == 2
    r = rects[0]
    assert r.kind == "point" and r.name == "Rect_0"  # shadows from its centre, area samples for the relighting
    assert np.linalg.norm(r.position - PANEL_CENTRE) < 0.03
    normal = -r.axes[:, 2]  # UsdLux area lights emit along local -Z
    assert math.degrees(math.acos(min(1.0, float(normal @ PANEL_NORMAL)))) < 3.0
    assert abs(np.linalg.det(r.axes) - 1.0) < 1e-9
    assert abs(r.width / PANEL_W - 1.0) < 0.15 and abs(r.height / PANEL_H - 1.0) < 0.15
    assert abs(abs(r.axes[0, 0]) - 1.0) < 0.02  # width (the long side) along x
    # radiance = colour * intensity: the panel's colour (luminance 3 x opacity-free SH colour)
    assert abs(r.intensity / 3.0 - 1.0) < 0.05 and abs(se.LUMA @ r.color - 1.0) < 1e-9
    assert points[0].name == "Light_0" and np.linalg.norm(points[0].position - np.array(LAMP)) < 0.1
    # the point lights are those of the room without the panel (its second: what paper 3.1 finds next)
    before = _lights(one_lamp_room.gaussians, 2).lights
    for a, b in zip(points, before, strict=True):
        np.testing.assert_allclose(a.position, b.position, atol=1e-5)  # float32 storage of the concatenation
        assert a.intensity == pytest.approx(b.intensity, rel=1e-5)
    assert not any(cap.rects["Rect_0"].contains(lt.position, 0.1, 0.1)[0] for lt in points)
    # the paper-3.1 candidates on the panel are reported as part of it, not made point lights
    assert any("part of the planar emitter Rect_0" in c.rejected for c in cap.rejected)
    assert any(line.startswith("rect light Rect_0: ") for line in cap.lines)
    ev = lights_evidence(cap)["Rect_0"]
    assert ev["count"] >= 300 and ev["flatness"] < 0.1 and ev["visibility"] > 0.9
    assert abs(ev["area_m2"] / (PANEL_W * PANEL_H) - 1.0) < 0.2


def test_mirror_image_of_the_panel_below_the_floor_is_rejected(one_lamp_room):
    mirror = PANEL_CENTRE * np.array([1.0, -1.0, 1.0])
    scene = GaussianSet.concatenate([one_lamp_room.gaussians, _panel(PANEL_CENTRE), _panel(mirror, seed=1)])
    found = estimate_rect_lights(scene, CENTRE)
    assert sorted(round(float(f.position[1]), 1) for f in found) == [-1.6, 1.6]  # both are planar and bright
    cap = _lights(scene, 1)
    rects = [lt for lt in cap.lights if lt.form == "rect"]
    assert len(rects) == 1 and np.linalg.norm(rects[0].position - PANEL_CENTRE) < 0.03
    below = [c for c in cap.rejected if np.linalg.norm(c.position - mirror) < 0.05]
    assert below and "below the floor" in below[0].rejected
    assert any(line.startswith("rejected planar emitter at (0.50, -1.60, -3.97)") and "below the floor" in line
               for line in cap.lines)
    assert "below the floor" in lights_evidence(cap)[""]["rejected"]


def test_panel_behind_a_wall_is_rejected_as_hidden(one_lamp_room):
    behind = PANEL_CENTRE + np.array([0.0, 0.0, -0.3])  # 27 cm behind the z = -4 wall, facing the room
    scene = GaussianSet.concatenate([one_lamp_room.gaussians, _panel(behind)])
    assert len(estimate_rect_lights(scene, CENTRE)) == 1
    cap = _lights(scene, 1)
    assert not cap.rects
    hidden = [c for c in cap.rejected if np.linalg.norm(c.position - behind) < 0.05]
    assert hidden and "hidden from the avatars' region" in hidden[0].rejected and hidden[0].visibility < 0.2


def test_demo_room_without_a_panel_keeps_its_two_point_lights():
    room = make_room(density=60.0, seed=0)
    assert estimate_rect_lights(room.gaussians, CENTRE) == []  # its lamp-lit, saturated ceiling is no window
    cap = _lights(room.gaussians, 2)
    assert [lt.form for lt in cap.lights] == ["point", "point"]
    got = sorted(tuple(np.round(lt.position, 1)) for lt in cap.lights)
    assert got == sorted(tuple(np.round(lp.position, 1)) for lp in room.lamps)
    assert not cap.rects and not any("planar" in c.rejected for c in cap.rejected)


def _tiny_stage(path, scene):
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
    from usd_gs.usd.schema import apply_role

    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    apply_role(write_gaussian_prim(stage, "/World/Scene", scene, keep_raw=False), "scene")
    rng = np.random.default_rng(0)
    n = 400
    pos = CENTRE + rng.uniform(-1, 1, (n, 3)) * [0.2, 0.8, 0.15]
    av = GaussianSet(pos, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), 0.03), np.full(n, 0.8),
                     np.zeros((n, 1, 3), np.float32))
    apply_role(write_gaussian_prim(stage, "/World/Avatar", av, keep_raw=False), "avatar")
    save_stage_atomic(stage, path)


def test_usdgs_lights_writes_the_rect_light_and_reads_it_back(one_lamp_room, tmp_path, capsys):
    from pxr import Usd, UsdLux

    from usd_gs.cli import main
    from usd_gs.usd.lux import read_stage_lights

    src, out = tmp_path / "room.usdc", tmp_path / "lights.usda"
    _tiny_stage(src, GaussianSet.concatenate([one_lamp_room.gaussians, _panel(PANEL_CENTRE)]))
    assert main(["lights", str(src), "-o", str(out), "--lights", "indoor"]) == 0
    printed = capsys.readouterr().out
    assert "rect light Rect_0: 1.20 x 0.80 m at (0.50, 1.60, -3.97)" in printed
    assert "part of the planar emitter Rect_0" in printed
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath("/UsdGs/Lights/Rect_0")
    assert prim.GetTypeName() == "RectLight"
    rl = UsdLux.RectLight(prim)
    assert rl.GetWidthAttr().Get() == pytest.approx(PANEL_W, rel=0.15)
    assert rl.GetHeightAttr().Get() == pytest.approx(PANEL_H, rel=0.15)
    assert rl.GetIntensityAttr().Get() == pytest.approx(3.0, rel=0.05)
    cd = prim.GetCustomData()["usdgs"]
    assert cd["estimated"] and cd["score"] > 0 and cd["count"] >= 300
    assert cd["flatness"] < 0.1 and cd["visibility"] > 0.9 and len(cd["normal"]) == 3
    # --lights stage reads the same light back: centre, emission normal (local -Z), sides
    lights, _ = read_stage_lights(stage, Usd.TimeCode(1))
    back = [lt for lt in lights if lt.form == "rect"]
    assert len(back) == 1 and back[0].kind == "point"
    assert np.linalg.norm(back[0].position - PANEL_CENTRE) < 0.03
    assert float(-back[0].axes[:, 2] @ PANEL_NORMAL) > math.cos(math.radians(3.0))
    assert back[0].width == pytest.approx(rl.GetWidthAttr().Get(), rel=1e-6)
    np.testing.assert_allclose(back[0].radiance(), np.asarray(cd["radiance"]), rtol=1e-5)
