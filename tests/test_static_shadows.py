"""The static scene's shot-long DGSM (usd_gs.shadows.static_scene) against the exact transmittance."""

from __future__ import annotations

import numpy as np
import pytest
from dgsm_testutil import random_rotations

from usd_gs.gaussians import GaussianSet
from usd_gs.point_blocks import PointBlocks
from usd_gs.shadows.dgsm import DGSMConfig, exact_transmittance
from usd_gs.shadows.static_scene import StaticSceneAtlas

LIGHT = np.array([0.0, 2.6, 0.0])


def _scene(rng) -> GaussianSet:
    """A table top of flat Gaussians at 0.8 m and a few blobs, lit from above."""
    n_top, n_blob = 1500, 60
    top = np.stack([rng.uniform(-0.5, 0.5, n_top), np.full(n_top, 0.8), rng.uniform(-0.4, 0.4, n_top)], 1)
    blobs = rng.normal([0.6, 1.2, 0.0], 0.15, size=(n_blob, 3))
    pos = np.concatenate([top, blobs])
    q = np.concatenate([np.tile([1.0, 0.0, 0.0, 0.0], (n_top, 1)), random_rotations(rng, n_blob)])
    s = np.concatenate([np.tile([0.02, 0.004, 0.02], (n_top, 1)), np.exp(rng.uniform(-4, -2.5, (n_blob, 3)))])
    a = np.concatenate([np.full(n_top, 0.6), rng.uniform(0.3, 0.9, n_blob)])
    return GaussianSet(pos, q, s, a, np.zeros((len(pos), 1, 3)), label="table")


def _walker(rng, x: float) -> np.ndarray:
    """Points of a receiver 'avatar' standing at ``x`` (m), partly under the table."""
    return np.stack([rng.uniform(x - 0.15, x + 0.15, 800), rng.uniform(0.0, 1.7, 800),
                     rng.uniform(-0.1, 0.1, 800)], 1)


def test_lazy_atlas_matches_exact_and_reuses_columns():
    rng = np.random.default_rng(3)
    scene = _scene(rng)
    cfg = DGSMConfig(sampling="center")
    cache = StaticSceneAtlas(scene, LIGHT, cfg)
    errs, computed = [], []
    for x in (0.0, 0.05, 0.1, 0.1):  # a receiver moving under the table edge, then standing
        pts = _walker(np.random.default_rng(int(x * 100)), x)
        got = cache.transmittance(pts)
        ref = exact_transmittance(scene, pts, LIGHT, cfg)
        assert np.all(np.isfinite(got)) and np.all((got >= 0) & (got <= 1))
        errs.append(np.abs(got - ref))
        computed.append(cache.computed_pixels)
        assert (ref < 0.5).mean() > 0.2 and (ref > 0.95).mean() > 0.2  # both shadow and light
    err = np.concatenate(errs)
    assert err.mean() < 2e-3 and err.max() < 0.05
    # columns are computed once: the same points again add none, a small move adds a few
    assert computed[3] == computed[2]
    assert computed[0] < computed[1] < computed[0] * 2


def test_receivers_beyond_the_scene_read_the_full_ray():
    rng = np.random.default_rng(4)
    scene = _scene(rng)
    cfg = DGSMConfig(sampling="center")
    cache = StaticSceneAtlas(scene, LIGHT, cfg)
    far = np.array([[0.0, -3.0, 0.0], [0.1, -5.0, 0.05], [3.0, -2.0, 0.0]])  # past t_max below the table
    np.testing.assert_allclose(cache.transmittance(far), exact_transmittance(scene, far, LIGHT, cfg), atol=5e-3)
    assert cache.transmittance(far)[0] < 0.5


def test_empty_scene_gives_ones():
    cfg = DGSMConfig()
    cache = StaticSceneAtlas(GaussianSet.empty(), LIGHT, cfg)
    np.testing.assert_array_equal(cache.transmittance(np.zeros((4, 3))), np.ones(4))


