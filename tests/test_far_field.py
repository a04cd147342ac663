"""usd_gs.relight.far_field: the cached far layer against the full probe render."""

from __future__ import annotations

import numpy as np
import pytest

from usd_gs.gaussians import GaussianSet
from usd_gs.relight.far_field import FarField, FarLayers, composite_faces
from usd_gs.relight.probe import fit_probe, render_probe_faces
from usd_gs.synthetic import random_gaussians

SIZE = 16


def _shell(n: int, r0: float, r1: float, seed: int) -> GaussianSet:
    """``n`` Gaussians between ``r0`` and ``r1`` of the origin, visible sizes, degree 1."""
    g = random_gaussians(n, 1, seed=seed)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    g.positions[:] = (d * rng.uniform(r0, r1, (n, 1))).astype(np.float32)
    g.scales[:] = np.float32(0.02 * r1)
    g.opacities[:] = np.float32(0.6)
    return g


def _scene():
    """Static: a near shell (1-3 m) and a far one (30-40 m); dynamic: a small cluster at the end."""
    near, far = _shell(3000, 1.0, 3.0, 1), _shell(6000, 30.0, 40.0, 2)
    moving = _shell(400, 0.5, 0.8, 3)
    everything = GaussianSet.concatenate([near, far, moving])
    return everything, near.count + far.count


def test_composite_of_depth_separated_layers_is_the_full_render():
    everything, s = _scene()
    centre = np.zeros(3)
    far = np.zeros(everything.count, bool)
    far[3000:s] = True
    full = render_probe_faces(everything, centre, SIZE)
    out = composite_faces(render_probe_faces(everything, centre, SIZE, ~far), render_probe_faces(everything, centre,
                                                                                                  SIZE, far))
    for a, b in zip(out[:2], full[:2], strict=True):
        assert np.abs(a - b).max() < 2e-5
    seen = full[1] > 0.5
    assert np.abs(out[2] - full[2])[seen].max() < 1e-3 * full[2][seen].max()  # alpha-weighted depth


def test_nothing_beyond_the_radius_is_the_plain_render_bit_for_bit():
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    mask[s:] = False
    ff = FarField(100.0, 0.05, s)
    got = ff.render(everything, np.array([0.1, 0.2, 0.0]), SIZE, mask)
    ref = render_probe_faces(everything, np.array([0.1, 0.2, 0.0]), SIZE, mask)
    assert ff.renders == 0 and all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True))


def test_far_layer_is_reused_within_a_cell_and_matches_the_full_render():
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    ff = FarField(10.0, 0.05, s)  # anchors on a 0.5 m grid
    errors = []
    for k, c in enumerate([(0.0, 0.0, 0.0), (0.1, -0.2, 0.05), (0.2, 0.2, -0.2), (0.9, 0.0, 0.0)]):
        centre = np.array(c)
        got = ff.render(everything, centre, SIZE, mask)
        assert ff.renders == (1 if k < 3 else 2)  # the last centre is in another cell
        ref = render_probe_faces(everything, centre, SIZE, mask)
        a, b = (fit_probe(x[0], degree=3, alpha=x[1]).rh() for x in (got, ref))
        errors.append(np.linalg.norm(a - b) / np.linalg.norm(b))
    # directions of the far shell off by <= 0.35 m / 30 m: the probe within 1 % of the full render's
    assert max(errors) < 0.01 and errors[0] < 1e-5
    assert np.array_equal(ff.anchor((0.1, -0.2, 0.05)), ff.anchor((0.0, 0.0, 0.0)))


def test_a_changed_mask_renders_a_new_far_layer():
    everything, s = _scene()
    ff = FarField(10.0, 0.05, s)
    mask = np.ones(everything.count, bool)
    ff.render(everything, np.zeros(3), SIZE, mask)
    mask[5000:5100] = False  # e.g. another light set's emitter Gaussians
    got = ff.render(everything, np.zeros(3), SIZE, mask)
    ref = render_probe_faces(everything, np.zeros(3), SIZE, mask)
    assert ff.renders == 2 and np.abs(got[0] - ref[0]).max() < 2e-5


