"""CPU splat rasteriser: brute-force float64 reference, analytic footprints, blending order,
early termination, masks, SH colour, cube faces, tile independence, PNG writer."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels.cubemap_dirs import cube_face_directions
from numba_kernels.rasterize import rasterize
from numba_kernels.reference.rasterize import rasterize as render_reference
from usd_gs import sh3dgs
from usd_gs.gaussians import GaussianSet
from usd_gs.render.camera import Camera
from usd_gs.render.rasterize import cube_faces_cross, render, render_batch, render_cube_faces, to_srgb8, write_png

IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


def _random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _gset(pos, scales, opac, dc, q=None, sh=None):
    pos = np.atleast_2d(np.asarray(pos, np.float64))
    n = len(pos)
    if sh is None:
        sh = np.zeros((n, 1, 3))
        sh[:, 0] = (np.asarray(dc, np.float64) - 0.5) / sh3dgs.C0  # colour dc exactly
    if q is None:
        q = np.tile(IDENTITY_Q, (n, 1))
    return GaussianSet(pos, q, np.broadcast_to(np.asarray(scales, np.float64), (n, 3)),
                       np.broadcast_to(np.asarray(opac, np.float64), (n,)), sh)


def _reference(g: GaussianSet, cam: Camera, mask=None, antialiased=False):
    vr, vt = cam.view_matrix()
    return render_reference(g.positions, g.orientations, g.scales, g.opacities, g.sh, vr, vt, cam.intrinsics(),
                            [cam.near, cam.far], cam.position, cam.width, cam.height, include=mask,
                            antialiased=antialiased)


def _psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return np.inf if mse == 0 else 10.0 * np.log10(1.0 / mse)


CAM = Camera.look_at([0.3, 0.2, 4.0], [0.0, 0.0, 0.0], width=64, height=48, fov_y_deg=50.0)


def _scene_random(seed=0, n=300):
    """Random sizes/orientations/opacities/SH3, some behind the camera (z > 4) and some beside it."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1, 1, (n, 3)) * [2.0, 1.5, 3.0]
    pos[:20, 2] = rng.uniform(4.5, 6.0, 20)  # behind the camera
    return GaussianSet(pos, _random_quats(rng, n), np.exp(rng.uniform(np.log(0.01), np.log(0.3), (n, 3))),
                       rng.uniform(0.05, 1.0, n), rng.normal(0, 0.5, (n, 16, 3)))


def _scene_hard(seed=1):
    """Needles (aspect up to 300), equal-depth overlaps, centres on tile borders, big splats."""
    rng = np.random.default_rng(seed)
    uv_border = []
    # centres projected exactly onto tile borders (pixel coordinates 16, 32, 48 / 16, 32)
    for u in (16.0, 32.0, 48.0):
        for v in (16.0, 32.0):
            uv_border.append((u, v))
    uv_border = np.array(uv_border)
    depth = 3.0
    dirs_cam = np.stack([(uv_border[:, 0] - CAM.cx) / CAM.fx, -(uv_border[:, 1] - CAM.cy) / CAM.fy,
                         -np.ones(len(uv_border))], axis=1)
    border = CAM.position + depth * dirs_cam @ CAM.rotation.T
    m = 120
    needles = rng.uniform(-1, 1, (m, 3)) * [1.5, 1.2, 1.0]
    s_needle = np.full((m, 3), 0.004)
    s_needle[:, 0] = rng.uniform(0.3, 1.2, m)
    same = rng.uniform(-1, 1, (40, 3)) * [1.0, 0.8, 0.0]  # all at world z = 0 -> nearly equal depth
    same[20:, :] = same[:20, :]  # exact duplicates: equal depth, tie broken by index
    pos = np.concatenate([border, needles, same, [[0.0, 0.0, 0.0]]])
    n = len(pos)
    scales = np.concatenate([np.full((len(border), 3), 0.08), s_needle, np.full((40, 3), 0.05), [[0.9, 0.9, 0.9]]])
    sh = rng.normal(0, 0.6, (n, 4, 3))
    return GaussianSet(pos, _random_quats(rng, n), scales, rng.uniform(0.3, 1.0, n), sh)


