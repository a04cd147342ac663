"""The static atlases' serve radius on a shot with a far part: speed and error side by side.

Runs ``usdgs process SHOT --frames F`` in this process on one thread with the point lights' static
atlases as shipped (bins over at most ``SERVE_RADIUS`` for the receivers within it) or, with
``--whole``, with bins over the whole range (``SERVE_RADIUS`` set beyond the scene), and prints
the occluders packed and radial-bin pairs over the run's static atlases, their lookup seconds
(packing, columns and lookups), and the error of a sample of each lookup batch (1,500 points,
seeded) against the exact transmittance over the atlas's packed occluders
(``usd_gs.shadows.dgsm.exact_transmittance``). Run it once per variant (numba's threads are set
before the first kernel runs); the shot: ``bench_far_first_frame.py``'s far-scene shot or the demo.

    NUMBA_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python benchmarks/bench_static_atlas_serve.py SHOT
        [--frames 1] [--whole]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shot")
    ap.add_argument("--frames", default="1")
    ap.add_argument("--whole", action="store_true", help="bins over the whole range (no serve radius)")
    a = ap.parse_args()
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()
    import usd_gs.pipeline.shot as shot
    import usd_gs.shadows.static_scene as ss
    from usd_gs.cli import main as usdgs
    from usd_gs.shadows.dgsm import exact_transmittance

    if a.whole:
        shot.SERVE_RADIUS = 1e12
    atlases, errors, seconds = {}, [], [0.0]
    build, served = ss.StaticSceneAtlas._build, ss.StaticSceneAtlas._served

    def recorded_build(self, keep):
        self.packed_rows = keep
        atlases[id(self)] = self
        return build(self, keep)

    def timed_served(self, pts):
        t0 = time.perf_counter()
        out = served(self, pts)
        seconds[0] += time.perf_counter() - t0
        rows = getattr(self, "packed_rows", None)
        if pts.shape[0] and rows is not None and rows.size:
            rng = np.random.default_rng(len(errors))
            pick = rng.choice(pts.shape[0], min(1500, pts.shape[0]), replace=False)
            exact = exact_transmittance(self._all.subset(rows), pts[pick], self.light, self.cfg)
            errors.append(np.abs(out[pick] - exact))
        return out

    ss.StaticSceneAtlas._build, ss.StaticSceneAtlas._served = recorded_build, timed_served
    with tempfile.TemporaryDirectory() as tmp:
        rc = usdgs(["process", a.shot, "-o", str(Path(tmp) / "out.usdc"), "--frames", a.frames, "-q"])
    if rc:
        raise SystemExit(f"usdgs process failed ({rc})")
    err = np.concatenate(errors) if errors else np.zeros(0)
    t_max = sorted({round(x.t_max, 2) for x in atlases.values()})
    print(f"{'whole range' if a.whole else 'serve radius'}: atlases {len(atlases)}, t_max {t_max} m, "
          f"occluders packed {sum(x.kept for x in atlases.values()):,}, bin pairs "
          f"{sum(x.pairs for x in atlases.values()):,}, lookups {seconds[0]:.3f} s")
    print(f"  error against exact ({err.size:,} sampled lookups): mean {err.mean():.2e}, "
          f"p99 {np.quantile(err, 0.99):.2e}, max {err.max():.3f}")


if __name__ == "__main__":
    main()
