"""Where the moving casters' DGSMs spend a frame: every ``dgsm_build.build_point`` call of one frame
of ``usdgs process`` is recorded, then rerun on one thread phase by phase (ROI voxels, culling
footprints, tile lists, accumulation, plain and refined lookups, the refined ones reading the ROI's
stencils as the main job's do), with the counts that drive each.

    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_caster_phases.py [--stage stages/demo.usda]
        [--frame 5] [--repeat 3]

Prints one row per (caster, light) build and the frame's totals (seconds: the minimum of ``--repeat``
runs). The phases are the kernels ``build_point`` and ``lookup_point_refined`` call, with their
arguments; the atlas and the lookups are checked equal to ``build_point``'s and
``lookup_point_refined``'s own.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

import numba_kernels.dgsm_build as build
import numba_kernels.dgsm_sample as sample
from numba_kernels.thread_chunks import run_chunks


def record_builds(stage: Path, frame: int) -> list:
    """The ``(args, kwargs)`` of every ``build_point`` call while ``usdgs process`` runs ``frame``."""
    from usd_gs.cli import main
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()  # (as the usdgs console script sets the process up)

    calls = []
    plain = build.build_point

    def spy(*a, **k):
        calls.append((a, k))
        return plain(*a, **k)

    build.build_point = spy
    try:
        with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
            assert main(["process", str(stage), "-o", str(Path(tmp) / "o.usdc"), "--frames", str(frame), "-q"]) == 0
    finally:
        build.build_point = plain
    return calls


def _best(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def phases(args, repeat: int) -> dict:
    """Seconds and counts of one build's phases (``build_point``'s positional arguments ``args``)."""
    light, occ, dir_dep, cov6, pts, width, K, t_max, k_sigma = args[:9]
    t_max = build.t_max_for(build.far_distance(light, pts), K) if t_max is None else t_max
    row = {}
    def roi():
        st = build.point_stencils(light, pts, width, K, t_max)
        return st, build.stencil_roi(st, width)

    row["roi"], (stencils, (pixels, kmin, kmax)) = _best(roi, repeat)
    wt = width // build.TILE
    active = np.zeros(wt * wt, np.bool_)
    active[(pixels // width // build.TILE) * wt + (pixels % width) // build.TILE] = True
    n = occ.shape[0]  # (the centres read from the packed occluders, as build_point gives them)
    fx, fy, rp, glob_, cone = np.empty(n), np.empty(n), np.empty(n), np.zeros(n, np.bool_), np.empty((n, 4))
    row["footprints"], _ = _best(lambda: run_chunks(build._footprints, n, light, occ, cov6, width, float(k_sigma),
                                                    fx, fy, rp, glob_, cone, min_chunk=1024), repeat)
    row["tile lists"], (start, items) = _best(lambda: build._bin_tiles_chunked(fx, fy, rp, glob_, width, active),
                                              repeat)
    tiles = (start, items, np.flatnonzero(glob_).astype(np.int64), cone)

    def accumulate():
        index, out, pairs, erfs = build.atlas_buffers(width * width, pixels, kmin, kmax)
        build.accumulate_pixels(light, occ, dir_dep, pixels, width, K, t_max, kmin, kmax, tiles, True, True, out, pairs,
                                erfs)
        return index, out, pairs, erfs

    row["accumulation"], (index, out, pairs, erfs) = _best(accumulate, repeat)
    atlas = build.Atlas(width, K, float(t_max), kmin, kmax, index, out, pixels, int(pairs.sum()), int(erfs.sum()),
                        tiles)
    reference = build.build_point(*args)
    assert np.array_equal(reference.values, atlas.values) and np.array_equal(reference.pixels, atlas.pixels)
    row["lookups"], plain = _best(lambda: sample.lookup_point(atlas, light, pts), repeat)
    row["refined lookups"], (vals, refined) = _best(  # (reading the ROI's stencils, as the main job does)
        lambda: sample.lookup_point_refined(atlas, light, pts, occ, dir_dep, stencils=stencils), repeat)
    assert np.array_equal(vals, sample.lookup_point_refined(reference, light, pts, occ, dir_dep)[0])
    row.update(occluders=n, points=len(pts), pixels=len(pixels), tile_items=len(items), pairs=int(pairs.sum()),
               refined=int(refined.sum()))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stage", default="stages/demo.usda")
    ap.add_argument("--frame", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    calls = record_builds(Path(a.stage), a.frame)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        rows = [phases(args, a.repeat) for args, _ in calls]
    finally:
        numba.set_num_threads(threads)
    timed = ["roi", "footprints", "tile lists", "accumulation", "lookups", "refined lookups"]
    print(f"{a.stage}, frame {a.frame}: {len(rows)} moving-caster DGSMs, one thread, seconds (min of {a.repeat})")
    head = f"{'occluders':>9} {'points':>7} {'pixels':>6} {'pairs':>9} {'refined':>7}  "
    print(head + "  ".join(f"{t:>12}" for t in timed))
    for r in rows:
        print(f"{r['occluders']:9d} {r['points']:7d} {r['pixels']:6d} {r['pairs']:9d} {r['refined']:7d}  "
              + "  ".join(f"{r[t]:12.4f}" for t in timed))
    print(f"{'frame':>43}  " + "  ".join(f"{sum(r[t] for r in rows):12.4f}" for t in timed))
    ref = sum(r["refined"] for r in rows)
    print(f"refined lookups: {ref} of {sum(r['points'] for r in rows)} points "
          f"({100.0 * ref / max(sum(r['points'] for r in rows), 1):.1f} %); the refinement's own time: "
          f"{sum(r['refined lookups'] - r['lookups'] for r in rows):.4f} s")


if __name__ == "__main__":
    main()