@pytest.mark.parametrize("make", [_scene_random, _scene_hard])
def test_matches_brute_force_reference(make):
    g = make()
    fast = render(g, CAM)
    c, t, d = _reference(g, CAM)
    assert _psnr(fast.rgb, c) >= 40.0
    assert _psnr(fast.alpha, 1.0 - t) >= 40.0
    # much tighter in fact (same image formation, float32 records vs float64): only a rare pixel
    # where float32 rounding flips a threshold (1/255, 3 sigma) differs by more than 1e-4
    err = np.abs(fast.rgb - c).max(axis=-1)
    assert np.mean(err > 1e-4) < 0.002 and err.max() < 0.05
    assert np.mean(np.abs(fast.alpha - (1.0 - t)) > 1e-4) < 0.002
    cov = (1.0 - t) > 0.05
    assert np.median(np.abs(fast.depth[cov] - d[cov] / (1.0 - t[cov]))) < 1e-5
    assert 0.3 < fast.alpha.mean() < 1.0  # the scene is neither empty nor trivially opaque


def test_cube_faces_match_reference():
    # mirrored (det -1) face cameras inside a scene: every face against the brute-force reference
    from usd_gs.render.camera import cube_face_cameras

    g = _scene_random(seed=7, n=250)
    centre = np.array([0.1, -0.2, 0.3])
    rgb, alpha, depth = render_cube_faces(g, centre, 24)
    for f, cam in enumerate(cube_face_cameras(centre, 24)):
        c, t, d = _reference(g, cam)
        assert _psnr(rgb[f], c) >= 40.0 and np.mean(np.abs(rgb[f] - c).max(-1) > 1e-4) < 0.005
        assert _psnr(alpha[f], 1.0 - t) >= 40.0
        assert alpha[f].mean() > 0.05


def test_sub_pixel_splats_are_culled_before_projection_and_the_image_is_unchanged():
    """A probe-like render (no dilation, antialiased) of splats far smaller than a pixel: the cheap
    cull already drops those whose bounding square holds no pixel centre (most of them), and what
    is drawn equals the brute-force reference, pixel for pixel (a wrongly culled splat would show)."""
    rng = np.random.default_rng(11)
    n = 4000
    pos = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.1, 1.1, n), rng.uniform(-0.5, 0.5, n)])
    g = GaussianSet(pos, _random_quats(rng, n), np.exp(rng.uniform(np.log(5e-4), np.log(4e-3), (n, 3))),
                    rng.uniform(0.05, 1.0, n), rng.normal(0, 0.5, (n, 4, 3)))
    vr, vt = CAM.view_matrix()
    color, trans, _, stats = rasterize(g.positions, g.orientations, g.scales, g.opacities, g.sh, vr[None], vt[None],
                                       CAM.intrinsics()[None], np.array([[CAM.near, CAM.far]]),
                                       CAM.position[None], CAM.width, CAM.height, dilation=0.0, antialiased=True)
    c, t, _ = render_reference(g.positions, g.orientations, g.scales, g.opacities, g.sh, vr, vt, CAM.intrinsics(),
                               [CAM.near, CAM.far], CAM.position, CAM.width, CAM.height, dilation=0.0,
                               antialiased=True)
    assert stats["entries"] > 40  # some splats do cover a pixel centre
    assert stats["culled_pass"] < 0.5 * n  # the others never reach the full projection
    assert stats["entries"] <= stats["culled_pass"]
    np.testing.assert_allclose(color[0], c, atol=1e-4)  # float32 records; a missing splat: >= 1/255 of alpha
    np.testing.assert_allclose(trans[0], t, atol=1e-4)


def _full_cull_bits(pos, scales, opac, cams, width, height, dilation, guard=1.3):
    """The cull's per-camera bits without its division-free early reject: the full bound of
    ``numba_kernels.rasterize._cull`` (each image axis's half-extent bound), in numpy (float64)."""
    from numba_kernels.rasterize import ALPHA_MIN, SUPPORT_Q

    p = np.asarray(pos, np.float64)
    op = np.minimum(1.0, np.asarray(opac, np.float64))
    q = np.minimum(SUPPORT_Q * (1 + 1e-5), 2 * np.log(np.maximum(op, ALPHA_MIN) / ALPHA_MIN) * (1 + 1e-5) + 1e-5)
    smax = np.abs(np.asarray(scales, np.float64)).max(axis=1)
    bits = np.zeros(len(p), np.int64)
    for k, cam in enumerate(cams):
        vr, vt = cam.view_matrix()
        fx, fy, cx, cy = cam.intrinsics()
        with np.errstate(divide="ignore", invalid="ignore"):  # (rows with a NaN or infinite centre)
            v = p @ np.asarray(vr).T + vt
            x, y, z = v[:, 0], v[:, 1], v[:, 2]
            iz = 1.0 / z
            hx, hy = 0.5 * width / fx, 0.5 * height / fy
            mx, my = (0.5 * width - cx) / fx, (0.5 * height - cy) / fy
            tx = np.clip(x * iz, mx - guard * hx, mx + guard * hx)
            ty = np.clip(y * iz, my - guard * hy, my + guard * hy)
            ebx = np.sqrt(q * (smax**2 * (fx * iz) ** 2 * (1 + tx * tx) + dilation)) * (1 + 1e-6) + 1e-6
            eby = np.sqrt(q * (smax**2 * (fy * iz) ** 2 * (1 + ty * ty) + dilation)) * (1 + 1e-6) + 1e-6
            u, w = fx * x * iz + cx, fy * y * iz + cy
            hit = ((z > cam.near) & (z <= cam.far) & (op >= ALPHA_MIN)
                   & (np.minimum(np.floor(u + ebx - 0.5), width - 1) >= np.maximum(np.ceil(u - ebx - 0.5), 0))
                   & (np.minimum(np.floor(w + eby - 0.5), height - 1) >= np.maximum(np.ceil(w - eby - 0.5), 0)))
        bits |= np.where(hit, np.int64(1) << k, 0)
    return bits