def test_bounded_atlas_packs_only_what_the_receivers_reach_and_gives_the_same_bits():
    """Occluders far from every ray between the light and the receivers are left out of the
    packing (and packed again when the receivers walk away): the lookups are bit for bit those
    of the atlas of every occluder."""
    rng = np.random.default_rng(5)
    near = _scene(rng)
    far = _scene(np.random.default_rng(6))
    far.positions[:, 0] += 30.0  # a second table 30 m away, under no ray to the walker
    scene = GaussianSet.concatenate([near, far], label="two tables")
    cfg = DGSMConfig(sampling="center")
    full = StaticSceneAtlas(scene, LIGHT, cfg, bounded=False)
    bounded = StaticSceneAtlas(scene, LIGHT, cfg)
    # the same with the capsule test decided table by table (usd_gs.point_blocks)
    blocks = PointBlocks.of_ranges({"/near": (0, near.count), "/far": (near.count, scene.count)})
    by_block = StaticSceneAtlas(scene, LIGHT, cfg, blocks=blocks)
    for x in (0.0, 0.1, 4.0, 29.5):  # the last two leave the reach: two more packings
        pts = _walker(np.random.default_rng(int(x * 10)), x)
        a, b, c = full.transmittance(pts), bounded.transmittance(pts), by_block.transmittance(pts)
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64)), x
        assert np.array_equal(a.view(np.uint64), c.view(np.uint64)) and by_block.kept == bounded.kept, x
        if x == 0.0:
            assert (a < 0.5).mean() > 0.2  # under the near table: in its shadow
        if x == 0.1:
            assert bounded.kept == near.count and bounded.builds == 1  # the far table left out
    assert bounded.builds == 3 and bounded.kept == scene.count and by_block.builds == 3


def test_block_extents_of_a_mask_are_the_subsets_extent_bit_for_bit():
    import pytest

    from usd_gs.errors import GaussianDataError
    from usd_gs.shadows.static_scene import BlockExtents
    from usd_gs.synthetic import random_gaussians

    g = random_gaussians(150_000, 0, seed=3)  # three chunks of 65,536 rows
    g.positions[:, 0] *= 20.0
    ext = BlockExtents(g, 3.0)
    rng = np.random.default_rng(1)
    faces = np.concatenate([np.argmin(g.positions, axis=0), np.argmax(g.positions, axis=0)])
    masks = [None, rng.random(g.count) > 0.3, np.ones(g.count, bool)]
    masks.append(np.ones(g.count, bool))
    masks[-1][faces] = False  # the Gaussians nearest the box's faces left out
    masks.append(np.zeros(g.count, bool))
    masks[-1][70_000:80_000] = True  # whole chunks left out
    for keep in masks:
        want = g.extent(3.0) if keep is None else g.subset(keep).extent(3.0)
        assert np.array_equal(ext.of(keep).view(np.uint32), want.view(np.uint32))
    g.scales[100_000] = 3e38
    keep = rng.random(g.count) > 0.5
    keep[100_000] = True
    with pytest.raises(GaussianDataError, match="element"):
        BlockExtents(g, 3.0).of(keep)


def test_atlas_of_a_masked_block_is_the_atlas_of_the_subset():
    from usd_gs.shadows.static_scene import BlockExtents

    rng = np.random.default_rng(7)
    scene = _scene(rng)
    keep = rng.random(scene.count) > 0.2
    cfg = DGSMConfig(sampling="center")
    pts = _walker(np.random.default_rng(2), 0.05)
    a = StaticSceneAtlas(scene.subset(keep), LIGHT, cfg).transmittance(pts)
    b = StaticSceneAtlas(scene, LIGHT, cfg, keep=keep, extents=BlockExtents(scene, cfg.k_sigma)).transmittance(pts)
    assert np.array_equal(a.view(np.uint64), b.view(np.uint64)) and (a < 0.5).mean() > 0.1


def test_block_extents_of_given_blocks_are_the_subsets_extent_bit_for_bit():
    """Blocks given with their boxes (the prims' boxes, ``prim_boxes``) instead of fixed chunks:
    the same bits for every mask, an empty prim among them."""
    from numba_kernels.extent import block_extents
    from usd_gs.shadows.shot import Receivers, prim_boxes, prim_spheres
    from usd_gs.shadows.static_scene import BlockExtents
    from usd_gs.synthetic import random_gaussians

    sizes = [5000, 0, 70_000, 300, 24_700]
    parts = [(f"/p{i}", random_gaussians(n, 0, seed=10 + i)) for i, n in enumerate(sizes)]
    for k, (_, g) in enumerate(parts):
        g.positions[:, k % 3] += 10.0 * k
    recv = Receivers.build(parts)
    g = recv.gaussians
    starts, boxes, ok = prim_boxes(recv, 3.0)
    assert starts.tolist() == [0, 5000, 5000, 75_000, 75_300, 100_000] and not ok[1] and ok[[0, 2, 3, 4]].all()
    want_boxes, _ = block_extents(g.positions, g.orientations, g.scales, starts, 3.0)
    assert np.array_equal(boxes[ok].view(np.uint64), want_boxes[ok].view(np.uint64))
    given, chunks = BlockExtents(g, 3.0, starts, boxes, ok), BlockExtents(g, 3.0)
    rng = np.random.default_rng(8)
    masks = [None, rng.random(g.count) > 0.4, np.zeros(g.count, bool), np.ones(g.count, bool)]
    masks.append(np.zeros(g.count, bool))
    masks[-1][5000:75_000] = True  # one whole prim
    masks.append(masks[-1].copy())
    masks[-1][75_010] = True  # and one row of another
    for keep in masks:
        a, b = given.of(keep), chunks.of(keep)
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
        if keep is not None and keep.any():
            assert np.array_equal(a.view(np.uint32), g.subset(keep).extent(3.0).view(np.uint32))
    # the spheres from those boxes are the spheres computed on their own, each prim's own extent
    spheres = prim_spheres(recv, 3.0, (starts, boxes, ok))
    assert set(spheres) == {"/p0", "/p2", "/p3", "/p4"}
    for path, (a, b) in recv.ranges.items():
        if b > a:
            ext = g.subset(slice(a, b)).extent(3.0).astype(np.float64)
            np.testing.assert_array_equal(spheres[path][0], 0.5 * (ext[0] + ext[1]))
            assert spheres[path][1] == 0.5 * float(np.linalg.norm(ext[1] - ext[0]))
    with pytest.raises(ValueError, match="boxes"):
        BlockExtents(g, 3.0, starts)