def test_grid_level_follows_the_clearance_around_the_anchor():
    """Level L (pitch x 2^L) only where no static Gaussian lies between radius and radius x 2^L:
    the far shell at 30-40 m allows level 1 at radius 10 (20 m clear) and level 2 at radius 5,
    a shell at 12-14 m keeps level 0 at radius 10."""
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    for radius, level in ((10.0, 1), (5.0, 2), (20.0, 0)):
        ff = FarField(radius, 0.05, s)
        ff.render(everything, np.zeros(3), SIZE, mask)
        assert ff.level == level and ff.renders == 1
    close = GaussianSet.concatenate([_shell(3000, 1.0, 3.0, 1), _shell(3000, 12.0, 14.0, 4), _shell(400, 0.5, 0.8, 3)])
    ff = FarField(10.0, 0.05, 6000)
    ff.render(close, np.zeros(3), SIZE, np.ones(close.count, bool))
    assert ff.level == 0 and ff.renders == 1


def test_coarse_level_worst_corner_of_its_cell_matches_the_full_render():
    """At level 2 (radius 5: 1 m cells), a probe at a cell corner (0.87 m from the anchor) sees the
    far shell (>= 30 m) off by under the level-0 bound: the probe within 1 % of the full render's."""
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    ff = FarField(5.0, 0.05, s)
    centre = np.array([0.49, 0.49, -0.49])
    got = ff.render(everything, centre, SIZE, mask)
    assert ff.level == 2 and np.array_equal(ff.anchor(centre, 2), np.zeros(3))
    ref = render_probe_faces(everything, centre, SIZE, mask)
    a, b = (fit_probe(x[0], degree=3, alpha=x[1]).rh() for x in (got, ref))
    assert np.linalg.norm(a - b) / np.linalg.norm(b) < 0.01


def test_prims_in_one_cell_share_a_far_layer():
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    shared = FarLayers(4)
    first, second, alone = FarField(10.0, 0.05, s, shared), FarField(10.0, 0.05, s, shared), FarField(10.0, 0.05, s)
    first.render(everything, np.array([0.1, 0.0, 0.0]), SIZE, mask)
    got = second.render(everything, np.array([-0.2, 0.1, 0.0]), SIZE, mask)
    ref = alone.render(everything, np.array([-0.2, 0.1, 0.0]), SIZE, mask)
    assert (first.renders, second.renders, alone.renders) == (1, 0, 1)
    assert all(np.array_equal(x, y) for x, y in zip(got, ref, strict=True))


def test_far_layer_from_a_shot_cache_file_is_the_rendered_one(tmp_path):
    """A farm chunk's far layer goes to the shot cache file; a later chunk (new stores, the file
    read again) composites the same layer without rendering it: the same faces bit for bit.
    Layers with nothing far are not stored."""
    from usd_gs.pipeline.shot_cache import ShotCache

    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    path = tmp_path / "shot_cache.npz"
    cache = ShotCache(path, "run")
    first = FarField(10.0, 0.05, s, FarLayers(2, backing=cache))
    ref = first.render(everything, np.array([0.1, 0.0, 0.0]), SIZE, mask)
    FarField(100.0, 0.05, s, FarLayers(2, backing=cache)).render(everything, np.zeros(3), SIZE, mask)  # nothing far
    assert first.renders == 1 and cache.computed == 1 and cache.save()
    again = ShotCache(path, "run")
    later = FarField(10.0, 0.05, s, FarLayers(2, backing=again))
    got = later.render(everything, np.array([0.1, 0.0, 0.0]), SIZE, mask)
    assert later.renders == 0 and again.loaded == 1
    assert all(np.array_equal(x, y) for x, y in zip(got, ref, strict=True))
    other = np.ones(everything.count, bool)
    other[:10] = False  # another mask (other emitters): another layer, rendered
    fresh = FarField(10.0, 0.05, s, FarLayers(2, backing=again))
    fresh.render(everything, np.array([0.1, 0.0, 0.0]), SIZE, other)
    assert fresh.renders == 1