@pytest.mark.parametrize("dilation", [0.0, 0.3])
def test_cull_early_reject_keeps_every_pair_the_full_bound_keeps(dilation):
    """The cull's division-free reject of the cameras a splat misses by far changes no bit: on cube
    faces and a perspective camera, splats of every size straddling the image borders get exactly
    the bits of the full bound (a reject too eager would drop a bit; the full bound is what decides)."""
    from numba_kernels import rasterize as kr
    from usd_gs.render.camera import cube_face_cameras

    rng = np.random.default_rng(4)
    n = 30000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.array([0.2, 1.0, -0.3])
    pos = centre + d * np.exp(rng.uniform(np.log(0.05), np.log(50.0), n))[:, None]
    scales = np.exp(rng.uniform(np.log(1e-4), np.log(2.0), (n, 3)))
    opac = rng.uniform(0.0, 1.0, n)
    for cams, size in ((cube_face_cameras(centre, 32), (32, 32)), ([CAM], (CAM.width, CAM.height))):
        vm = [c.view_matrix() for c in cams]
        vr = np.stack([v[0] for v in vm])
        intr = np.stack([c.intrinsics() for c in cams])
        nearfar = np.array([[c.near, c.far] for c in cams])
        w, h = size
        packed, _ = kr.camera_rows(vr, np.stack([v[1] for v in vm]), intr, nearfar, w, h, 1.3)
        vis = np.empty(n, np.int64)
        kr._cull(0, n, pos.astype(np.float32), scales.astype(np.float32), opac.astype(np.float32),
                 np.zeros(0, np.bool_), np.zeros(0, np.int64), packed, w, h, dilation, np.zeros(0, np.int64),
                 np.zeros(0, np.int64), vis)
        want = _full_cull_bits(pos.astype(np.float32), scales.astype(np.float32), opac.astype(np.float32), cams, w,
                               h, dilation)
        assert np.array_equal(vis, want)
        # many cameras are in front of a splat that they miss: what the early reject is for
        front = sum(((pos @ np.asarray(v[0]).T + v[1])[:, 2] > c.near).sum() for v, c in zip(vm, cams, strict=True))
        kept = sum(bin(int(b)).count("1") for b in vis)
        assert np.mean(vis != 0) > 0.05 and kept < 0.8 * front