def test_occluder_subset_keeps_the_geometry_without_the_colours():
    from usd_gs.synthetic import random_gaussians

    g = random_gaussians(500, 3, seed=2)
    idx = np.flatnonzero(np.random.default_rng(0).random(500) > 0.5)
    sub, occ = g.subset(idx), g.occluder_subset(idx)
    for name in ("positions", "orientations", "scales", "opacities"):
        assert np.array_equal(getattr(sub, name), getattr(occ, name)) and getattr(occ, name).flags.c_contiguous
    assert occ.sh.shape == (idx.size, 1, 3) and not occ.sh.any() and occ.label == g.label and not occ.extras


def test_receivers_near_the_light_get_bins_over_the_serve_radius_only():
    """A scene with a far part (a second table 40 m away): the receivers within ``serve_radius``
    of the light are looked up in bins spanning that far only (within the bounds of
    ``test_lazy_atlas_matches_exact_and_reuses_columns`` of the exact transmittance; the bins over
    the whole range are refined exactly more often), the receivers beyond it in the atlas of the whole range
    (bit for bit), in one call or apart; a scene within the radius gets the single atlas's bits."""
    from numba_kernels import dgsm_build

    near = _scene(np.random.default_rng(11))
    far = _scene(np.random.default_rng(12))
    far.positions[:, 0] += 40.0
    scene = GaussianSet.concatenate([near, far], label="two tables")
    cfg = DGSMConfig(sampling="center")
    whole = StaticSceneAtlas(scene, LIGHT, cfg)
    served = StaticSceneAtlas(scene, LIGHT, cfg, serve_radius=15.0)
    assert served.serve == 15.0 and whole.serve is None
    assert served.t_max == dgsm_build.t_max_for(15.0, served.K) and whole.t_max > 40.0
    walker = _walker(np.random.default_rng(13), 0.05)  # under the near table, 1-3 m from the light
    # beyond the far table as seen from the light (its shadow) and beside it
    rng = np.random.default_rng(14)
    top = np.stack([rng.uniform(39.6, 40.4, 800), np.full(800, 0.8), rng.uniform(-0.3, 0.3, 800)], 1)
    beyond = LIGHT + rng.uniform(1.02, 1.08, (800, 1)) * (top - LIGHT)
    beyond[400:, 2] += 1.0
    ref_near = exact_transmittance(scene, walker, LIGHT, cfg)
    got_near = served.transmittance(walker)
    err = np.abs(got_near - ref_near)
    assert (ref_near < 0.5).mean() > 0.2 and err.max() < 0.05 and err.mean() < 2e-3
    assert served._beyond is None  # nothing asked beyond the radius yet
    got_beyond = served.transmittance(beyond)
    want = whole.transmittance(beyond)
    assert np.array_equal(got_beyond.view(np.uint64), want.view(np.uint64)) and 0.2 < (want < 0.5).mean() < 0.8
    both = served.transmittance(np.concatenate([beyond[:300], walker, beyond[300:]]))
    assert np.array_equal(both.view(np.uint64), np.concatenate([got_beyond[:300], got_near, got_beyond[300:]])
                          .view(np.uint64))
    # nothing beyond the radius: the single atlas
    alone, plain = StaticSceneAtlas(near, LIGHT, cfg, serve_radius=15.0), StaticSceneAtlas(near, LIGHT, cfg)
    assert alone.serve is None and alone.t_max == plain.t_max
    assert np.array_equal(alone.transmittance(walker).view(np.uint64), plain.transmittance(walker).view(np.uint64))