@pytest.mark.parametrize("radius, tolerance", [(0.0, 0.05), (10.0, 0.0), (10.0, 0.6)])
def test_bad_parameters(radius, tolerance):
    with pytest.raises(ValueError):
        FarField(radius, tolerance, 10)


def _three_probes():
    """The test scene, a mask without the moving cluster and three probe centres in three cells."""
    everything, s = _scene()
    mask = np.ones(everything.count, bool)
    mask[s:] = False
    centres = [np.array([0.1, 0.0, 0.0]), np.array([1.2, 0.3, 0.0]), np.array([-0.9, 0.0, 1.4])]
    return everything, s, mask, centres


def _spy_cubes(monkeypatch):
    """Record the centres of each batched far-layer pass (``render_probe_cubes`` in far_field)."""
    import usd_gs.relight.far_field as ff

    calls = []
    real = ff.render_probe_cubes

    def spy(everything, centres, *args, **kwargs):
        calls.append(len(centres))
        return real(everything, centres, *args, **kwargs)

    monkeypatch.setattr(ff, "render_probe_cubes", spy)
    return calls


def test_a_batch_renders_the_missing_far_layers_in_one_pass_bit_for_bit(monkeypatch):
    """Three probes in three cells of one shared store: ``FarLayers.batch`` plans their three far
    layers, one rasteriser pass draws them (from three anchors), and each probe render is bit for
    bit the one of a store that renders its own layer; each prim counts its layer, and the next
    renders find them kept (no batch)."""
    everything, s, mask, centres = _three_probes()
    refs = [FarField(10.0, 0.05, s).render(everything, c, SIZE, mask) for c in centres]
    calls = _spy_cubes(monkeypatch)
    shared = FarLayers(6)
    fields = [FarField(10.0, 0.05, s, shared) for _ in centres]
    batch = shared.batch([(f, everything, c, SIZE, mask, 0.0, 1) for f, c in zip(fields, centres, strict=True)])
    assert batch is not None and len(batch.plans) == 3 and calls == []
    batch.run()
    assert calls == [3] and [f.renders for f in fields] == [1, 1, 1]
    # the three balls hold the same rows: their split is made once (FarField.split's ``seen``)
    near = [shared.get(key)[0] for key in batch.plans]
    assert near[0].size == 3000 and near[1] is near[0] and near[2] is near[0]
    for f, c, ref in zip(fields, centres, refs, strict=True):
        got = f.render(everything, c, SIZE, mask)
        assert all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True))
    assert calls == [3] and [f.renders for f in fields] == [1, 1, 1]
    assert shared.batch([(f, everything, c, SIZE, mask, 0.0, 1) for f, c in zip(fields, centres, strict=True)]) \
        is None  # (every layer kept)


def test_a_probe_before_its_batch_runs_it_and_no_thread_waits_on_a_task_not_running(monkeypatch):
    """The probe renders may start before the batch's task (one thread, or two threads busy with
    them): the first that needs a layer runs the batch itself, the others wait for that thread or
    find the layers done, the batch's task then does nothing; two threads that take the three
    probes before the batch finish (no deadlock) with the same bits."""
    from concurrent.futures import ThreadPoolExecutor

    everything, s, mask, centres = _three_probes()
    refs = [FarField(10.0, 0.05, s).render(everything, c, SIZE, mask) for c in centres]
    calls = _spy_cubes(monkeypatch)
    for threads in (1, 2):
        calls.clear()
        shared = FarLayers(6)
        fields = [FarField(10.0, 0.05, s, shared) for _ in centres]
        batch = shared.batch([(f, everything, c, SIZE, mask, 0.0, 1) for f, c in zip(fields, centres, strict=True)])
        with ThreadPoolExecutor(threads) as pool:
            probes = [pool.submit(f.render, everything, c, SIZE, mask) for f, c in zip(fields, centres, strict=True)]
            last = pool.submit(batch.run)
            got = [p.result(timeout=120) for p in probes]
            last.result(timeout=120)
        assert calls == [3] and [f.renders for f in fields] == [1, 1, 1]
        for g, ref in zip(got, refs, strict=True):
            assert all(np.array_equal(a, b) for a, b in zip(g, ref, strict=True))


