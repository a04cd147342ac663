"""The static scene's point-light atlas with and without the receivers' reach bound.

A room-sized block of 300,000 Gaussians around the light and 2,700,000 more 40 m away (nothing
between them and the receivers), 50,000 receiver points around the room's centre: seconds to
build each atlas (packing and binning its occluders) and to answer the first lookup, the
occluders packed, and whether the two give the same bits (they must: the bound is exact).

Usage (from the repo root):
    PYTHONPATH=. .venv/bin/python benchmarks/bench_static_atlas_reach.py [--repeat 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.dgsm import DGSMConfig
from usd_gs.shadows.static_scene import StaticSceneAtlas
from usd_gs.synthetic import random_gaussians


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    near = random_gaussians(300_000, 0, seed=1)
    near.positions *= np.float32(3.0)
    far = random_gaussians(2_700_000, 0, seed=2)
    far.positions = (far.positions * np.float32(10.0) + np.float32([40.0, 0.0, 0.0])).astype(np.float32)
    far.opacities[:] = 0.5
    scene = GaussianSet.concatenate([near, far], label="room + far block")
    cfg = DGSMConfig(sampling="center")
    light = np.array([0.5, 2.5, 0.3])
    pts = np.random.default_rng(0).normal(0.0, 0.5, (50_000, 3))
    best: dict[bool, list] = {False: [], True: []}
    values = {}
    for _ in range(args.repeat):
        for bounded in (False, True):  # alternating
            t0 = time.perf_counter()
            atlas = StaticSceneAtlas(scene, light, cfg, bounded=bounded)
            values[bounded] = atlas.transmittance(pts)
            best[bounded].append((time.perf_counter() - t0, atlas.kept or atlas.count))
    same = np.array_equal(values[False].view(np.uint64), values[True].view(np.uint64))
    for bounded in (False, True):
        s, kept = min(best[bounded])
        print(f"{'bounded' if bounded else 'every occluder':16s} {s:7.2f} s (best of {args.repeat})  "
              f"occluders packed {kept:,}")
    print(f"speed-up {min(best[False])[0] / min(best[True])[0]:.1f}x; same bits: {same}; "
          f"shadowed receivers {(values[True] < 0.99).mean():.1%}")


if __name__ == "__main__":
    main()