def test_cull_in_columns_gives_each_pairs_own_bits_with_masks_orders_blocks_and_bad_rows():
    """``_cull`` gathers rows into columns and tests each camera over them in vectorised loops
    (``_early_pass``, ``_support_pass``): its bits are those of the full bound pair by pair (numpy,
    float64), for three cubes at once (18 cameras) over bricks near and 40 m away, with a mask, with
    an order, with block camera masks, across its row batches (``_CULL_ROWS``), and with rows whose
    centre or opacity is NaN or infinite (never kept) and opacities below 1/255."""
    from numba_kernels import rasterize as kr
    from numba_kernels.capsule import block_scale_bound, block_spheres
    from usd_gs.render.camera import cube_face_cameras

    rng = np.random.default_rng(21)
    parts = []
    for i in range(12):  # bricks of ~700 rows: some cross a row batch, near ones straddle faces
        m = int(rng.integers(300, 1400))
        centre = rng.normal(0.0, 1.0, 3) * (1.5 if i < 6 else 40.0)
        parts.append(centre + rng.normal(0.0, rng.uniform(0.1, 2.0), (m, 3)))
    pos = np.concatenate(parts).astype(np.float32)
    n = len(pos)
    scales = np.exp(rng.uniform(np.log(1e-4), np.log(0.5), (n, 3))).astype(np.float32)
    opac = rng.uniform(0.0, 1.0, n).astype(np.float32)
    bad = rng.choice(n, 12, replace=False)
    pos[bad[:4], 0] = np.nan
    pos[bad[4:8], 2] = np.inf
    opac[bad[8:]] = np.nan
    starts = np.array([0, *np.cumsum([len(p) for p in parts])], np.int64)
    cams = [c for centre in ([0.0, 0.2, 0.0], [1.5, 0.2, 0.0], [0.0, 0.2, 1.5])
            for c in cube_face_cameras(np.array(centre), 32, near=0.05)]
    vm = [c.view_matrix() for c in cams]
    packed, _ = kr.camera_rows(np.stack([v[0] for v in vm]), np.stack([v[1] for v in vm]),
                               np.stack([c.intrinsics() for c in cams]), np.array([[c.near, c.far] for c in cams]),
                               32, 32, 1.3)
    want = _full_cull_bits(pos, scales, opac, cams, 32, 32, 0.0)
    assert np.all(want[bad] == 0) and np.mean(want != 0) > 0.05
    none = np.zeros(0, np.int64)
    centres, radii = block_spheres(pos, starts)
    blocks = kr._block_masks((starts, centres, radii, block_scale_bound(scales, starts)), np.zeros(0, np.int64), n,
                             packed, 32, 32, 0.0)
    include = rng.uniform(size=n) < 0.7
    order = np.flatnonzero(rng.uniform(size=n) < 0.5).astype(np.int64)
    cases = [("plain", np.zeros(0, bool), none, (none, none), want),
             ("blocks", np.zeros(0, bool), none, blocks, want),
             ("mask", include, none, (none, none), np.where(include, want, 0)),
             ("order and blocks", np.zeros(0, bool), order,
              kr._block_masks((starts, centres, radii, block_scale_bound(scales, starts)), order, n, packed, 32, 32,
                              0.0), want[order])]
    for name, inc, ordr, (bstart, bmask), expect in cases:
        vis = np.full(len(expect), -1, np.int64)
        kr._cull(0, len(expect), pos, scales, opac, inc, ordr, packed, 32, 32, 0.0, bstart, bmask, vis)
        assert np.array_equal(vis, expect), name
        part = np.full(len(expect), -1, np.int64)  # ranges as run_chunks gives them: the same bits
        for lo in range(0, len(expect), 997):
            kr._cull(lo, min(len(expect), lo + 997), pos, scales, opac, inc, ordr, packed, 32, 32, 0.0, bstart,
                     bmask, part)
        assert np.array_equal(part, expect), name
    far = starts[6]  # the far bricks: most of their rows are decided without the support's log
    assert np.mean(want[far:] != 0) < 0.5


def test_a_splat_missing_every_pixel_centre_is_rejected_before_its_support_is_sized():
    """``_misses_centres`` (the cull's test before the support's log and square root) says "no centre"
    only where :func:`_pixel_range` of the largest half-extent the cull can compute from that
    ``a`` is empty: on centres spread over the image, halfway between pixel centres, and at
    distances from the nearest centre one part in 1e9 either side of that extent (where it must
    say "maybe"); for sub-pixel splats it decides most of them."""
    from numba_kernels.rasterize import SUPPORT_Q_MAX, _misses_centres, _pixel_range

    rng = np.random.default_rng(8)
    a = np.exp(rng.uniform(np.log(1e-8), np.log(2.0), 20000))
    e = np.sqrt(SUPPORT_Q_MAX * a) * (1 + 1e-6) + 1e-6  # the largest half-extent for a
    k = rng.integers(-2, 66, a.size) + 0.5  # a pixel centre (some outside a 64-pixel image)
    side = rng.choice([-1.0, 1.0], a.size)
    cases = {"spread": rng.uniform(-2.0, 66.0, a.size), "halfway": k + 0.5,
             "just beyond": k + side * np.minimum(e * (1 + 1e-9) + 1e-12, 0.5),
             "just within": k + side * e * (1 - 1e-9)}
    for name, m in cases.items():
        missed = np.array([_misses_centres(float(mm), float(aa)) for mm, aa in zip(m, a, strict=True)])
        for mm, ee in zip(m[missed], e[missed], strict=True):
            lo, hi = _pixel_range(float(mm), float(ee), 64)
            assert hi < lo, (name, mm, ee)
        if name == "just within":
            assert not missed.any()  # a centre within the extent: never rejected
        if name == "spread":
            assert missed[e < 0.05].mean() > 0.8  # sub-pixel: most decided without the log
    assert not _misses_centres(np.nan, 1e-4) and not _misses_centres(3.7, np.nan)


