"""The rasteriser's block-level camera skip (``rasterize(..., blocks=)``): the same images, bit for
bit, as the plain cull, and a camera left out of a block only where the plain cull drops every
Gaussian of that block for it."""

from __future__ import annotations

import numpy as np
import pytest

from numba_kernels import rasterize as rz
from numba_kernels.capsule import block_scale_bound, block_spheres
from usd_gs.gaussians import GaussianSet
from usd_gs.point_blocks import PointBlocks
from usd_gs.render.camera import Camera, cube_face_cameras
from usd_gs.synthetic import random_gaussians


def _camera_args(cams):
    vm = [c.view_matrix() for c in cams]
    return (np.stack([v[0] for v in vm]), np.stack([v[1] for v in vm]), np.stack([c.intrinsics() for c in cams]),
            np.array([[c.near, c.far] for c in cams]), np.stack([c.position for c in cams]),
            cams[0].width, cams[0].height)


def _bricks(seed: int = 0):
    """Spatially coherent bricks around the origin: near ones straddling several cube faces, far
    ones (20-60 m) inside one or two, one behind a camera's near plane and one with a NaN scale."""
    rng = np.random.default_rng(seed)
    parts = []
    for i in range(48):
        g = random_gaussians(1500, 1, seed=100 + i)
        spread = rng.uniform(0.05, 1.5)
        centre = rng.normal(0.0, 1.0, 3) * rng.choice([0.4, 3.0, 40.0])
        g.positions = (g.positions * np.float32(spread) + centre.astype(np.float32)).astype(np.float32)
        g.opacities = rng.uniform(0.002, 1.0, g.count).astype(np.float32)  # some below 1/255
        parts.append(g)
    parts[5].scales[7] = np.nan
    parts[6].positions[3] = np.nan
    g = GaussianSet.concatenate(parts)
    starts = np.array([0, *np.cumsum([p.count for p in parts])], np.int64)
    return g, starts


def _blocks(g, starts):
    centres, radii = block_spheres(g.positions, starts)
    return starts, centres, radii, block_scale_bound(g.scales, starts)


def _render(g, args, **kw):
    return rz.rasterize(g.positions, g.orientations, g.scales, g.opacities, g.sh, *args, antialiased=True, **kw)


def _same_bits(a, b) -> bool:
    return all(np.array_equal(x.view(np.uint32), y.view(np.uint32)) for x, y in zip(a[:3], b[:3], strict=True))


@pytest.mark.parametrize("dilation", [0.0, 0.3])
def test_cube_render_with_blocks_is_the_plain_render(dilation):
    g, starts = _bricks()
    blocks = _blocks(g, starts)
    order = np.flatnonzero(np.random.default_rng(1).random(g.count) > 0.3).astype(np.int64)
    mask = np.random.default_rng(2).random(g.count) > 0.5
    args = _camera_args(cube_face_cameras(np.array([0.1, 0.2, -0.3]), 48, near=0.05))
    for kw in ({}, {"order": order}, {"include": mask}):
        plain = _render(g, args, dilation=dilation, **kw)
        skip = _render(g, args, dilation=dilation, blocks=blocks, **kw)
        assert _same_bits(plain, skip)
        assert plain[3] == skip[3]  # the same pairs pass the cull, the same entries are drawn
        assert plain[3]["entries"] > 10_000
    # blocks cover a prefix only: the rows after them test every camera
    half = (starts[:25],) + tuple(x[:24] for x in blocks[1:])
    assert _same_bits(_render(g, args, dilation=dilation), _render(g, args, dilation=dilation, blocks=half))


def test_blocks_leave_out_only_cameras_the_cull_drops_for_every_gaussian():
    g, starts = _bricks(3)
    args = _camera_args(cube_face_cameras(np.array([0.0, 0.0, 0.0]), 32, near=0.05, far=45.0))
    view_rot, view_t, intr, nearfar, _, w, h = args
    cams, _ = rz.camera_rows(view_rot, view_t, intr, nearfar, w, h)  # the cull's camera rows
    _, centres, radii, smax = _blocks(g, starts)
    masks = rz._block_cameras(cams, w, h, 0.0, centres, radii, smax)
    vis = np.empty(g.count, np.int64)
    none = np.zeros(0, np.int64)
    rz._cull(0, g.count, g.positions, g.scales, g.opacities, np.zeros(0, bool), none, cams, w, h, 0.0, none, none,
             vis)
    every = (1 << 6) - 1
    left_out = 0
    for b in range(len(starts) - 1):
        seen = np.bitwise_or.reduce(vis[starts[b]:starts[b + 1]])
        assert seen & ~masks[b] == 0, b  # no Gaussian of the block passes a camera left out
        left_out += bin(every & ~masks[b]).count("1")
    assert masks[6] == every  # a NaN position: nothing left out (a NaN scale leaves the depth tests: above)
    assert np.isnan(smax[5]) and masks[5] != 0
    far = [b for b in range(len(starts) - 1) if np.linalg.norm(centres[b]) > 15.0 and b not in (5, 6)]
    assert far and all(bin(masks[b]).count("1") <= 3 for b in far)  # a far brick lies in a few faces
    assert left_out > len(starts)  # more than one camera per block on average


def test_a_tilted_camera_with_blocks_is_the_plain_render():
    g, starts = _bricks(5)
    ang = 0.4
    rot = np.array([[np.cos(ang), 0.0, np.sin(ang)], [0.0, 1.0, 0.0], [-np.sin(ang), 0.0, np.cos(ang)]])
    cam = Camera(np.array([0.3, -0.2, 6.0]), rot, 70.0, 60.0, 40.0, 30.0, 80, 64, 0.1, 30.0)
    args = _camera_args([cam])
    plain = _render(g, args, dilation=0.3)
    skip = _render(g, args, dilation=0.3, blocks=_blocks(g, starts))
    assert _same_bits(plain, skip) and plain[3] == skip[3] and plain[3]["entries"] > 1000


def test_block_scale_bound_is_the_largest_absolute_scale():
    rng = np.random.default_rng(4)
    s = rng.normal(0.0, 0.1, (1000, 3)).astype(np.float32)
    s[500, 1] = np.nan
    s[498, 2] = -np.inf
    s[501, 0] = np.inf  # (the NaN's block: still NaN)
    starts = np.array([0, 10, 10, 499, 700, 1000], np.int64)
    got = block_scale_bound(s, starts)
    assert got[1] == 0.0 and np.isnan(got[3])  # an empty block, the block with the NaN
    assert got[2] == np.inf  # an infinite scale: no finite bound
    for b in (0, 4):
        assert got[b] == np.abs(s[starts[b]:starts[b + 1]]).astype(np.float64).max()


def test_point_blocks_cull_bounds():
    g, starts = _bricks(6)
    blocks = PointBlocks(starts)
    got = blocks.cull_bounds(g.positions, g.scales)
    want = _blocks(g, starts)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert np.array_equal(got[2], want[2]) and np.array_equal(got[3], want[3], equal_nan=True)
    assert blocks.cull_bounds(g.positions[:100], g.scales[:100]) is None  # fewer rows than the blocks


def test_bad_blocks_are_rejected():
    g, starts = _bricks(7)
    args = _camera_args(cube_face_cameras(np.zeros(3), 16))
    starts, centres, radii, smax = _blocks(g, starts)
    for bad in ((starts + 1, centres, radii, smax), (starts, centres[:-1], radii, smax),
                (starts[::-1].copy(), centres, radii, smax), (np.append(starts, g.count + 5), centres, radii, smax)):
        with pytest.raises(ValueError, match="blocks"):
            _render(g, args, blocks=bad)
