"""OutputAuthor.receivers (many prims at once) writes what OutputAuthor.receiver writes prim by
prim: the same time samples, values and return flags, frame after frame."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, Usd

from usd_gs.errors import UserError
from usd_gs.usd.output_author import SH_TOLERANCE, OutputAuthor, sh_display_change, sh_display_changes


def _layer_content(stage) -> dict:
    layer = stage.GetRootLayer()
    out = {}

    def visit(path):
        spec = layer.GetObjectAtPath(path)
        for key in spec.ListInfoKeys():
            if key != "timeSamples":
                out[(str(path), key)] = repr(spec.GetInfo(key))
        if path.IsPropertyPath():
            for t in layer.ListTimeSamplesForPath(path):
                v = np.asarray(layer.QueryTimeSample(path, t))
                out[(str(path), t)] = (v.dtype.str, v.shape, v.tobytes())

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def _frames(rng, counts, k, n_frames):
    """Per frame (transmittance, sh_out, sh_in) over all prims: some prims unaffected, some barely
    changed (below the tolerance), some shadowed, some back to unaffected, values repeating."""
    m = int(sum(counts))
    sh_in = rng.normal(scale=0.4, size=(m, k, 3)).astype(np.float32)
    sh_in[:5] = -0.0  # signed zeros: half values compared bit for bit
    owner = np.repeat(np.arange(len(counts)), counts)
    out = []
    for f in range(n_frames):
        t = np.ones(m, np.float32)
        mode = (np.arange(len(counts)) + f) % 4  # 0 unaffected, 1 tiny change, 2 shadowed, 3 same as before
        tiny = mode[owner] == 1
        shadow = (mode[owner] == 2) | ((mode[owner] == 3) & (f % 2 == 0))
        t[shadow] = rng.uniform(0.1, 0.9, shadow.sum()).astype(np.float32)
        sh_out = sh_in.copy()
        sh_out[tiny] += np.float32(1e-4)
        sh_out[shadow] *= t[shadow][:, None, None]
        out.append((t, sh_out, sh_in))
    return out


@pytest.mark.parametrize("precision,tol,aovs", [("half", SH_TOLERANCE, ()), ("float", 0.0, ("transmittance",)),
                                                ("half", 0.0, ("transmittance",)), ("float", SH_TOLERANCE, ())])
@pytest.mark.parametrize("k", [1, 16])
def test_receivers_author_what_receiver_authors(precision, tol, aovs, k):
    rng = np.random.default_rng(7 + k)
    counts = np.array([3, 0, 5, 1, 4, 7, 2, 6])
    paths = [f"/W/B{i}" for i in range(len(counts))]
    offsets = np.concatenate([[0], np.cumsum(counts)])
    frames = [1, 2, 3, 5, 6, 7, 9]
    seq = _frames(rng, counts, k, len(frames))
    one, many = Usd.Stage.CreateInMemory(), Usd.Stage.CreateInMemory()
    a1 = OutputAuthor(one, frames, aovs, precision, tol)
    a2 = OutputAuthor(many, frames, aovs, precision, tol)
    for f, (t, sh_out, sh_in) in zip(frames, seq, strict=True):
        # a changing subset of prims each frame, as the main job passes the touched and unclean ones
        which = [i for i in range(len(paths)) if (i + f) % 3 or not a1.is_clean(paths[i])]
        flags1 = [a1.receiver(paths[i], f, t[offsets[i]:offsets[i + 1]], sh_out[offsets[i]:offsets[i + 1]],
                              sh_in[offsets[i]:offsets[i + 1]]) for i in which]
        rows = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in which])
        sub = np.concatenate([[0], np.cumsum(counts[which])])
        flags2 = a2.receivers(f, [paths[i] for i in which], sub, t[rows], sh_out[rows], sh_in[rows])
        assert flags2.tolist() == flags1, f"frame {f}"
        assert [a2.is_clean(p) for p in paths] == [a1.is_clean(p) for p in paths]
    assert a2.samples_written == a1.samples_written > 0
    assert _layer_content(many) == _layer_content(one)
    # prims without Gaussians only, and float64 SH (the row-by-row bit comparison does not apply)
    empty = np.zeros((0, k, 3), np.float32)
    assert a2.receivers(9, ["/W/B1"], [0, 0], np.ones(0, np.float32), empty, empty).tolist() == [False]
    t, sh_out, sh_in = seq[2]
    rows = np.arange(offsets[2], offsets[4])
    f = a1.receivers(9, paths[2:4], offsets[2:5] - offsets[2], t[rows], sh_out[rows].astype(np.float64), sh_in[rows])
    g = [a2.receiver(paths[i], 9, t[offsets[i]:offsets[i + 1]], sh_out[offsets[i]:offsets[i + 1]].astype(np.float64),
                     sh_in[offsets[i]:offsets[i + 1]]) for i in (2, 3)]
    assert f.tolist() == g
    assert _layer_content(many) == _layer_content(one)


def test_receivers_beyond_half_range_name_the_prim_and_element():
    author = OutputAuthor(Usd.Stage.CreateInMemory(), [1], (), "half", 0.0)
    sh = np.zeros((5, 1, 3), np.float32)
    sh_out = sh.copy()
    sh_out[3, 0, 1] = 7e4  # row 3: the second prim's element 1
    with pytest.raises(UserError, match=r"/B\.radiance:sphericalHarmonicsCoefficientsh\[1\]"):
        author.receivers(1, ["/A", "/B"], [0, 2, 5], np.ones(5, np.float32), sh_out, sh)


def test_display_changes_per_prim_equal_the_single_prim_bound():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(12, 9, 3)).astype(np.float32), rng.normal(size=(12, 9, 3)).astype(np.float32)
    offsets = np.array([0, 4, 4, 11, 12])
    got = sh_display_changes(a, b, offsets)
    want = [sh_display_change(a[i:j], b[i:j]) for i, j in zip(offsets[:-1], offsets[1:], strict=True)]
    assert got.tolist() == want and want[1] == 0.0 and min(want[0], want[2], want[3]) > 0.1


def test_receiver_keeps_the_unaffected_half_values_only_while_the_bits_are_the_same():
    stage = Usd.Stage.CreateInMemory()
    author = OutputAuthor(stage, [1, 2, 3], (), "half", 0.0)
    sh_in = np.full((4, 1, 3), 0.25, np.float32)
    t = np.ones(4, np.float32)
    assert author.receiver("/P", 1, t, sh_in * np.float32(0.5), sh_in)
    other = sh_in.copy()
    other[2, 0, 1] = 0.75  # another unaffected SH: the cached halves must not be used
    assert author.receiver("/P", 2, t, other, other)
    attr = stage.GetPrimAtPath("/P").GetAttribute("radiance:sphericalHarmonicsCoefficientsh")
    np.testing.assert_array_equal(np.asarray(attr.Get(2)), other.reshape(-1, 3).astype(np.float16))
    # the hold sample before a change is the unaffected SH of that frame, to the bit: -0.0, not the +0.0 before
    author = OutputAuthor(stage, [1, 2, 3], (), "half", 0.0)
    zeros = np.zeros((4, 1, 3), np.float32)
    assert not author.receiver("/Q", 1, t, zeros, zeros)
    assert not author.receiver("/Q", 2, t, -zeros, -zeros)
    assert author.receiver("/Q", 3, t, zeros + np.float32(0.5), -zeros)
    held = np.asarray(stage.GetPrimAtPath("/Q").GetAttribute("radiance:sphericalHarmonicsCoefficientsh").Get(2))
    assert (held == 0).all() and np.signbit(held).all()


@pytest.mark.parametrize("k", [1, 9])
def test_receivers_with_the_callers_half_values_author_the_same(k):
    """``sh_in_half`` (the main job keeps its static SH as float16 once per shot) changes nothing:
    the same flags, samples and layer as converting ``sh_in`` at every call."""
    rng = np.random.default_rng(11 + k)
    counts = np.array([4, 2, 0, 6, 3])
    paths = [f"/W/B{i}" for i in range(len(counts))]
    offsets = np.concatenate([[0], np.cumsum(counts)])
    frames = [1, 2, 4, 5, 6]
    seq = _frames(rng, counts, k, len(frames))
    plain, given = Usd.Stage.CreateInMemory(), Usd.Stage.CreateInMemory()
    a1 = OutputAuthor(plain, frames, (), "half", SH_TOLERANCE)
    a2 = OutputAuthor(given, frames, (), "half", SH_TOLERANCE)
    for f, (t, sh_out, sh_in) in zip(frames, seq, strict=True):
        which = list(range(len(paths))) if f % 2 else [0, 3, 4]  # every prim (the tracks keep views), or some
        rows = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in which])
        sub = np.concatenate([[0], np.cumsum(counts[which])])
        p = [paths[i] for i in which]
        flags1 = a1.receivers(f, p, sub, t[rows], sh_out[rows], sh_in[rows])
        flags2 = a2.receivers(f, p, sub, t[rows], sh_out[rows], sh_in[rows], sh_in[rows].astype(np.float16))
        assert flags2.tolist() == flags1.tolist(), f"frame {f}"
    assert a2.samples_written == a1.samples_written > 0
    assert _layer_content(given) == _layer_content(plain)


def test_segment_halves_convert_the_segments_asked_for_bit_for_bit():
    """SegmentHalves gives ``block[rows].astype(float16)`` bit for bit, segment by segment as asked
    (in any order, the same segment again); a value beyond the half range in a segment makes only
    a request that includes that segment (and every later one) return None."""
    from usd_gs.usd.output_author import SegmentHalves

    rng = np.random.default_rng(5)
    counts = np.array([3, 0, 5, 2, 4])
    offsets = np.concatenate([[0], np.cumsum(counts)])
    block = rng.normal(0.0, 3.0, (offsets[-1], 4, 3)).astype(np.float32)
    block[offsets[2] + 1, 2, 0] = 1e-6  # a half subnormal
    block[offsets[3], 0, 1] = 65504.0  # the largest half
    halves = SegmentHalves(block, offsets)

    def rows_of(segs):
        return np.concatenate([np.arange(offsets[s], offsets[s + 1]) for s in segs]).astype(np.int64)

    for segs in ([3], [0, 2], [0, 1, 2, 3], [4]):
        segs = np.array(segs)
        got = halves.rows(segs, rows_of(segs))
        assert got.dtype == np.float16
        assert np.array_equal(got.view(np.uint16), block[rows_of(segs)].astype(np.float16).view(np.uint16))
    every = halves.rows(np.arange(len(counts)), None)
    assert np.array_equal(every.view(np.uint16), block.astype(np.float16).view(np.uint16))

    block[offsets[4] + 1, 1, 2] = -70000.0  # beyond the half range, in the last segment
    fresh = SegmentHalves(block, offsets)
    first = fresh.rows(np.array([0, 2]), rows_of([0, 2]))
    assert np.array_equal(first.view(np.uint16), block[rows_of([0, 2])].astype(np.float16).view(np.uint16))
    assert fresh.rows(np.array([3, 4]), rows_of([3, 4])) is None
    assert fresh.rows(np.array([0]), rows_of([0])) is None  # (the caller converts from then on)
