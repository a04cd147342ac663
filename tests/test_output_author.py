"""OutputAuthor: sparse time samples that read back exactly at every processed frame."""

from __future__ import annotations

import numpy as np
from pxr import Usd

from usd_gs.usd.output_author import LIGHT_SCALE, SH_COEFFS, TRANSMITTANCE, OutputAuthor


def _sequence(n: int = 3):
    """Per frame 1..10 the transmittance fed to the author: unaffected, a hold, a change,
    another hold, back to unaffected, affected again."""
    ones = np.ones(n, np.float32)
    a = np.array([0.2, 1.0, 0.5], np.float32)[:n]
    b = np.array([0.9, 0.1, 1.0], np.float32)[:n]
    return {1: ones, 2: ones, 3: a, 4: a, 5: a, 6: b, 7: b, 8: ones, 9: ones, 10: a}


def test_every_processed_frame_reads_back_exactly():
    stage = Usd.Stage.CreateInMemory()
    frames = list(range(1, 11))
    author = OutputAuthor(stage, frames)
    seq = _sequence()
    sh_in = np.full((3, 1, 3), 0.25, np.float32)
    for f in frames:
        t = seq[f]
        author.receiver("/P", f, t, sh_in * t[:, None, None], sh_in)
        author.light_scale("/A", f, np.tile(seq[f][:, None], (1, 3)) * 2.0)
    prim = stage.GetPrimAtPath("/P")
    tr, sh = prim.GetAttribute(TRANSMITTANCE), prim.GetAttribute(SH_COEFFS)
    ls = stage.GetPrimAtPath("/A").GetAttribute(LIGHT_SCALE)
    for f in frames:
        np.testing.assert_array_equal(np.asarray(tr.Get(f)), seq[f], err_msg=f"frame {f}")
        np.testing.assert_array_equal(np.asarray(sh.Get(f))[:, 0], 0.25 * seq[f], err_msg=f"frame {f}")
        np.testing.assert_array_equal(np.asarray(ls.Get(f))[:, 0], 2.0 * seq[f], err_msg=f"frame {f}")
    # sparse: held frames 4, 5 and 9 are not authored; frame 2 carries the unaffected value
    # before the first change, 5 and 7 end holds, frame 1 is never written (held before 2)
    assert tr.GetTimeSamples() == [2.0, 3.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]


def test_strided_frames_hold_at_previous_processed_frame():
    stage = Usd.Stage.CreateInMemory()
    frames = [0, 4, 8, 12]
    author = OutputAuthor(stage, frames)
    a = np.array([0.5, 1.0], np.float32)
    for f, t in zip(frames, [np.ones(2, np.float32), np.ones(2, np.float32), a, a], strict=True):
        author.receiver("/P", f, t, np.zeros((2, 1, 3), np.float32), np.zeros((2, 1, 3), np.float32))
    attr = stage.GetPrimAtPath("/P").GetAttribute(TRANSMITTANCE)
    assert attr.GetTimeSamples() == [4.0, 8.0]
    np.testing.assert_array_equal(np.asarray(attr.Get(0)), [1.0, 1.0])
    np.testing.assert_array_equal(np.asarray(attr.Get(4)), [1.0, 1.0])
    np.testing.assert_array_equal(np.asarray(attr.Get(12)), a)


def test_untouched_prim_gets_no_samples():
    stage = Usd.Stage.CreateInMemory()
    author = OutputAuthor(stage, [1, 2, 3])
    for f in (1, 2, 3):
        author.receiver("/P", f, np.ones(4, np.float32), np.ones((4, 1, 3), np.float32), np.ones((4, 1, 3), np.float32))
    assert not stage.GetPrimAtPath("/P")
    assert author.samples_written == 0


def test_same_values_is_array_equal_block_by_block(monkeypatch):
    import usd_gs.usd.output_author as oa

    monkeypatch.setattr(oa, "_SAME_BLOCK", 64)  # several blocks in a small array
    rng = np.random.default_rng(5)
    a = rng.standard_normal((100, 9, 3)).astype(np.float16)
    cases = {"equal": a.copy(), "first": a.copy(), "last": a.copy(), "nan": a.copy()}
    cases["first"][0, 0, 0] += 1
    cases["last"][-1, -1, -1] += 1
    cases["nan"][50, 4, 1] = np.nan
    for name, b in cases.items():
        assert oa.same_values(a, b) == np.array_equal(a, b) == (name == "equal"), name
    assert not oa.same_values(cases["nan"], cases["nan"])  # NaN differs from itself, as in np.array_equal
    assert not oa.same_values(a, a[:99]) and not oa.same_values(a, a.reshape(-1, 3))
    assert oa.same_values(a[:0], a[:0]) and oa.same_values(a[:, :3], a[:, :3].copy())  # empty; non-contiguous


def test_sh_display_within_is_the_bound_below_the_tolerance_block_by_block(monkeypatch):
    import usd_gs.usd.output_author as oa

    monkeypatch.setattr(oa, "_SAME_BLOCK", 60)  # blocks of 2 rows of (10, 3)
    rng = np.random.default_rng(8)
    a = rng.standard_normal((41, 10, 3)).astype(np.float32)
    tol = 1.0 / 512.0
    for row, step in ((0, 0.0), (0, 1e-4), (40, 1e-4), (40, 0.01), (17, 0.01), (5, np.nan)):
        b = a.copy()
        b[row, 3, 2] += step
        assert oa.sh_display_within(a, b, tol) == (oa.sh_display_change(a, b) < tol), (row, step)
    assert oa.sh_display_within(a[:0], a[:0], tol)
