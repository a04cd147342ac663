"""Speed and error of the CPU splat rasteriser (numba_kernels/rasterize.py).

Prints, side by side:
- PSNR (and max abs error) of the fast path against the brute-force float64 reference
  (numba_kernels/reference/rasterize.py) on small scenes (64x48, a few hundred Gaussians);
- wall (and process CPU) time of six 64x64 cube faces and of one 960x540 view of
  1,000,000-Gaussian scenes: a room-like scene (walls + furniture) and
  ``usd_gs.synthetic.random_gaussians`` (issue targets: <= 0.5 s and <= 2 s), plus the real
  biker.ply capture (152,746 splats) when ../shared/data is present; after a warm-up call
  (numba compile and cache load excluded), best of ``--repeats``.

Run:  PYTHONPATH=. .venv/bin/python benchmarks/bench_rasterize.py [--n 1000000] [--degree 3]
      [--repeats 3] [--png-dir /tmp/rasterize_bench]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from usd_gs import sh3dgs
from usd_gs.gaussians import GaussianSet
from usd_gs.render.camera import Camera


def _random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _surface_quats(normal_axis: int, n: int, rng) -> np.ndarray:
    """Quaternions that put the local z axis (the thin one) along world axis ``normal_axis``,
    with a random spin about it."""
    ang = rng.uniform(0, np.pi, n)
    spin = np.stack([np.cos(ang), np.zeros(n), np.zeros(n), np.sin(ang)], axis=1)  # about local z
    base = {0: np.array([np.cos(np.pi / 4), 0, np.sin(np.pi / 4), 0]),      # z -> x (rotate about y)
            1: np.array([np.cos(np.pi / 4), -np.sin(np.pi / 4), 0, 0]),     # z -> y (rotate about -x)
            2: np.array([1.0, 0, 0, 0])}[normal_axis]
    w1, x1, y1, z1 = base
    w2, x2, y2, z2 = spin.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)


def room_scene(n: int, degree: int = 3, seed: int = 0) -> GaussianSet:
    """A room-like scene (Y up, metres): 8 x 3 x 6 m room centred on the origin (floor y=0).

    60% of the Gaussians are flat splats (sigma 1-3 cm in plane, 2 mm thick) on floor, ceiling
    and walls; 40% are clutter: small random splats (sigma 3-30 mm) on the faces of 200 boxes
    (furniture, 0.2-1 m) standing on the floor.
    Colours: smooth per-surface albedo plus SH noise up to ``degree``.
    """
    rng = np.random.default_rng(seed)
    half = np.array([4.0, 1.5, 3.0])
    centre = np.array([0.0, 1.5, 0.0])
    n_surf = int(0.6 * n)
    n_clut = n - n_surf
    # surfaces: pick one of 6 planes proportional to area
    areas = 4.0 * np.repeat([half[1] * half[2], half[0] * half[2], half[0] * half[1]], 2)
    plane = rng.choice(6, size=n_surf, p=areas / areas.sum())
    axis = plane // 2
    sign = np.where(plane % 2 == 0, -1.0, 1.0)
    p = rng.uniform(-1, 1, (n_surf, 3)) * half
    p[np.arange(n_surf), axis] = sign * half[axis]
    p += centre
    q = np.empty((n_surf, 4))
    for a in range(3):
        sel = axis == a
        q[sel] = _surface_quats(a, int(sel.sum()), rng)
    s = np.empty((n_surf, 3))
    s[:, :2] = rng.uniform(0.01, 0.03, (n_surf, 2))
    s[:, 2] = 0.002
    op_s = rng.uniform(0.5, 1.0, n_surf)
    albedo = np.array([[0.6, 0.5, 0.4], [0.5, 0.55, 0.6], [0.35, 0.3, 0.25], [0.8, 0.8, 0.78],
                       [0.7, 0.65, 0.55], [0.55, 0.6, 0.5]])
    col_s = albedo[plane] * (0.85 + 0.15 * np.sin(3.0 * p[:, [0]]) * np.cos(2.0 * p[:, [2]]))
    # clutter: boxes (furniture) with small random splats on their faces
    nb = 200
    bc = rng.uniform(-1, 1, (nb, 3)) * (half - 0.5) + centre
    bs = rng.uniform(0.1, 0.5, (nb, 3))
    bc[:, 1] = bs[:, 1]  # resting on the floor
    box = rng.integers(0, nb, n_clut)
    face = rng.integers(0, 6, n_clut)
    fa = face // 2
    u = rng.uniform(-1, 1, (n_clut, 3))
    u[np.arange(n_clut), fa] = np.where(face % 2 == 0, -1.0, 1.0)
    pc = bc[box] + u * bs[box]
    qc = _random_quats(rng, n_clut)
    sc = np.exp(rng.uniform(np.log(0.003), np.log(0.03), (n_clut, 3)))
    op_c = rng.uniform(0.3, 1.0, n_clut)
    col_c = rng.uniform(0.1, 0.9, (nb, 3))[box] * (0.8 + 0.2 * rng.uniform(size=(n_clut, 1)))
    k = sh3dgs.num_coeffs(degree)
    sh = np.zeros((n, k, 3))
    sh[:, 0] = (np.concatenate([col_s, col_c]) - 0.5) / sh3dgs.C0
    if k > 1:
        sh[:, 1:] = rng.normal(0, 0.05, (n, k - 1, 3))
    return GaussianSet(np.concatenate([p, pc]), np.concatenate([q, qc]), np.concatenate([s, sc]),
                       np.concatenate([op_s, op_c]), sh, label="room_scene")


def small_scenes(seed: int = 0):
    """Small hard scenes for the reference comparison: (name, GaussianSet, Camera)."""
    rng = np.random.default_rng(seed)
    out = []
    cam = Camera.look_at([0.3, 0.2, 4.0], [0, 0, 0], width=64, height=48, fov_y_deg=50)
    n = 300
    g = GaussianSet(rng.uniform(-1, 1, (n, 3)) * [2.0, 1.5, 2.5], _random_quats(rng, n),
                    np.exp(rng.uniform(np.log(0.01), np.log(0.3), (n, 3))), rng.uniform(0.05, 1, n),
                    rng.normal(0, 0.5, (n, 16, 3)), label="random")
    out.append(("random 300, SH3", g, cam))
    # very elongated needles and equal-depth overlaps, some behind the camera
    m = 200
    s = np.full((m, 3), 0.005)
    s[:, 0] = rng.uniform(0.3, 1.5, m)
    pos = rng.uniform(-1, 1, (m, 3)) * [1.5, 1.2, 1.0]
    pos[: m // 4, 2] = 0.25  # a quarter share one depth plane
    pos[m // 4: m // 3, 2] = 6.0  # behind the camera at z = 4
    g2 = GaussianSet(pos, _random_quats(rng, m), s, rng.uniform(0.2, 1, m), rng.normal(0, 0.5, (m, 4, 3)),
                     label="needles")
    out.append(("needles 200, SH1", g2, cam))
    return out


def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def best_time(fn, repeats):
    """(best wall s, process CPU s of that run, result) after one warm-up call."""
    fn()  # warm-up (compile / cache load)
    best = (np.inf, np.inf, None)
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fn()
        t, c = time.perf_counter() - t0, time.process_time() - c0
        if t < best[0]:
            best = (t, c, res)
    return best


def bench_scene(name, scene, probe, cam, repeats, png_dir):
    from usd_gs.render.rasterize import cube_faces_cross, render, render_cube_faces, write_png

    print(f"\n== {name}: {scene.count:,} Gaussians, SH degree {scene.sh_degree} ==")
    t, c, (rgb6, a6, _) = best_time(lambda: render_cube_faces(scene, probe, 64), repeats)
    print(f"six 64x64 cube faces : wall {t:6.3f} s  cpu {c:6.3f} s  (target <= 0.5 s) alpha {a6.mean():.3f}")
    t, c, res = best_time(lambda: render(scene, cam), repeats)
    print(f"960x540 view         : wall {t:6.3f} s  cpu {c:6.3f} s  (target <= 2 s)   alpha {res.alpha.mean():.3f}")
    if png_dir:
        os.makedirs(png_dir, exist_ok=True)
        tag = name.split()[0]
        write_png(os.path.join(png_dir, f"{tag}_view.png"), res.rgb)
        write_png(os.path.join(png_dir, f"{tag}_cube_cross.png"), cube_faces_cross(rgb6))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--png-dir", default=None)
    args = ap.parse_args()

    import numba

    from numba_kernels.reference.rasterize import rasterize as render_reference
    from usd_gs.render.rasterize import render
    from usd_gs.synthetic import random_gaussians

    print(f"numba threads: {numba.get_num_threads()}, load average: {os.getloadavg()[0]:.2f}")
    print("== fast path vs brute-force float64 reference (64x48) ==")
    for name, g, cam in small_scenes():
        fast = render(g, cam)
        vr, vt = cam.view_matrix()
        c, t, _ = render_reference(g.positions, g.orientations, g.scales, g.opacities, g.sh, vr, vt,
                                   cam.intrinsics(), [cam.near, cam.far], cam.position, cam.width, cam.height)
        print(f"{name:22s} PSNR rgb {psnr(fast.rgb, c):7.1f} dB  alpha {psnr(fast.alpha, 1 - t):7.1f} dB  "
              f"max|d rgb| {np.abs(fast.rgb - c).max():.2e}")

    room = room_scene(args.n, args.degree)
    bench_scene("room (walls + furniture boxes)", room, np.array([0.5, 2.5, -0.3]),
                Camera.look_at([3.8, 1.7, 2.8], [-2.0, 0.8, -2.0], width=960, height=540, fov_y_deg=60),
                args.repeats, args.png_dir)
    rnd = random_gaussians(args.n, args.degree, seed=0)
    bench_scene("random_gaussians (uniform in a 10 m box)", rnd, np.zeros(3),
                Camera.look_at([0.0, 2.0, 12.0], [0.0, 0.0, 0.0], width=960, height=540, fov_y_deg=60),
                args.repeats, args.png_dir)
    biker = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "splats" / "biker.ply"
    if biker.exists():
        from usd_gs.io.ply import read_ply

        g = read_ply(biker)  # Y-up, feet at y = 0, head at y ~ 3.1
        centre = np.array([0.0, 1.6, 0.0])
        bench_scene("biker.ply (real capture)", g, centre + [0.0, 0.0, 1.5],
                    Camera.look_at(centre + [4.0, 0.3, -2.0], centre, width=960, height=540, fov_y_deg=45),
                    args.repeats, args.png_dir)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
