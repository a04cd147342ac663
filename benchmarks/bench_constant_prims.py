"""Inserted objects that hold one pose: their reads, packing and shadows on the static scene held
for the shot, against doing them at every frame, speed and difference side by side in one run.

The shot is built from the captures in ``../shared/data`` as a user would: the seal (``.splat``,
turned Y-up), the monkey flipbook (SOG sequence, a moving avatar) and two inserted objects with
nothing time-sampled, the playbot (SOG LOD set, 500,000 Gaussians, SH degree 2) and the skull
(``.sog``, degree 3). Each mode runs ``usdgs process`` in this process, alternating: ``held`` (the
shipped behaviour: ``usd_gs.pipeline.shot.ShotProcessor._constant``) and ``every frame`` (that set
emptied: the objects are read, packed and cast at every frame, as before). Printed per run: frame
1 and the steady frames' mean seconds; then the largest differences between the two modes'
outputs: the transmittance AOV and the displayed DC colour of the relit SH.

    PYTHONPATH=.:benchmarks .venv/bin/python benchmarks/bench_constant_prims.py [--frames 1-8] [--rounds 2]
        [--workdir DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
C0 = 0.28209479177387814

SHOT = """#usda 1.0
(
    startTimeCode = 1
    endTimeCode = 50
    upAxis = "Y"
    metersPerUnit = 1
    timeCodesPerSecond = 24
)
def Xform "World"
{
    def "Seal" (prepend references = @seal.usdc@</World/Seal>)
    {
        float xformOp:rotateX = 180
        uniform token[] xformOpOrder = ["xformOp:rotateX"]
    }
    def "Monkey" (prepend references = @monkey.usdc@</World/Monkey>)
    {
        double3 xformOp:translate = (0.5, 0.5, 1.0)
        float3 xformOp:scale = (0.3, 0.3, 0.3)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }
    def "Playbot" (prepend references = @playbot.usdc@</World/Playbot>)
    {
        double3 xformOp:translate = (1.2, 0.9, -0.5)
        float3 xformOp:scale = (0.5, 0.5, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }
    def "Skull" (prepend references = @skull.usdc@</World/Skull>)
    {
        double3 xformOp:translate = (-1.0, 0.8, 1.0)
        float3 xformOp:scale = (0.4, 0.4, 0.4)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }
}
"""


def build_shot(work: Path, last_frame: int) -> Path:
    """The shot of the module docstring in ``work`` (imports with ``usdgs import``)."""
    from usd_gs.cli import main

    imports = [(DATA / "scenes" / "luma-seal.splat", "seal", "/World/Seal", "scene", []),
               (DATA / "sequences" / "monkey" / "monkey_####.sog", "monkey", "/World/Monkey", "avatar",
                ["--frames", f"1-{last_frame}"]),
               (DATA / "objects" / "playbot", "playbot", "/World/Playbot", "object", []),
               (DATA / "objects" / "skull.sog", "skull", "/World/Skull", "object", [])]
    for src, name, prim, role, extra in imports:
        out = work / f"{name}.usdc"
        if not out.exists():
            assert main(["import", str(src), "-o", str(out), "--prim", prim, "--role", role, "-q", *extra]) == 0
    shot = work / "shot.usda"
    shot.write_text(SHOT)
    return shot


def run(shot: Path, out: Path, frames: str, held: bool) -> list[float]:
    """Seconds of each frame of one in-process ``usdgs process`` (``held`` False: no prim counts as
    holding one pose)."""
    import usd_gs.pipeline.shot as shot_mod
    from usd_gs.cli import main
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()  # (as the usdgs console script sets the process up)

    times = []
    opened, frame = shot_mod.ShotProcessor._open, shot_mod.ShotProcessor._frame

    def open_(self):
        opened(self)
        if not held:
            self._constant = set()

    def timed(self, *a, **k):
        t = time.perf_counter()
        try:
            return frame(self, *a, **k)
        finally:
            times.append(time.perf_counter() - t)

    shot_mod.ShotProcessor._open, shot_mod.ShotProcessor._frame = open_, timed
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["process", str(shot), "-o", str(out), "--frames", frames, "--aovs", "transmittance",
                         "-q"]) == 0
    finally:
        shot_mod.ShotProcessor._open, shot_mod.ShotProcessor._frame = opened, frame
    return times


def differences(a: Path, b: Path) -> tuple[float, float, int]:
    """(largest |transmittance difference|, largest |displayed DC colour difference| of the relit SH,
    shadowed receiver values compared) between two outputs of the same shot, every frame."""
    from pxr import Usd

    sa, sb = Usd.Stage.Open(str(a)), Usd.Stage.Open(str(b))
    worst_t = worst_c = 0.0
    shadowed = 0
    for prim in sa.Traverse():
        ta = prim.GetAttribute("primvars:usdgs:transmittance")
        tb = sb.GetPrimAtPath(prim.GetPath()).GetAttribute("primvars:usdgs:transmittance")
        for t in (ta.GetTimeSamples() if ta else []):
            x, y = np.asarray(ta.Get(t)), np.asarray(tb.Get(t))
            worst_t = max(worst_t, float(np.abs(x - y).max()))
            shadowed += int(np.count_nonzero(x < 0.99))
        sha = prim.GetAttribute("radiance:sphericalHarmonicsCoefficientsh")
        shb = sb.GetPrimAtPath(prim.GetPath()).GetAttribute("radiance:sphericalHarmonicsCoefficientsh")
        k = (int(prim.GetAttribute("radiance:sphericalHarmonicsDegree").Get() or 0) + 1) ** 2
        for t in (sha.GetTimeSamples() if sha else []):
            x, y = (np.asarray(v.Get(t), np.float64).reshape(-1, k, 3)[:, 0] for v in (sha, shb))
            worst_c = max(worst_c, float(np.abs(C0 * (x - y)).max()))
    return worst_t, worst_c, shadowed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="1-8")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--workdir", default=None)
    a = ap.parse_args()
    work = Path(a.workdir or tempfile.mkdtemp(prefix="bench_constant_"))
    work.mkdir(parents=True, exist_ok=True)
    last = int(a.frames.split("-")[-1])
    shot = build_shot(work, last)
    print(f"{shot}: frames {a.frames}; seconds of frame 1 and the steady frames' mean")
    for r in range(a.rounds):
        for held in (True, False):
            name = "held" if held else "every frame"
            times = run(shot, work / f"{'held' if held else 'each'}.usdc", a.frames, held)
            print(f"round {r + 1} {name:12s} frame 1 {times[0]:6.2f} s, steady {np.mean(times[1:]):6.3f} s/frame")
    worst_t, worst_c, shadowed = differences(work / "held.usdc", work / "each.usdc")
    print(f"held vs every frame: transmittance max |difference| {worst_t:.4f} ({shadowed} shadowed receiver "
          f"values), relit displayed DC colour max |difference| {worst_c:.5f} ({255 * worst_c:.2f}/255)")


if __name__ == "__main__":
    main()
