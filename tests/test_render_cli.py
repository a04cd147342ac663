"""`usdgs render` and usd_gs/render/preview.py: frames to PNG/EXR, --compare, cameras, drawn prims, user errors."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from pxr import Gf, Usd, UsdGeom

from usd_gs.cli import main
from usd_gs.cli.render import frame_path
from usd_gs.demo.stage import CAMERA_APERTURE_MM
from usd_gs.gaussians import GaussianSet
from usd_gs.render.camera import Camera
from usd_gs.render.preview import (
    drawn_gaussian_prims,
    framing_camera,
    read_stage_gaussians,
    render_stage_frame,
    resolve_camera,
)
from usd_gs.render.rasterize import render
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.gaussian_prim import new_stage, read_gaussian_prim, save_stage_atomic, write_gaussian_prim
from usd_gs.usd.stage import open_stage

W = 160
H = round(W * CAMERA_APERTURE_MM[1] / CAMERA_APERTURE_MM[0])  # 90: height from the 16:9 aperture


@pytest.fixture(scope="module")
def processed(quick_demo, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "demo.lit.usdc"
    assert main(["process", str(quick_demo), "-o", str(out), "--frames", "1-2", "-q"]) == 0
    return out


def _png(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def _u8(rgb: np.ndarray) -> np.ndarray:
    """What write_png stores for a float image: clip to [0, 1], scale by 255, round."""
    return np.round(np.clip(rgb.astype(np.float64), 0, 1) * 255).astype(np.uint8)


def _small_stage(path, up="Y", camera_paths=(), frames=(1.0,)):
    """A stage without sublayers: 300 random Gaussians (SH 1) under a scaled, rotated, translated Xform."""
    stage = new_stage(up_axis=up, default_prim="W")
    stage.SetStartTimeCode(frames[0])
    stage.SetEndTimeCode(frames[-1])
    xf = UsdGeom.Xform.Define(stage, "/W")
    xf.AddTranslateOp().Set(Gf.Vec3d(10.0, -3.0, 2.0))
    xf.AddRotateXYZOp().Set(Gf.Vec3f(20.0, 35.0, -10.0))
    xf.AddScaleOp().Set(Gf.Vec3f(0.5, 0.5, 0.5))
    g = random_gaussians(300, degree=1, seed=3)
    g.opacities[:] = np.maximum(g.opacities, 0.5)
    write_gaussian_prim(stage, "/W/G", g, keep_raw=False)
    for p in camera_paths:
        cam = UsdGeom.Camera.Define(stage, p)
        cam.AddTranslateOp().Set(Gf.Vec3d(10.0, -3.0, 12.0))
    save_stage_atomic(stage, path)
    return open_stage(str(path))


# ----------------------------------------------------------------------------- frames to PNG
def test_render_frames_writes_pngs_equal_to_the_renderer(quick_demo, tmp_path):
    assert main(["render", str(quick_demo), "--frames", "1-2", "-o", str(tmp_path / "f_####.png"), "--width", str(W),
                 "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0001.png", "f_0002.png"]
    stage = open_stage(str(quick_demo))
    imgs = []
    for f in (1, 2):
        img = _png(tmp_path / f"f_{f:04d}.png")
        assert img.shape == (H, W, 3)
        ref = render_stage_frame(stage, f, "/World/Camera", W)
        assert ref.prims[-1].startswith("/World/Room/Brick_") and "/World/Biker" in ref.prims
        np.testing.assert_array_equal(img, _u8(ref.rgb))  # written as is: no sRGB curve, black background
        # the room surrounds the camera: everything is covered, and there is structure in the image
        assert ref.alpha.mean() > 0.95
        assert img.std() > 10.0
        imgs.append(img)
    # the avatars walk: the two frames differ, but only in part of the image
    moved = np.any(imgs[0] != imgs[1], axis=-1).mean()
    assert 0.0 < moved < 0.5


def test_default_camera_is_the_stage_camera(quick_demo, tmp_path):
    stage = open_stage(str(quick_demo))
    cam = resolve_camera(stage, None, 1.0, W)
    ref = Camera.from_usd(stage.GetPrimAtPath("/World/Camera"), 1.0, width=W)
    assert (cam.width, cam.height) == (W, H)
    np.testing.assert_array_equal(cam.position, ref.position)
    np.testing.assert_array_equal(cam.rotation, ref.rotation)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.near, cam.far) == (ref.fx, ref.fy, ref.cx, ref.cy, ref.near, ref.far)
    # the CLI without --camera gives the same image as with --camera /World/Camera
    assert main(["render", str(quick_demo), "-o", str(tmp_path / "a.png"), "--width", str(W), "-q"]) == 0
    assert main(["render", str(quick_demo), "-o", str(tmp_path / "b.png"), "--width", str(W), "-q",
                 "--camera", "/World/Camera", "--frames", "1"]) == 0
    np.testing.assert_array_equal(_png(tmp_path / "a.png"), _png(tmp_path / "b.png"))


def test_first_camera_in_path_order(tmp_path):
    stage = _small_stage(tmp_path / "two.usda", camera_paths=("/W/Zcam", "/Acam"))
    cam = resolve_camera(stage, None, 1.0, 64)
    np.testing.assert_array_equal(cam.position, Camera.from_usd(stage.GetPrimAtPath("/Acam"), 1.0, 64).position)
    np.testing.assert_array_equal(cam.position, [10.0, -3.0, 12.0])


# ----------------------------------------------------------------------------- compare
def test_compare_is_input_and_processed_side_by_side(quick_demo, processed, tmp_path):
    args = ["--frames", "2", "--width", str(W), "-q"]
    assert main(["render", str(processed), "-o", str(tmp_path / "c.png"), "--compare", *args]) == 0
    assert main(["render", str(quick_demo), "-o", str(tmp_path / "in.png"), *args]) == 0
    assert main(["render", str(processed), "-o", str(tmp_path / "out.png"), *args]) == 0
    c = _png(tmp_path / "c.png")
    left, right = _png(tmp_path / "in.png"), _png(tmp_path / "out.png")
    assert c.shape == (H, 2 * W + 4, 3)
    np.testing.assert_array_equal(c[:, :W], left)
    np.testing.assert_array_equal(c[:, W + 4:], right)
    assert np.all(c[:, W:W + 4] == 255)  # white separator
    # the processed stage really is different (shadows, relit avatars) from the input
    diff = np.abs(left.astype(np.int16) - right.astype(np.int16))
    assert diff.mean() > 0.5
    # the shadows darken the room: away from the avatars and the guitar (their own coverage
    # below 2%), a good share of pixels lost light and none gained any
    stage = open_stage(str(quick_demo))
    movers = GaussianSet.concatenate([read_gaussian_prim(stage.GetPrimAtPath(p), 2.0)
                                      for p in ("/World/Biker", "/World/CesiumMan", "/World/Guitar")])
    room = render(movers, resolve_camera(stage, None, 2.0, W)).alpha < 0.02
    assert room.mean() > 0.8
    lsum, rsum = left.astype(np.int16).sum(-1), right.astype(np.int16).sum(-1)
    assert (rsum < lsum - 6)[room].mean() > 0.01
    assert not (rsum > lsum + 6)[room].any()


def test_compare_needs_sublayers(tmp_path, capsys):
    _small_stage(tmp_path / "plain.usda")
    assert main(["render", str(tmp_path / "plain.usda"), "-o", str(tmp_path / "c.png"), "--compare", "-q"]) == 2
    err = capsys.readouterr().err
    assert "plain.usda" in err and "--compare" in err and "sublayer" in err
    assert not (tmp_path / "c.png").exists()


# ----------------------------------------------------------------------------- EXR
def test_exr_holds_the_linear_render(quick_demo, tmp_path):
    import OpenEXR

    assert main(["render", str(quick_demo), "--frames", "2", "-o", str(tmp_path / "e_##.exr"), "--exr",
                 "--width", str(W), "--background", "0.25,0.5,1", "-q"]) == 0
    with OpenEXR.File(str(tmp_path / "e_02.exr")) as f:
        px = f.channels()["RGBA"].pixels
    assert px.shape == (H, W, 4) and px.dtype == np.float32
    ref = render_stage_frame(open_stage(str(quick_demo)), 2, None, W, background=(0.25, 0.5, 1.0))
    np.testing.assert_array_equal(px[..., :3], ref.rgb)
    np.testing.assert_array_equal(px[..., 3], ref.alpha)
    # some pixels exceed the 8-bit range or are not multiples of 1/255: real float data
    assert np.any(np.abs(px[..., :3] * 255 - np.round(px[..., :3] * 255)) > 1e-3)


# ----------------------------------------------------------------------------- look-at fallback
@pytest.mark.parametrize("width,height", [(160, 90), (60, 200)])
def test_framing_camera_sees_every_box_corner(width, height):
    lo, hi = np.array([-1.0, 2.0, -3.0]), np.array([4.0, 2.5, 1.0])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for up in ("Y", "Z"):
        cam = framing_camera(lo, hi, width, height, up_axis=up)
        uv, depth = cam.project(corners)
        assert np.all(depth > cam.near) and np.all(depth < cam.far)
        assert np.all((uv[:, 0] >= 0) & (uv[:, 0] <= width) & (uv[:, 1] >= 0) & (uv[:, 1] <= height))
        # not a speck: the box spans a good part of the narrower image side
        span = max((uv[:, 0].max() - uv[:, 0].min()) / width, (uv[:, 1].max() - uv[:, 1].min()) / height)
        assert span > 0.4
        # the stage's up axis points up in the image
        axis = np.array([0.0, 1.0, 0.0] if up == "Y" else [0.0, 0.0, 1.0])
        assert cam.rotation[:, 1] @ axis > 0.5


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_fallback_camera_frames_all_gaussians(tmp_path, up):
    stage = _small_stage(tmp_path / "nocam.usda", up=up)
    cam = resolve_camera(stage, None, 1.0, 120)
    assert (cam.width, cam.height) == (120, round(120 * 9 / 16))
    centres = read_gaussian_prim(stage.GetPrimAtPath("/W/G"), 1.0).positions
    uv, depth = cam.project(centres)
    assert np.all(depth > cam.near)
    assert np.all((uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height))
    assert main(["render", str(tmp_path / "nocam.usda"), "-o", str(tmp_path / "n.png"), "--width", "120", "-q"]) == 0
    img = _png(tmp_path / "n.png")
    assert img.shape == (68, 120, 3) and np.count_nonzero(img.max(-1)) > 100


# ----------------------------------------------------------------------------- which prims are drawn
def test_guide_proxy_and_invisible_prims_are_skipped(tmp_path):
    stage = new_stage(default_prim="W")
    counts = {"/W/A": 50, "/W/Guide": 60, "/W/Proxy": 70, "/W/Hidden/G": 80, "/W/Blink": 90}
    for i, (path, n) in enumerate(counts.items()):
        write_gaussian_prim(stage, path, random_gaussians(n, degree=0, seed=i))
    UsdGeom.Imageable(stage.GetPrimAtPath("/W/Guide")).CreatePurposeAttr(UsdGeom.Tokens.guide)
    UsdGeom.Imageable(stage.GetPrimAtPath("/W/Proxy")).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    UsdGeom.Imageable(stage.GetPrimAtPath("/W/Hidden")).MakeInvisible()  # an ancestor hides it
    vis = UsdGeom.Imageable(stage.GetPrimAtPath("/W/Blink")).CreateVisibilityAttr()
    vis.Set(UsdGeom.Tokens.inherited, Usd.TimeCode(1))
    vis.Set(UsdGeom.Tokens.invisible, Usd.TimeCode(2))
    assert [p.GetPath().pathString for p in drawn_gaussian_prims(stage, 1)] == ["/W/A", "/W/Blink"]
    assert [p.GetPath().pathString for p in drawn_gaussian_prims(stage, 2)] == ["/W/A"]
    g1, prims1 = read_stage_gaussians(stage, 1)
    assert prims1 == ["/W/A", "/W/Blink"] and g1.count == 50 + 90
    np.testing.assert_array_equal(g1.positions[:50], random_gaussians(50, degree=0, seed=0).positions)
    g2, _ = read_stage_gaussians(stage, 2)
    assert g2.count == 50


def test_nothing_drawn_gives_the_background(tmp_path):
    stage = new_stage(default_prim="W")
    write_gaussian_prim(stage, "/W/G", random_gaussians(20, degree=0, seed=1))
    UsdGeom.Imageable(stage.GetPrimAtPath("/W/G")).MakeInvisible()
    cam = Camera.look_at([0, 0, 20], [0, 0, 0], width=16, height=8)
    res = render_stage_frame(stage, 1, cam, background=(0.1, 0.2, 0.3))
    assert res.count == 0 and res.rgb.shape == (8, 16, 3)
    np.testing.assert_array_equal(res.rgb, np.broadcast_to(np.float32([0.1, 0.2, 0.3]), (8, 16, 3)))
    assert not res.alpha.any()


# ----------------------------------------------------------------------------- output names and errors
def test_frame_path():
    assert frame_path("out_####.png", 1.0) == "out_0001.png"
    assert frame_path("d/x_##.exr", 123.0) == "d/x_123.exr"
    assert frame_path("out_####.png", 2.5) == "out_0002.5.png"
    assert frame_path("out_###.png", -4.0) == "out_-004.png"
    assert frame_path("dir#1/still.png", 7.0) == "dir#1/still.png"  # only the file name is a pattern


@pytest.mark.parametrize("case", ["missing_stage", "no_prim", "not_camera", "no_hash", "no_dir", "bad_ext",
                                  "bad_background"])
def test_user_errors_exit_2_naming_the_thing(quick_demo, tmp_path, capsys, case):
    stage = str(quick_demo)
    out = str(tmp_path / "f_####.png")
    argv, needle = {
        "missing_stage": (["render", str(tmp_path / "nope.usda"), "-o", out], "nope.usda"),
        "no_prim": (["render", stage, "-o", out, "--camera", "/Nope"], "/Nope"),
        "not_camera": (["render", stage, "-o", out, "--camera", "/World"], "not a UsdGeom.Camera"),
        "no_hash": (["render", stage, "-o", str(tmp_path / "f.png"), "--frames", "1-2"], "f.png"),
        "no_dir": (["render", stage, "-o", str(tmp_path / "missing" / "f_####.png")], "missing"),
        "bad_ext": (["render", stage, "-o", str(tmp_path / "f_####.jpg")], "f_####.jpg"),
        "bad_background": (["render", stage, "-o", out, "--background", "1,2"], "--background"),
    }[case]
    assert main([*argv, "--width", "32", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("usdgs render: error:") and needle in err and "\n" not in err
    if case == "not_camera":
        assert "/World" in err
    if case == "no_hash":
        assert "#" in err
    assert not list(tmp_path.glob("*.png"))


def test_compare_on_an_unprocessed_stage_warns(quick_demo, tmp_path, capsys):
    # the demo input has data sublayers but no /UsdGs prim: it works, with a warning naming the sublayer
    assert main(["render", str(quick_demo), "-o", str(tmp_path / "c.png"), "--compare", "--width", "32"]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "cesium_man.usdc" in err
    assert _png(tmp_path / "c.png").shape == (18, 2 * 32 + 4, 3)


def test_frames_outside_the_stage_range_warn(processed, tmp_path, capsys):
    """A frame beyond the stage's time range renders the held values, with a warning naming it and the
    range; frames inside give none."""
    out = str(tmp_path / "r_####.png")
    assert main(["render", str(processed), "-o", out, "--frames", "2,99", "--width", "32"]) == 0
    err = capsys.readouterr().err
    from pxr import Usd

    end = Usd.Stage.Open(str(processed)).GetEndTimeCode()
    assert f"warning: frame(s) 99 outside {processed}'s time range 1..{end:g}" in err
    assert (tmp_path / "r_0099.png").exists()
    assert main(["render", str(processed), "-o", str(tmp_path / "s_####.png"), "--frames", "1-2", "--width", "32"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_fallback_camera_frames_the_capture_not_its_stray_splats(tmp_path):
    """A 1 m cluster of 5,000 Gaussians and 20 stray ones 30-40 m away (a capture's floaters): the
    default look-at camera frames the cluster (the 1st-99th percentile of the centres on each axis),
    which then fills most of the image height, where the union of the bounds would leave it a few
    pixels; a prim that moves widens the box to every rendered frame's centres."""
    from usd_gs.render.preview import gaussian_framing_bounds, gaussian_world_bounds

    stage = new_stage(up_axis="Y", default_prim="W")
    UsdGeom.Xform.Define(stage, "/W")
    g = random_gaussians(5020, degree=0, seed=4)
    rng = np.random.default_rng(4)
    g.positions[:5000] = rng.uniform(-0.5, 0.5, (5000, 3)).astype(np.float32)
    d = rng.normal(size=(20, 3))
    d *= rng.uniform(30, 40, (20, 1)) / np.linalg.norm(d, axis=1, keepdims=True)
    g.positions[5000:] = d.astype(np.float32)
    write_gaussian_prim(stage, "/W/G", g, keep_raw=False)
    lo, hi = gaussian_framing_bounds(stage, [1.0])
    assert np.all(lo > -0.5) and np.all(lo < -0.45) and np.all(hi < 0.5) and np.all(hi > 0.45)
    assert np.all(gaussian_world_bounds(stage, [1.0])[1] > 20.0)  # (the union: the strays)
    cam = resolve_camera(stage, None, 1.0, 160)
    uv, depth = cam.project(g.positions[:5000].astype(np.float64))
    assert np.all(depth > cam.near) and np.all((uv[:, 1] >= 0) & (uv[:, 1] <= cam.height))
    assert np.ptp(uv[:, 1]) > 0.5 * cam.height
    # a second prim, moving 3 m along x between frames 1 and 2: its centres at both frames are framed
    m = random_gaussians(500, degree=0, seed=5)
    m.positions[:] = rng.uniform(-0.1, 0.1, (500, 3)).astype(np.float32)
    write_gaussian_prim(stage, "/W/M", m, keep_raw=False)
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/W/M")).AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), Usd.TimeCode(1))
    op.Set(Gf.Vec3d(3, 0, 0), Usd.TimeCode(2))
    lo, hi = gaussian_framing_bounds(stage, [1.0, 2.0])
    assert hi[0] > 2.9 and lo[0] < -0.45