def test_reference_with_mask_and_background():
    g = _scene_random(seed=3)
    mask = np.random.default_rng(0).uniform(size=g.count) < 0.5
    fast = render(g, CAM, background=(0.2, 0.4, 0.9), mask=mask)
    c, t, _ = _reference(g, CAM, mask=mask)
    ref = c + t[..., None] * np.array([0.2, 0.4, 0.9])
    assert _psnr(fast.rgb, ref) >= 40.0 and np.mean(np.abs(fast.rgb - ref) > 1e-4) < 0.002
    # the mask is the subset
    sub = render(g.subset(mask), CAM, background=(0.2, 0.4, 0.9))
    np.testing.assert_array_equal(sub.alpha, fast.alpha)
    np.testing.assert_allclose(sub.rgb, fast.rgb, atol=1e-6)


def test_order_draws_what_the_mask_draws_bit_for_bit():
    g = _scene_random(seed=5, n=1500)  # (several chunks of _write_entries, with and without the order)
    mask = np.random.default_rng(1).uniform(size=g.count) < 0.3
    for cams in ([CAM], None):
        if cams is None:
            a = render_cube_faces(g, np.zeros(3), 16, mask=mask, antialiased=True)
            b = render_cube_faces(g, np.zeros(3), 16, antialiased=True, order=np.flatnonzero(mask))
        else:
            a = render_batch(g, cams, mask=mask)
            b = render_batch(g, cams, order=np.flatnonzero(mask))
        assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    empty = render_batch(g, [CAM], order=np.zeros(0, np.int64))
    assert not empty[1].any()
    for bad in ([3, 2], [2, 2], [-1], [g.count]):
        with pytest.raises(ValueError, match="increasing indices"):
            render_batch(g, [CAM], order=np.array(bad))
    with pytest.raises(ValueError, match="not both"):
        render_batch(g, [CAM], mask=mask, order=np.flatnonzero(mask))


def _facing_camera(size=33):
    # principal point = centre of pixel 16 for an odd size
    return Camera(np.zeros(3), np.eye(3), 40.0, 40.0, size / 2, size / 2, size, size, near=0.05, far=100.0)


def test_single_isotropic_gaussian_analytic_footprint():
    cam = _facing_camera()
    z, sigma2d, op, dc = 2.0, 4.0, 0.8, np.array([0.2, 0.5, 0.9])
    # (f s / z)^2 + 0.3 = sigma2d^2 so the dilated footprint has sigma exactly 4 px
    s = np.sqrt(sigma2d**2 - 0.3) * z / cam.fx
    res = render(_gset([[0.0, 0.0, -z]], s, op, dc), cam)
    assert res.alpha[16, 16] == pytest.approx(op, abs=1e-6)
    assert res.alpha[16, 20] == pytest.approx(op * np.exp(-0.5), abs=1e-6)  # 1 sigma right
    assert res.alpha[12, 16] == pytest.approx(op * np.exp(-0.5), abs=1e-6)  # 1 sigma up
    assert res.alpha[19, 20] == pytest.approx(op * np.exp(-0.5 * 25 / 16), abs=1e-6)  # (4, 3) px: 1.25 sigma
    assert res.alpha[16, 16 + 12] == pytest.approx(op * np.exp(-4.5), abs=1e-6)  # 3 sigma: still inside
    assert res.alpha[16, 16 + 13] == 0.0 and res.alpha[0, 0] == 0.0  # outside the 3-sigma support
    hit = res.alpha > 0
    np.testing.assert_allclose(res.depth[hit], z, rtol=1e-6)
    assert np.all(res.depth[~hit] == 0)
    # colour = 0.5 + C0 * f_dc (premultiplied by alpha over black)
    np.testing.assert_allclose(res.rgb[hit] / res.alpha[hit, None], np.broadcast_to(dc, (hit.sum(), 3)), atol=1e-5)
    # over a background: c a + (1 - a) b
    bg = np.array([1.0, 0.0, 0.25])
    res_bg = render(_gset([[0.0, 0.0, -z]], s, op, dc), cam, background=bg)
    np.testing.assert_allclose(res_bg.rgb[16, 16], dc * op + (1 - op) * bg, atol=1e-6)


