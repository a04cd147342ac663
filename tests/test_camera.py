"""Pinhole cameras: look-at, projection conventions, USD cameras, OpenGL cube-map faces."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels.cubemap_dirs import cube_face_directions
from usd_gs.errors import UserError
from usd_gs.render.camera import CUBE_FACE_NAMES, Camera, cube_face_cameras


def test_look_at_projects_target_to_centre_and_up_upward():
    cam = Camera.look_at([1.0, 2.0, 5.0], [0.5, 1.0, -1.0], up=(0, 1, 0), width=101, height=61, fov_y_deg=60)
    uv, z = cam.project([[0.5, 1.0, -1.0]])
    np.testing.assert_allclose(uv[0], [50.5, 30.5], atol=1e-9)
    assert z[0] == pytest.approx(np.linalg.norm([0.5, 1.0, 6.0]))
    # a point above the target lands higher in the image (smaller v), one to the right larger u
    right = cam.rotation[:, 0]
    uv2, _ = cam.project([[0.5, 1.3, -1.0], np.array([0.5, 1.0, -1.0]) + 0.2 * right])
    assert uv2[0, 1] < 30.5 and abs(uv2[0, 0] - 50.5) < 1e-9
    assert uv2[1, 0] > 50.5
    # proper rotation, camera looks down its local -Z
    assert np.linalg.det(cam.rotation) == pytest.approx(1.0)
    fwd = np.array([-0.5, -1.0, -6.0]) / np.linalg.norm([0.5, 1.0, 6.0])
    np.testing.assert_allclose(-cam.rotation[:, 2], fwd, atol=1e-12)
    # vertical field of view: the top edge of the image is fov/2 above the axis
    assert cam.fy == pytest.approx(30.5 / np.tan(np.radians(30)))


def test_pixel_directions_round_trip_through_project():
    cam = Camera(np.array([0.3, -1.0, 2.0]), Camera.look_at([0, 0, 0], [1, 2, 3]).rotation, 80.0, 70.0, 30.0, 20.0,
                 64, 48)
    d = cam.pixel_directions()
    assert d.shape == (48, 64, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    pts = cam.position + 2.5 * d.reshape(-1, 3)
    uv, z = cam.project(pts)
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    np.testing.assert_allclose(uv[:, 0], jj.ravel(), atol=1e-9)
    np.testing.assert_allclose(uv[:, 1], ii.ravel(), atol=1e-9)
    assert np.all(z > 0)
    vr, vt = cam.view_matrix()
    np.testing.assert_allclose(vr @ cam.position + vt, 0.0, atol=1e-12)


@pytest.mark.parametrize("size", [1, 4, 7])
def test_cube_face_cameras_match_opengl_cubemap_directions(size):
    cams = cube_face_cameras([1.0, -2.0, 0.5], size)
    assert len(cams) == 6 == len(CUBE_FACE_NAMES)
    dirs = np.stack([c.pixel_directions() for c in cams])
    np.testing.assert_allclose(dirs, cube_face_directions(size), atol=1e-12)
    for c in cams:
        assert np.linalg.det(c.rotation) == pytest.approx(-1.0)  # cube-map faces are mirror images
        assert c.fx == c.fy == c.cx == c.cy == size / 2


def test_cube_face_table_spot_checks():
    # OpenGL spec: face +X texel (s, t) looks along (1, -t, -s) etc.; corner texel (0, 0) of a
    # size-2 face has s = t = -0.5
    cams = cube_face_cameras(np.zeros(3), 2)
    expect = {0: (1, 0.5, 0.5), 1: (-1, 0.5, -0.5), 2: (-0.5, 1, -0.5), 3: (-0.5, -1, 0.5),
              4: (-0.5, 0.5, 1), 5: (0.5, 0.5, -1)}
    for f, v in expect.items():
        d = cams[f].pixel_directions()[0, 0]
        np.testing.assert_allclose(d, np.array(v) / np.linalg.norm(v), atol=1e-12)


def test_invalid_cameras_raise_user_error():
    with pytest.raises(UserError, match="near"):
        Camera(np.zeros(3), np.eye(3), 10, 10, 5, 5, 10, 10, near=0.0)
    with pytest.raises(UserError, match="orthogonal"):
        Camera(np.zeros(3), 2 * np.eye(3), 10, 10, 5, 5, 10, 10)
    with pytest.raises(UserError, match="focal"):
        Camera(np.zeros(3), np.eye(3), 0, 10, 5, 5, 10, 10)
    with pytest.raises(UserError, match="parallel"):
        Camera.look_at([0, 0, 0], [0, 1, 0], up=(0, 1, 0))
    with pytest.raises(UserError):
        cube_face_cameras(np.zeros(3), 0)


def _usd_camera(stage, path, translate, rotate_xyz, focal=35.0, h_ap=36.0, v_ap=24.0, h_off=0.0, v_off=0.0,
                clip=(0.1, 500.0), scale=1.0):
    from pxr import Gf, UsdGeom

    cam = UsdGeom.Camera.Define(stage, path)
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(*translate))
    xf.AddRotateXYZOp().Set(Gf.Vec3f(*rotate_xyz))
    if scale != 1.0:
        xf.AddScaleOp().Set(Gf.Vec3f(scale, scale, scale))
    cam.GetFocalLengthAttr().Set(focal)
    cam.GetHorizontalApertureAttr().Set(h_ap)
    cam.GetVerticalApertureAttr().Set(v_ap)
    cam.GetHorizontalApertureOffsetAttr().Set(h_off)
    cam.GetVerticalApertureOffsetAttr().Set(v_off)
    cam.GetClippingRangeAttr().Set(Gf.Vec2f(*clip))
    return cam


def _usd_pixels(usd_cam, points, width, height):
    """Project with USD's own frustum matrices: NDC -> pixels (y up in NDC, rows down)."""
    from pxr import Gf, Usd

    fr = usd_cam.GetCamera(Usd.TimeCode.Default()).frustum
    m = fr.ComputeViewMatrix() * fr.ComputeProjectionMatrix()
    out = []
    for p in points:
        h = Gf.Vec4d(p[0], p[1], p[2], 1.0) * m
        ndc = np.array([h[0] / h[3], h[1] / h[3]])
        out.append([(ndc[0] + 1) * 0.5 * width, (1 - ndc[1]) * 0.5 * height])
    return np.array(out)


