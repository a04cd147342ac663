"""A shot built from the captures as a user would, whose cost is the output's: the flowers capture
(PlayCanvas SOG LOD set, level 0: 542,104 Gaussians, SH degree 2, Y-down, role scene) under an
estimated sky, the angel statue (``.sog``, Y-down, an inserted object) and the monkey flipbook
(SOG sequence, a moving avatar) walking across the grass. Nothing lights it but the sky, and the
monkey hides a little of it from the whole garden: every frame changes every scene Gaussian's SH by
more than the output's threshold, so each frame writes the whole capture (about 29 MB of half SH).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_capture_shot.py [--frames 1-12] [--runs 2]
        [--workdir DIR] [--brick-size N]

Imports with ``usdgs import`` into ``--workdir`` (kept between runs), then runs ``usdgs process`` in a
child process per run (warm numba cache) and prints per run the seconds per frame, the authoring's
seconds per frame (``timings_s.write``: it runs on the main thread beside the next frame's shadow
tasks), the one-off light estimation and the output's megabytes per frame. ``--brick-size N`` imports
the flowers as spatial bricks of at most N Gaussians instead of one prim.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

SHOT = """#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Y"
    metersPerUnit = 1
    startTimeCode = 1
    endTimeCode = {last}
    timeCodesPerSecond = 24
)

def Xform "World"
{{
    def Xform "FlowersXf"
    {{
        double3 xformOp:scale = (10, 10, 10)
        uniform token[] xformOpOrder = ["xformOp:scale"]
        def "Flowers" (references = @./{flowers}@) {{}}
    }}
    def Xform "AngelXf"
    {{
        double3 xformOp:translate = (1.5, 1.5, 0)
        double3 xformOp:scale = (0.5, 0.5, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
        def "Angel" (references = @./angel.usdc@) {{}}
    }}
    def Xform "MonkeyXf"
    {{
        double3 xformOp:translate.timeSamples = {{
            1: (-1.5, 1.0, 0.5),
            {last}: (0.5, 1.0, 0.5),
        }}
        double3 xformOp:scale = (0.4, 0.4, 0.4)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
        def "Monkey" (references = @./monkey.usdc@) {{}}
    }}
}}
"""


def build_shot(work: Path, last_frame: int, brick_size: int = 0) -> Path:
    """The shot of the module docstring in ``work``; the imports are made once (``usdgs import``)."""
    from usd_gs.cli import main

    flowers = f"flowers_b{brick_size}.usdc" if brick_size else "flowers.usdc"
    bricks = ["--brick-size", str(brick_size)] if brick_size else []
    imports = [(DATA / "scenes" / "flowers" / "lod-meta.json", flowers,
                ["--lod", "0", "--y-down", "--role", "scene", *bricks]),
               (DATA / "humans" / "statues" / "angel.sog", "angel.usdc", ["--y-down", "--role", "object"]),
               (DATA / "sequences" / "monkey" / "monkey_####.sog", f"monkey_{last_frame}.usdc",
                ["--frames", f"1-{last_frame}", "--role", "avatar"])]
    for src, name, extra in imports:
        out = work / name
        if not out.exists():
            assert main(["import", str(src), "-o", str(out), "-q", *extra]) == 0
    shot = work / f"shot_{last_frame}_{brick_size}.usda"
    text = SHOT.format(last=last_frame, flowers=flowers).replace("monkey.usdc", f"monkey_{last_frame}.usdc")
    shot.write_text(text)
    return shot


def run_once(shot: Path, out: Path, frames: str) -> dict:
    """One ``usdgs process`` of ``shot`` in a child process; its ``--json`` summary."""
    cmd = [sys.executable, "-m", "usd_gs.cli", "process", str(shot), "-o", str(out), "--frames", frames, "--json"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default="1-12")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--brick-size", type=int, default=0)
    a = ap.parse_args()
    first, last = (int(x) for x in a.frames.split("-"))
    work = a.workdir or Path(tempfile.mkdtemp(prefix="usdgs_capture_shot_"))
    work.mkdir(parents=True, exist_ok=True)
    shot = build_shot(work, last, a.brick_size)
    n = last - first + 1
    print(f"{shot}: frames {a.frames}, one child process per run")
    print(f"{'run':>3} {'s/frame':>8} {'write s/frame':>13} {'light estimate s':>16} {'MB/frame':>9} {'samples':>8}")
    for r in range(a.runs):
        d = run_once(shot, work / "out.usdc", a.frames)
        t = d["timings_s"]
        print(f"{r + 1:3d} {d['seconds_per_frame']:8.3f} {t.get('write', 0.0) / n:13.3f} {t.get('lights', 0.0):16.2f} "
              f"{d['output_bytes'] / n / 1e6:9.1f} {d['samples_written']:8d}")


if __name__ == "__main__":
    main()