def test_antialiased_keeps_a_small_splats_energy():
    """Opacity-compensated dilation: a sub-pixel Gaussian's summed alpha equals its undilated
    integral op * 2 pi sigma^2 (px^2) up to the tails the 1/255 alpha floor and the 3-sigma
    support drop (< 5 % here); the plain 0.3 px^2 dilation inflates it by (sigma^2 + 0.3) / sigma^2;
    and the mode matches the brute-force reference on a random scene."""
    from usd_gs.render.rasterize import render_batch

    cam = _facing_camera(65)
    z, op = 2.0, 0.99
    for sigma_px in (0.3, 0.5, 1.0):
        s = sigma_px * z / cam.fx
        g = _gset([[0.0, 0.0, -z]], s, op, [1.0, 1.0, 1.0])
        plain = render(g, cam).alpha.sum()
        _, alpha, _ = render_batch(g, [cam], antialiased=True)
        truth = op * 2.0 * np.pi * sigma_px**2
        assert 0.95 * truth < alpha.sum() <= truth
        assert plain / truth == pytest.approx(1.0 + 0.3 / sigma_px**2, rel=0.05)  # (sigma^2 + 0.3) / sigma^2
    g = _scene_random(seed=5)
    rgb, alpha, _ = render_batch(g, [CAM], antialiased=True)
    c, t, _ = _reference(g, CAM, antialiased=True)
    assert _psnr(rgb[0], c) >= 40.0 and _psnr(alpha[0], 1.0 - t) >= 40.0
    assert np.abs(alpha[0] - render(g, CAM).alpha).max() > 1e-3  # the mode does change the image


def test_alpha_clamp_threshold_and_no_dilation():
    cam = _facing_camera()
    # opacity 1 is clamped to alpha 0.99
    res = render(_gset([[0.0, 0.0, -2.0]], 0.1, 1.0, [1, 1, 1]), cam)
    assert res.alpha[16, 16] == pytest.approx(0.99, abs=1e-7)
    # opacity below 1/255 draws nothing
    res = render(_gset([[0.0, 0.0, -2.0]], 0.1, 0.9 / 255, [1, 1, 1]), cam)
    assert res.alpha.max() == 0.0
    # dilation is a parameter: without it sigma2d = f s / z exactly
    res = render(_gset([[0.0, 0.0, -2.0]], 4.0 * 2.0 / 40.0, 0.5, [1, 1, 1]), cam, dilation=0.0)
    assert res.alpha[16, 20] == pytest.approx(0.5 * np.exp(-0.5), abs=1e-6)


def test_front_to_back_order_tiebreak_and_early_termination():
    cam = _facing_camera()
    s = 0.2
    red, green = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    # nearer green behind farther red in index order: depth decides
    g = _gset([[0, 0, -3.0], [0, 0, -2.0]], s, 0.7, [red, green])
    c = render(g, cam).rgb[16, 16]
    np.testing.assert_allclose(c, 0.7 * np.array(green) + 0.3 * 0.7 * np.array(red), atol=1e-6)
    # equal depth: the lower index is in front
    g = _gset([[0, 0, -2.0], [0, 0, -2.0]], s, 0.7, [red, green])
    np.testing.assert_allclose(render(g, cam).rgb[16, 16], [0.7, 0.3 * 0.7, 0.0], atol=1e-6)
    g = _gset([[0, 0, -2.0], [0, 0, -2.0]], s, 0.7, [green, red])
    np.testing.assert_allclose(render(g, cam).rgb[16, 16], [0.3 * 0.7, 0.7, 0.0], atol=1e-6)
    # early termination: T = 0.05, 0.0025, 1.25e-4, then 6.25e-6 < 1e-4 stops the pixel;
    # the 4th and later (blue) splats must not contribute
    cols = [red, red, red, [0, 0, 1], [0, 0, 1]]
    g = _gset([[0, 0, -2.0 - 0.1 * k] for k in range(5)], s, 0.95, cols)
    res = render(g, cam)
    assert res.alpha[16, 16] == pytest.approx(1 - 0.05**3, abs=1e-7)
    np.testing.assert_allclose(res.rgb[16, 16], [1 - 0.05**3, 0, 0], atol=1e-6)
    expect_depth = (0.95 * 2.0 + 0.05 * 0.95 * 2.1 + 0.05**2 * 0.95 * 2.2) / (1 - 0.05**3)
    assert res.depth[16, 16] == pytest.approx(expect_depth, rel=1e-6)


def test_behind_camera_and_near_far_culling():
    cam = _facing_camera()
    g = _gset([[0, 0, 2.0], [0, 0, -0.04], [0, 0, -200.0]], 0.5, 0.9, [1, 1, 1])
    assert render(g, cam).alpha.max() == 0.0


