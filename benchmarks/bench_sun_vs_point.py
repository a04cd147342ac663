"""The sun path against the point-light path of the main job's shadows (issue 16), speed and error side by side.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_sun_vs_point.py [--receivers N] [--repeat R]

Scene: ``bench_dgsm``'s (``biker.ply`` scaled to 1.8 m as the caster, N flat floor and wall
receivers, default 1,000,000). Lights: a point light 2.5 m up and 1 m beside the avatar's centroid,
a point light 30 m away along the same direction (nearly parallel light: the sun's receivers),
and a DistantLight along that direction (from the near light to the centroid). Each runs
through what ``usdgs process`` calls for a moving caster on static
receivers (``usd_gs.shadows.shot.caster_transmittance``, cone/cylinder ROI, centre sampling, the
default ``DGSMConfig``).
Printed per light: best-of-R wall time, the ROI receivers, and the error against the exact
transmittance (``dgsm_exact``) at 3000 random ROI receivers (mean, 99th percentile, max).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bench_dgsm import load_biker, make_room

from numba_kernels import dgsm_exact
from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders
from usd_gs.shadows.shot import Receivers, caster_transmittance
from usd_gs.usd.lux import ShotLight


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--receivers", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    avatar = load_biker()
    room = make_room(a.receivers)
    recv = Receivers.build([("/room", room)])
    c = (avatar.opacities.astype(np.float64) @ avatar.positions) / avatar.opacities.sum()
    pos = np.array([c[0] + 1.0, 2.5, c[2]])
    d = (c - pos) / np.linalg.norm(c - pos)
    point = ShotLight("point", "point", pos, np.zeros(3), np.ones(3), 1.0)
    far = ShotLight("far", "point", c - 30.0 * d, np.zeros(3), np.ones(3), 1.0)  # nearly parallel: the sun's receivers
    sun = ShotLight("sun", "directional", np.zeros(3), d, np.ones(3), 1.0, shape="distant")
    cfg = DGSMConfig(sampling="center")
    prepared = prepare_occluders(avatar, cfg)
    occ, dep, _ = prepared
    rng = np.random.default_rng(0)
    print(f"{avatar.count} occluders, {room.count} receivers; point light at {pos.round(3)}, sun along {d.round(3)}")
    rows = {}
    for light in (point, far, sun):
        caster_transmittance(avatar.subset(slice(0, 3000)), recv, light, cfg)  # warm-up
        best = np.inf
        for _ in range(a.repeat):
            t = time.perf_counter()
            idx, val = caster_transmittance(avatar, recv, light, cfg, prepared=prepared)
            best = min(best, time.perf_counter() - t)
        pick = rng.choice(idx.size, min(3000, idx.size), replace=False)
        x = room.positions[idx[pick]].astype(np.float64)
        ex = (dgsm_exact.transmittance_point(light.position, x, occ, dep) if light.kind == "point"
              else dgsm_exact.transmittance_directional(d, x, occ, dep))
        err = np.abs(val[pick] - ex)
        rows[light.name] = best
        print(f"  {light.name:5s}: {best * 1e3:7.1f} ms, {idx.size:,} ROI receivers, error vs exact: "
              f"mean {err.mean():.5f}, p99 {np.quantile(err, 0.99):.4f}, max {err.max():.4f}")
    print(f"sun / point time ratio: {rows['sun'] / rows['point']:.2f}; sun / far point light (equal receivers): "
          f"{rows['sun'] / rows['far']:.2f} (same run)")


if __name__ == "__main__":
    main()
