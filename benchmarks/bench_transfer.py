"""Speed and error of the SH probe fit, SH transfer (closed form vs quadrature) and ZH transfer.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_transfer.py [--n 100000] [--repeat 5]``

Prints, for N Gaussians: closed-form SH transfer time (eq. 10 scale, and relit coefficients),
the quadrature reference time at the smallest lat-long grid M that matches the closed form
to 1e-3 (relative to the largest value), their speed ratio and max relative error; the
degree-8 ZH transfer time; normal estimation time; the probe fit time for 6 x 64 x 64 faces
(after the one-off operator set-up). Numba kernels are warmed up before timing; times are
the median of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from numba_kernels.normals import gaussian_normals, local_normals_to_world, normals_to_local  # noqa: E402
from numba_kernels.probe_fit import CubeProbeFitter  # noqa: E402
from numba_kernels.sh_transfer import (  # noqa: E402
    relight_sh_coefficients,
    transfer_scale_quadrature,
    transfer_scale_sh,
)
from numba_kernels.zh_transfer import zh_diffuse_color  # noqa: E402

_CPU = []  # CPU seconds per call of the last timing (all threads), for loaded machines


def _median_time(fn, repeat):
    fn()  # warm-up / compile
    ts = []
    cpu = []
    for _ in range(repeat):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    _CPU[:] = [float(np.median(cpu))]
    return float(np.median(ts))


def _cpu_note():
    return f" [CPU {_CPU[0] * 1e3:.1f} ms]"


def _rel_err(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def dome_check(size: int = 64, n: int = 32768) -> None:
    """Issue 3.4 ground truth with the rasteriser: HDR sky dome -> cube faces -> eq. 7 fit,
    vs. the direct SH projection of the (64 x 128 box-filtered) HDR."""
    from usd_gs.io import envmap
    from usd_gs.relight.probe import fit_probe, hdr_dome_gaussians
    from usd_gs.render.rasterize import render_cube_faces

    data = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "hdri"
    print(f"dome check: {n} dome Gaussians, cube faces 6 x {size} x {size}; relative L2 coefficient error "
          "for degree 0..3 fits (limits 5% for <= 2, 10% for 3)")
    for path in sorted(data.glob("*")):
        img = envmap.read_envmap(path)
        img = img[: img.shape[0] // 8 * 8, : img.shape[0] // 8 * 16]
        lo = envmap.downsample_latlong(img, 8)
        dome = hdr_dome_gaussians(img, radius=10.0, n=n)
        t0 = time.perf_counter()
        rgb, alpha, _ = render_cube_faces(dome, np.zeros(3), size)
        t_render = time.perf_counter() - t0
        errs = []
        for degree in range(4):
            gt = envmap.project_latlong_to_sh(lo, degree, "rh")
            fit = fit_probe(rgb, degree, alpha=alpha).rh()
            errs.append(np.linalg.norm(fit - gt) / np.linalg.norm(gt))
        ok = max(errs[:3]) <= 0.05 and errs[3] <= 0.10
        print(f"  {path.name:28s} {dome.count} Gaussians, render {t_render * 1e3:.0f} ms, errors "
              + " ".join(f"{e * 100:.1f}%" for e in errs) + ("  OK" if ok else "  FAIL"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--q", type=float, default=1.0)
    ap.add_argument("--dome", action="store_true",
                    help="only run the HDR sky-dome probe check (needs usd_gs.render.rasterize)")
    args = ap.parse_args()
    if args.dome:
        dome_check()
        return
    rng = np.random.default_rng(0)
    n = args.n
    threads = os.environ.get("NUMBA_NUM_THREADS", "default")
    print(f"N = {n} Gaussians, q = {args.q}, cores = {os.cpu_count()}, NUMBA_NUM_THREADS = {threads}, "
          f"load average = {os.getloadavg()[0]:.1f}")
    print("times: median wall clock; [CPU ...] = CPU time of all threads per call (the work, robust to load)")

    normals = rng.normal(size=(n, 3))
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    probe3 = rng.normal(size=(16, 3)) * 0.3
    probe3[0] += [3.0, 2.5, 2.0]
    sh = (rng.normal(size=(n, 16, 3)) * 0.2).astype(np.float32)

    t_scale = _median_time(lambda: transfer_scale_sh(normals, probe3, q=args.q), args.repeat)
    cpu_scale = _CPU[0]
    note_scale = _cpu_note()
    scale = transfer_scale_sh(normals, probe3, q=args.q)
    t_relit = _median_time(lambda: relight_sh_coefficients(sh, scale, 1.0), args.repeat)
    print(f"SH transfer closed form (degree 3): scale {t_scale * 1e3:.2f} ms{note_scale} + relit coefficients "
          f"{t_relit * 1e3:.2f} ms{_cpu_note()} = {(t_scale + t_relit) * 1e3:.2f} ms")

    sub = normals[:2000]
    fast_sub = transfer_scale_sh(sub, probe3, q=args.q)
    chosen = None
    for nt in (16, 24, 32, 48, 64, 96, 128, 192, 256):
        err = _rel_err(fast_sub, transfer_scale_quadrature(sub, probe3, q=args.q, n_theta=nt, n_phi=2 * nt))
        if err <= 1e-3:
            chosen = nt
            break
    if chosen is None:
        chosen = 256
    m = chosen * 2 * chosen
    t_quad = _median_time(lambda: transfer_scale_quadrature(normals, probe3, q=args.q, n_theta=chosen,
                                                            n_phi=2 * chosen), max(1, args.repeat // 2))
    ref = transfer_scale_quadrature(normals, probe3, q=args.q, n_theta=chosen, n_phi=2 * chosen)
    print(f"SH transfer quadrature reference: M = {chosen} x {2 * chosen} = {m} directions, {t_quad * 1e3:.1f} ms"
          f"{_cpu_note()}")
    print(f"  speed ratio reference / closed form (scale only): wall {t_quad / t_scale:.0f}x, "
          f"CPU {_CPU[0] / max(cpu_scale, 1e-9):.0f}x; "
          f"max relative error {_rel_err(scale, ref):.2e}")
    big = transfer_scale_quadrature(sub, probe3, q=args.q, n_theta=512, n_phi=1024)
    print(f"  closed form vs quadrature at M = 512 x 1024 (2000 Gaussians): max relative error "
          f"{_rel_err(fast_sub, big):.2e}")

    quat = rng.normal(size=(n, 4)).astype(np.float32)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    albedo = rng.uniform(0.1, 1.0, (n, 3)).astype(np.float32)
    zc = rng.normal(size=(n, 3, 4, 3)).astype(np.float32)
    zm = rng.normal(size=(n, 3, 5)).astype(np.float32)
    probe8 = rng.normal(size=(81, 3)) * 0.1
    probe8[0] += 2.0
    t_zh = _median_time(lambda: zh_diffuse_color(quat, albedo, zc, zm, probe8), args.repeat)
    print(f"ZH transfer (degree 8 probe, 3 coloured ZH to degree 3 + mono 4..8): {t_zh * 1e3:.2f} ms{_cpu_note()}")

    pts = rng.normal(size=(n, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    scales = rng.uniform(0.005, 0.02, (n, 3)).astype(np.float32)
    opac = rng.uniform(0.2, 1.0, n).astype(np.float32)
    t_nrm = _median_time(lambda: gaussian_normals(pts, quat, scales, opac, radius=0.03), max(1, args.repeat // 2))
    note = _cpu_note()
    t_nrm_auto = _median_time(lambda: gaussian_normals(pts, quat, scales, opac), max(1, args.repeat // 2))
    print(f"normals (unit sphere, radius 0.03, ~22 neighbours): {t_nrm * 1e3:.1f} ms{note}; automatic radius: "
          f"{t_nrm_auto * 1e3:.1f} ms{_cpu_note()}")
    local = normals_to_local(quat, pts)
    t_posed = _median_time(lambda: local_normals_to_world(quat, local), args.repeat)
    print(f"posed-frame normals from rest-pose local normals: {t_posed * 1e3:.2f} ms{_cpu_note()}")

    faces = rng.random((6, 64, 64, 3)).astype(np.float32)
    for degree in (3, 8):
        t0 = time.perf_counter()
        fitter = CubeProbeFitter(64, degree, 1e-3)
        t_setup = time.perf_counter() - t0
        t_fit = _median_time(lambda f=fitter: f.fit(faces), args.repeat)
        print(f"probe fit 6x64x64 faces, degree {degree}: {t_fit * 1e3:.2f} ms{_cpu_note()} per fit "
              f"(one-off operator set-up {t_setup * 1e3:.0f} ms)")


if __name__ == "__main__":
    main()