def test_view_dependent_sh_colour_and_clamp():
    rng = np.random.default_rng(5)
    sh = rng.normal(0, 0.8, (1, 16, 3))
    g = _gset([[0.3, -0.2, 0.1]], 0.1, 0.9, None, sh=sh)
    for eye in ([0.0, 0.0, 3.0], [2.5, 1.0, -1.5], [-1.0, -2.5, 0.5]):
        cam = Camera.look_at(eye, g.positions[0], width=33, height=33, fov_y_deg=40)
        res = render(g, cam)
        d = g.positions[0].astype(np.float64) - np.asarray(eye)
        expect = np.maximum(0.0, sh3dgs.eval_color(sh, d / np.linalg.norm(d)))[0]
        np.testing.assert_allclose(res.rgb[16, 16] / res.alpha[16, 16], expect, atol=1e-5)
    neg = _gset([[0.0, 0.0, -2.0]], 0.1, 0.9, [-0.5, 0.25, 2.0])
    res = render(neg, _facing_camera())
    np.testing.assert_allclose(res.rgb[16, 16] / res.alpha[16, 16], [0.0, 0.25, 2.0], atol=1e-5)


def _raw(g, cams, tile=16, include=None):
    vm = [c.view_matrix() for c in cams]
    return rasterize(g.positions, g.orientations, g.scales, g.opacities, g.sh, np.stack([v[0] for v in vm]),
                     np.stack([v[1] for v in vm]), np.stack([c.intrinsics() for c in cams]),
                     np.array([[c.near, c.far] for c in cams]), np.stack([c.position for c in cams]),
                     cams[0].width, cams[0].height, include=include, tile=tile)


def test_tile_size_and_batching_do_not_change_the_image():
    g = _scene_hard()
    a = _raw(g, [CAM], tile=16)
    b = _raw(g, [CAM], tile=8)
    c = _raw(g, [CAM], tile=64)
    for x, y in ((a, b), (a, c)):
        for k in range(3):
            np.testing.assert_array_equal(x[k], y[k])
    cam2 = Camera.look_at([-2.0, 1.0, 3.0], [0, 0, 0], width=64, height=48)
    both = _raw(g, [CAM, cam2])
    single = _raw(g, [cam2])
    for k in range(3):
        np.testing.assert_array_equal(both[k][0], a[k][0])
        np.testing.assert_array_equal(both[k][1], single[k][0])


def test_deterministic_across_thread_counts():
    import numba

    g = _scene_random(seed=11)
    base = render(g, CAM)
    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = render(g, CAM)
    finally:
        numba.set_num_threads(n)
    for a, b in ((base.rgb, one.rgb), (base.alpha, one.alpha), (base.depth, one.depth)):
        np.testing.assert_array_equal(a, b)


def test_render_batch_equals_single_renders():
    from usd_gs.errors import UserError

    g = _scene_random(seed=12)
    cam2 = Camera.look_at([2.0, -1.0, 3.0], [0, 0, 0], width=64, height=48)
    rgb, alpha, depth = render_batch(g, [CAM, cam2], background=(0.1, 0.2, 0.3))
    for k, cam in enumerate((CAM, cam2)):
        one = render(g, cam, background=(0.1, 0.2, 0.3))
        np.testing.assert_array_equal(rgb[k], one.rgb)
        np.testing.assert_array_equal(alpha[k], one.alpha)
        np.testing.assert_array_equal(depth[k], one.depth)
    with pytest.raises(UserError, match="same image size"):
        render_batch(g, [CAM, _facing_camera()])


def test_degenerate_inputs_stay_finite():
    g = GaussianSet(np.array([[0, 0, -2.0], [0.1, 0, -2.0], [0, 0.1, -2.0]]),
                    np.array([[0, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5]]),
                    np.array([[1e-12, 1e-12, 1e-12], [1e6, 1e-6, 1e-6], [0.1, 0.1, 0.1]]),
                    np.array([1.0, 0.5, 0.5]), np.zeros((3, 1, 3)))
    for dil in (0.3, 0.0):
        res = render(g, _facing_camera(), dilation=dil)
        for a in (res.rgb, res.alpha, res.depth):
            assert np.all(np.isfinite(a))
    # non-finite values are skipped, the rest still renders
    bad = GaussianSet(np.array([[np.nan, 0, -2.0], [np.inf, 0, -2.0], [0, 0, -2.0], [0, 0, -2.0], [0, 0, -2.0],
                                [0, 0, -2.0]]),
                      np.array([[1, 0, 0, 0]] * 5 + [[np.nan, 0, 0, 0]]),
                      np.array([[0.1] * 3, [0.1] * 3, [np.nan] * 3, [0.1] * 3, [0.1] * 3, [0.1] * 3]),
                      np.array([0.5, 0.5, 0.5, np.nan, 0.5, 0.5]), np.zeros((6, 1, 3)))
    bad.sh[4, 0, 0] = np.nan
    res = render(bad, _facing_camera())
    for a in (res.rgb, res.alpha, res.depth):
        assert np.all(np.isfinite(a))
    # the NaN-colour splat (red channel -> 0) and the NaN-quaternion splat (identity) are drawn
    assert res.alpha[16, 16] == pytest.approx(1 - 0.5 * 0.5, abs=1e-6)
    # a splat at the camera centre (depth 0) and an empty set
    g0 = _gset([[0.0, 0.0, 0.0]], 0.1, 0.9, [1, 1, 1])
    assert render(g0, _facing_camera()).alpha.max() == 0.0
    empty = GaussianSet.empty()
    res = render(empty, _facing_camera())
    assert res.alpha.max() == 0.0 and res.rgb.shape == (33, 33, 3)