@pytest.mark.parametrize("offsets", [(0.0, 0.0), (2.0, -1.5)])
def test_from_usd_matches_usd_frustum_projection(offsets):
    from pxr import Usd

    stage = Usd.Stage.CreateInMemory()
    usd_cam = _usd_camera(stage, "/cam", (1.0, 2.0, 3.0), (10.0, 25.0, -5.0), focal=40.0, h_off=offsets[0],
                          v_off=offsets[1], scale=2.0)
    cam = Camera.from_usd(usd_cam, width=300)
    assert cam.height == 200  # 300 * 24 / 36
    assert (cam.near, cam.far) == pytest.approx((0.1, 500.0))
    np.testing.assert_allclose(cam.position, [1.0, 2.0, 3.0], atol=1e-9)
    rng = np.random.default_rng(0)
    fwd = -cam.rotation[:, 2]
    pts = cam.position + 5.0 * fwd + rng.uniform(-1, 1, (10, 3))
    uv, z = cam.project(pts)
    np.testing.assert_allclose(uv, _usd_pixels(usd_cam, pts, 300, 200), atol=1e-6)
    assert np.all(z > 0)
    # the prim itself and an explicit time code work too
    cam2 = Camera.from_usd(usd_cam.GetPrim(), time=1.0, width=300)
    np.testing.assert_allclose(cam2.rotation, cam.rotation)


def test_from_usd_animated_camera_and_errors():
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    cam = UsdGeom.Camera.Define(stage, "/anim")
    op = UsdGeom.Xformable(cam).AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 1.0)
    op.Set(Gf.Vec3d(10, 0, 0), 11.0)
    c = Camera.from_usd(cam, time=6.0, width=64)
    np.testing.assert_allclose(c.position, [5.0, 0.0, 0.0], atol=1e-9)
    cam.GetProjectionAttr().Set(UsdGeom.Tokens.orthographic)
    with pytest.raises(UserError, match="/anim.*orthographic"):
        Camera.from_usd(cam, width=64)
    xf = UsdGeom.Xform.Define(stage, "/notcam")
    with pytest.raises(UserError, match="/notcam"):
        Camera.from_usd(xf.GetPrim(), width=64)
