"""Spatial bricks: a partition of the set, bounded sizes, spatial compactness, CLI import."""

import numpy as np
import pytest

from usd_gs.cli import main
from usd_gs.errors import UserError
from usd_gs.synthetic import random_gaussians
from usd_gs.usd.bricks import brick_indices


def test_bricks_partition_with_bounded_sizes():
    p = np.random.default_rng(0).uniform(-5, 5, size=(10_000, 3))
    bricks = brick_indices(p, 700)
    allidx = np.concatenate(bricks)
    assert np.array_equal(np.sort(allidx), np.arange(10_000))
    sizes = np.array([b.size for b in bricks])
    assert sizes.max() <= 700 and sizes.min() >= 350
    # compact: median cuts tile the box, so the bricks' boxes do not overlap (their volumes add up
    # to at most the whole box) and no brick spans more than half of the 10 m cube
    volumes = np.array([np.prod(np.ptp(p[b], axis=0)) for b in bricks])
    assert volumes.sum() <= np.prod(np.ptp(p, axis=0)) * (1 + 1e-9)
    assert max(np.ptp(p[b], axis=0).max() for b in bricks) <= 5.05
    assert all(np.array_equal(a, b) for a, b in zip(bricks, brick_indices(p, 700), strict=True))


def test_small_set_is_one_brick_and_bad_size():
    p = np.zeros((5, 3))
    assert [b.tolist() for b in brick_indices(p, 10)] == [[0, 1, 2, 3, 4]]
    with pytest.raises(UserError, match="brick size must be >= 1"):
        brick_indices(p, 0)


def test_import_brick_size(tmp_path, capsys):
    from pxr import Usd

    from usd_gs.gaussians import GaussianSet
    from usd_gs.io.ply import write_ply
    from usd_gs.usd.gaussian_prim import read_gaussian_prim

    g = random_gaussians(3000, 1, seed=3)
    write_ply(tmp_path / "in.ply", g)
    assert main(["import", str(tmp_path / "in.ply"), "-o", str(tmp_path / "b.usdc"), "--prim", "/Scene",
                 "--brick-size", "1000", "--role", "scene"]) == 0
    assert "in 4 bricks" in capsys.readouterr().out
    stage = Usd.Stage.Open(str(tmp_path / "b.usdc"))
    kids = stage.GetPrimAtPath("/Scene").GetChildren()
    assert [k.GetName() for k in kids] == ["Brick_0000", "Brick_0001", "Brick_0002", "Brick_0003"]
    back = GaussianSet.concatenate([read_gaussian_prim(k) for k in kids])
    order = np.concatenate(brick_indices(g.positions, 1000))
    np.testing.assert_array_equal(back.positions, g.positions[order])
    np.testing.assert_array_equal(back.sh, g.sh[order])
    assert all(k.GetAttribute("usdgs:role").Get() == "scene" for k in kids)
