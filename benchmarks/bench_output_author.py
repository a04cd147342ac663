"""The main job's authoring of shadowed static bricks: OutputAuthor.receiver prim by prim against
OutputAuthor.receivers (all touched bricks at once), back to back on the same synthetic frames.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_output_author.py [--bricks 1024] [--per-brick 300]
        [--frames 8] [--degree 0] [--touched 0.45]

Per frame a moving shadow covers a ``--touched`` share of the bricks (each a new transmittance),
as the demo's avatars do; the bricks it left are written back as unaffected. Prints the seconds
per frame of both ways and their ratio, and checks that both wrote the same time samples.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pxr import Sdf, Usd  # noqa: E402

from usd_gs.usd.output_author import SH_TOLERANCE, OutputAuthor  # noqa: E402


def _frames(args, rng):
    k = (args.degree + 1) ** 2
    counts = np.full(args.bricks, args.per_brick)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    sh_in = rng.normal(scale=0.3, size=(offsets[-1], k, 3)).astype(np.float32)
    width = max(1, int(args.touched * args.bricks))
    out = []
    for f in range(args.frames):
        lo = (f * width // 3) % args.bricks
        hit = np.arange(lo, lo + width) % args.bricks
        t = np.ones(offsets[-1], np.float32)
        rows = np.concatenate([np.arange(offsets[b], offsets[b + 1]) for b in hit])
        t[rows] = rng.uniform(0.2, 1.0, rows.size).astype(np.float32)
        out.append((np.sort(hit), t))
    return offsets, sh_in, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bricks", type=int, default=1024)
    ap.add_argument("--per-brick", type=int, default=300)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--degree", type=int, default=0)
    ap.add_argument("--touched", type=float, default=0.45)
    args = ap.parse_args()
    offsets, sh_in, seq = _frames(args, np.random.default_rng(0))
    paths = [f"/World/Room/Brick_{i:04d}" for i in range(args.bricks)]
    frames = list(range(1, args.frames + 1))
    stages, times = {}, {}
    for way in ("receiver", "receivers"):
        stage = Usd.Stage.CreateInMemory()
        author = OutputAuthor(stage, frames, (), "half", SH_TOLERANCE)
        t0 = time.perf_counter()
        for f, (hit, t) in zip(frames, seq, strict=True):
            hits = set(hit.tolist())
            cand = [b for b in range(args.bricks) if b in hits or not author.is_clean(paths[b])]
            sh_out = sh_in * t[:, None, None]
            if way == "receiver":
                for b in cand:
                    a, e = offsets[b], offsets[b + 1]
                    author.receiver(paths[b], f, t[a:e], sh_out[a:e], sh_in[a:e])
            else:
                rows = np.concatenate([np.arange(offsets[b], offsets[b + 1]) for b in cand])
                sub = np.concatenate([[0], np.cumsum(offsets[np.array(cand) + 1] - offsets[cand])])
                author.receivers(f, [paths[b] for b in cand], sub, t[rows], sh_out[rows], sh_in[rows])
        times[way] = (time.perf_counter() - t0) / args.frames
        stages[way] = stage
    same = stages["receiver"].GetRootLayer().ExportToString() == stages["receivers"].GetRootLayer().ExportToString()
    n_samples = 0

    def count(path):
        nonlocal n_samples
        if path.IsPropertyPath():
            n_samples += len(stages["receivers"].GetRootLayer().ListTimeSamplesForPath(path))

    stages["receivers"].GetRootLayer().Traverse(Sdf.Path.absoluteRootPath, count)
    print(f"{args.bricks} bricks x {args.per_brick} Gaussians, degree {args.degree}, {args.frames} frames, "
          f"{n_samples} time samples written")
    print(f"receiver (prim by prim): {times['receiver'] * 1e3:.1f} ms/frame; receivers (all at once): "
          f"{times['receivers'] * 1e3:.1f} ms/frame; ratio {times['receiver'] / times['receivers']:.1f}x; "
          f"same layer: {same}")


if __name__ == "__main__":
    main()