def test_no_batch_for_one_missing_layer_and_a_failed_batch(monkeypatch):
    """A store that keeps one of two probes' layers plans no batch (one render is no pass to share).
    An error while a batch renders is raised to its task and to every later caller of its ``run``
    (a probe render waiting on it); a probe render that asks after the failure renders its own
    layer (the same bits as ever), the batch no longer pending."""
    import usd_gs.relight.far_field as ff

    everything, s, mask, centres = _three_probes()
    ref = FarField(10.0, 0.05, s).render(everything, centres[1], SIZE, mask)
    shared = FarLayers(6)
    fields = [FarField(10.0, 0.05, s, shared) for _ in centres]
    fields[0].render(everything, centres[0], SIZE, mask)
    assert shared.batch([(f, everything, c, SIZE, mask, 0.0, 1) for f, c in zip(fields[:2], centres[:2],
                                                                               strict=True)]) is None
    batch = shared.batch([(f, everything, c, SIZE, mask, 0.0, 1) for f, c in zip(fields, centres, strict=True)])
    assert batch is not None and len(batch.plans) == 2

    def broken(*args, **kwargs):
        raise MemoryError("far layers")

    monkeypatch.setattr(ff, "render_probe_cubes", broken)
    for _ in range(2):
        with pytest.raises(MemoryError, match="far layers"):
            batch.run()
    key = fields[1].key(everything, centres[1], SIZE, mask)[2]
    assert shared.due(key) is None
    got = fields[1].render(everything, centres[1], SIZE, mask)
    assert fields[1].renders == 1 and all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True))


def test_probe_cubes_drawn_together_are_each_cube_alone_bit_for_bit():
    """``render_probe_cubes``: several cubes in one rasteriser pass (more than ``CUBES_PER_PASS``:
    two passes), supersampled or not, each bit for bit ``render_probe_faces`` at its centre."""
    from usd_gs.relight.probe import render_probe_cubes
    from usd_gs.render.rasterize import CUBES_PER_PASS

    everything, s = _scene()
    rng = np.random.default_rng(3)
    centres = rng.uniform(-2.0, 2.0, (CUBES_PER_PASS + 1, 3))
    for size, supersample in ((4, 1), (6, 2)):
        together = render_probe_cubes(everything, centres, size, None, 0.0, supersample, order=np.arange(s))
        assert len(together) == len(centres)
        for c, got in zip(centres, together, strict=True):
            alone = render_probe_faces(everything, c, size, None, 0.0, supersample, order=np.arange(s))
            assert all(np.array_equal(a, b) for a, b in zip(got, alone, strict=True))
            assert got[1].max() > 0.5  # (something drawn)


def test_a_split_is_reused_only_for_the_same_rows_within_and_drawn():
    """``FarField.split(..., seen)`` returns an earlier split's arrays only where the ball holds the
    same static rows and the same rows are drawn; otherwise it makes its own, equal to a split
    without ``seen``."""
    everything, s, mask, _ = _three_probes()
    field = FarField(10.0, 0.05, s, FarLayers(6))
    seen: list = []
    a = field.split(everything, np.zeros(3), mask, seen)
    b = field.split(everything, np.array([0.3, 0.0, 0.0]), mask, seen)
    assert b[0] is a[0] and b[1] is a[1]
    fewer = mask.copy()
    fewer[7] = False
    c = field.split(everything, np.array([0.3, 0.0, 0.0]), fewer, seen)
    own = field.split(everything, np.array([0.3, 0.0, 0.0]), fewer)
    assert c[1] is not a[1] and np.array_equal(c[0], own[0]) and np.array_equal(c[1], own[1])
    assert 7 not in c[0] and 7 not in c[1] and len(seen) == 2
    moved = np.array([60.0, 0.0, 0.0])  # another ball: other rows within
    d = field.split(everything, moved, mask, seen)
    ref = field.split(everything, moved, mask)
    assert d[1] is not a[1] and np.array_equal(d[1], ref[1])
    assert (d[0] is None) == (ref[0] is None) and (d[0] is None or np.array_equal(d[0], ref[0]))
