"""What ``usdgs process`` writes: bytes per frame per attribute, and the rendered difference of
an output against a reference output of the same shot (e.g. ``--precision float --sh-tolerance
0 --aovs transmittance,lightScale``, every value exact).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_output_size.py OUT.usdc [--reference REF.usdc]
        [--frames 1,13,25,37] [--width 960]

Prints one line per attribute (MB in all, MB per processed frame, samples) and, with
``--reference``, the largest and the 99.9th-percentile absolute difference in display colour
(0..1, RGB) between the two renders from the stage's camera at each frame.
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def attribute_bytes(path: str) -> tuple[dict, dict, int]:
    """({attribute name: bytes}, {attribute name: samples}, processed frames) of a layer's time samples."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(path)
    size, count, frames = collections.Counter(), collections.Counter(), set()

    def visit(p):
        if not p.IsPropertyPath() or layer.GetAttributeAtPath(p) is None:
            return
        for t in layer.ListTimeSamplesForPath(p):
            v = layer.QueryTimeSample(p, t)
            size[p.name] += np.asarray(v).nbytes if hasattr(v, "__len__") else 8
            count[p.name] += 1
            frames.add(t)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return dict(size), dict(count), len(frames)


def render_difference(out: str, ref: str, frames, width: int) -> list[tuple[float, float, float]]:
    """[(frame, max abs difference, 99.9th percentile)] of the display colours of two processed stages."""
    from pxr import Usd

    from usd_gs.render.preview import render_stage_frame

    a, b = Usd.Stage.Open(out), Usd.Stage.Open(ref)
    rows = []
    for f in frames:
        ia = render_stage_frame(a, f, width=width).rgb
        ib = render_stage_frame(b, f, width=width).rgb
        d = np.abs(np.clip(ia, 0, 1) - np.clip(ib, 0, 1))
        rows.append((f, float(d.max()), float(np.quantile(d, 0.999))))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("output")
    ap.add_argument("--reference")
    ap.add_argument("--frames", default="1,13,25,37")
    ap.add_argument("--width", type=int, default=960)
    a = ap.parse_args()
    size, count, nframes = attribute_bytes(a.output)
    file_mb = Path(a.output).stat().st_size / 1e6
    print(f"{a.output}: {file_mb:.1f} MB on disk, {nframes} frames with samples, "
          f"{file_mb / max(nframes, 1):.2f} MB/frame")
    for name, b in sorted(size.items(), key=lambda kv: -kv[1]):
        print(f"  {name:50s} {b / 1e6:9.1f} MB {b / 1e6 / max(nframes, 1):7.2f} MB/frame {count[name]:6d} samples")
    if a.reference:
        frames = [float(x) for x in a.frames.split(",")]
        for f, mx, q in render_difference(a.output, a.reference, frames, a.width):
            print(f"  frame {f:g}: render difference max {mx:.5f} ({mx * 255:.2f}/255), 99.9 % {q:.5f}")


if __name__ == "__main__":
    main()
