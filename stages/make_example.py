"""Generate ``stages/example.usda``: a tiny synthetic shot for smoke tests and ``usdgs inspect``.

Contents (Y-up, metres, 24 time codes per second, frames 1..24):

- ``/World/Floor``: 30x30 flat Gaussians on y = 0, SH degree 1, role ``scene``.
- ``/World/Walker``: 200 Gaussians in a capsule 1.7 m tall, SH degree 0, role ``avatar``,
  moved by a time-sampled translate op along +X.
- ``/World/Ball``: 60 Gaussians in a 0.2 m sphere, SH degree 0, no role authored (``auto``),
  whose ``positions`` are time-sampled (a bounce).

Run ``python stages/make_example.py [OUT]`` (default: ``stages/example.usda`` beside this file).
Deterministic: the same code gives the same file.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _flat_gaussians(positions, sigma, thickness, colour, degree, rng):
    from usd_gs import sh3dgs
    from usd_gs.gaussians import GaussianSet

    n = len(positions)
    # local z -> world +Y: rotation of -90 degrees about X, quaternion (w, x, y, z)
    q = np.tile([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0], (n, 1))
    scales = np.tile([sigma, sigma, thickness], (n, 1))
    sh = np.zeros((n, sh3dgs.num_coeffs(degree), 3))
    sh[:, 0] = (np.asarray(colour) * rng.uniform(0.9, 1.1, size=(n, 1)) - 0.5) / sh3dgs.C0
    return GaussianSet(positions, q, scales, np.full(n, 0.9), sh)


def _blob(n, centre, radii, colour, sigma, rng):
    from usd_gs import sh3dgs
    from usd_gs.gaussians import GaussianSet

    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pos = np.asarray(centre) + u * np.asarray(radii)
    sh = np.zeros((n, 1, 3))
    sh[:, 0] = (np.asarray(colour) - 0.5) / sh3dgs.C0
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return GaussianSet(pos, q, np.full((n, 3), sigma), np.full(n, 0.8), sh)


def make_example(out: Path) -> Path:
    from pxr import Gf, UsdGeom

    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim
    from usd_gs.usd.schema import apply_role

    rng = np.random.default_rng(7)
    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    stage.SetTimeCodesPerSecond(24)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(24)
    UsdGeom.Xform.Define(stage, "/World")

    g = np.linspace(-2.0, 2.0, 30)
    xx, zz = np.meshgrid(g, g)
    floor = _flat_gaussians(np.stack([xx.ravel(), np.zeros(xx.size), zz.ravel()], 1), 0.08, 0.008,
                            (0.6, 0.55, 0.5), 1, rng)
    apply_role(write_gaussian_prim(stage, "/World/Floor", floor, keep_raw=False), "scene")

    walker = _blob(200, (0.0, 0.85, 0.0), (0.2, 0.85, 0.15), (0.3, 0.4, 0.7), 0.05, rng)
    prim = write_gaussian_prim(stage, "/World/Walker", walker, keep_raw=False)
    apply_role(prim, "avatar")
    op = UsdGeom.Xformable(prim).AddTranslateOp()
    for f in range(1, 25):
        op.Set(Gf.Vec3d(-1.5 + 3.0 * (f - 1) / 23.0, 0.0, 0.0), f)

    ball = _blob(60, (0.0, 0.0, 0.0), (0.1, 0.1, 0.1), (0.9, 0.3, 0.2), 0.03, rng)
    base = ball.positions.copy()
    for f in range(1, 25):
        ball.positions = base + np.array([0.8, 0.1 + 1.2 * abs(np.sin(np.pi * f / 12.0)), 0.6], np.float32)
        write_gaussian_prim(stage, "/World/Ball", ball, time=f, keep_raw=False)

    return save_stage_atomic(stage, str(out))


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("example.usda")
    print(make_example(target))