def test_bad_mask_raises():
    from usd_gs.errors import UserError

    g = _scene_random()
    with pytest.raises(UserError, match="mask"):
        render(g, CAM, mask=np.ones(3, bool))


def test_cube_faces_look_along_cubemap_directions():
    size = 16
    dirs = cube_face_directions(size)
    centre = np.array([0.2, -0.3, 0.5])
    rng = np.random.default_rng(2)
    texels = [(f, int(rng.integers(1, size - 1)), int(rng.integers(1, size - 1))) for f in range(6)]
    texels += [(0, 2, 13), (2, 1, 14), (5, 14, 3)]
    for f, i, j in texels:
        d = dirs[f, i, j]
        g = _gset([centre + 3.0 * d], 0.002, 0.9, [0.9, 0.4, 0.1])
        rgb, alpha, depth = render_cube_faces(g, centre, size)
        assert rgb.shape == (6, size, size, 3) and alpha.shape == depth.shape == (6, size, size)
        hit = np.unravel_index(np.argmax(alpha), alpha.shape)
        assert hit == (f, i, j)
        assert alpha[f, i, j] == pytest.approx(0.9, abs=1e-4)  # the texel centre sees the splat centre
        assert depth[f, i, j] == pytest.approx(3.0 * abs(d[f // 2]), rel=1e-5)  # depth along the face axis


def test_cube_faces_are_seamless_for_a_uniform_shell():
    # a dense shell of splats around the probe covers every texel of every face
    rng = np.random.default_rng(4)
    v = rng.normal(size=(20000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    g = _gset(2.0 * v, 0.05, 0.8, [0.3, 0.6, 0.9])
    rgb, alpha, _ = render_cube_faces(g, np.zeros(3), 8)
    assert alpha.min() > 0.999
    np.testing.assert_allclose(rgb, np.broadcast_to([0.3, 0.6, 0.9], rgb.shape), atol=2e-3)
    cross = cube_faces_cross(rgb)
    assert cross.shape == (24, 32, 3)


def _read_png(path):
    """Decoded PNG as (H, W, C) uint8, read independently of the writer with Pillow."""
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "PNG"
        a = np.asarray(im)
    return a[..., None] if a.ndim == 2 else a


def test_png_writer(tmp_path):
    img = np.zeros((3, 5, 3), np.float32)
    img[0, 0] = [1.0, 0.5, 0.0]
    img[2, 4] = [0.0031308, 0.2, 2.0]
    out = _read_png(write_png(tmp_path / "a.png", img, srgb=True))
    assert out.shape == (3, 5, 3)
    # sRGB: 0.5 -> 1.055 * 0.5^(1/2.4) - 0.055 = 0.7354 -> 188; 0.2 -> 0.4845 -> 124
    np.testing.assert_array_equal(out[0, 0], [255, 188, 0])
    np.testing.assert_array_equal(out[2, 4], [round(255 * 12.92 * 0.0031308), 124, 255])
    grey = _read_png(write_png(tmp_path / "g.png", np.array([[0.0, 1.0]]), srgb=True))
    np.testing.assert_array_equal(grey[..., 0], [[0, 255]])
    # default: display-referred values, scaled as they are
    plain = _read_png(write_png(tmp_path / "p.png", img))
    np.testing.assert_array_equal(plain[0, 0], [255, 128, 0])
    np.testing.assert_array_equal(plain[2, 4], [1, 51, 255])
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[1, 1] = [1, 2, 3, 4]
    np.testing.assert_array_equal(_read_png(write_png(tmp_path / "c.png", rgba)), rgba)
    assert to_srgb8(np.array([np.nan, -1.0, 0.5]))[1] == 0
