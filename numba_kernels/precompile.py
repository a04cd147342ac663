"""Fill the numba cache with the lighting kernels of the main job, from a second process.

numba compiles single-threaded, so on a cold cache a ``usdgs process`` run leaves its other
cores idle for most of the compile time. Run ``python -m numba_kernels.precompile`` (same
``NUMBA_CACHE_DIR`` / same installed sources) alongside it: this process compiles the kernels
the main job needs *last* first (relight, SH transfer, probe fit, probe rasteriser, normals,
light estimation: the reverse of their order of use), and the main job loads each one from the
cache when it gets there instead of compiling it. Neither waits for the other, and the worst
case is a kernel compiled twice. Results are unaffected (the same code is compiled either way).

The kernels are compiled by calling the public functions on tiny inputs of the dtypes their
wrappers normalise to, so the specialisations are the ones the main job uses. Measured on the
2-core machine (default 48-frame cold ``usdgs process stages/demo.usda``): 86.3 s alone; a prototype
that compiled the same kernels plus the shadow kernels from the demo's recorded signatures cut it to 65.2 s.

    PYTHONPATH=. python -m numba_kernels.precompile            # prints seconds per step
"""

from __future__ import annotations

import sys
import time
from types import SimpleNamespace

import numpy as np


def _gaussians(n: int = 64, k: int = 16, seed: int = 0):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1.0, 1.0, (n, 3)).astype(np.float32)
    quat = rng.normal(size=(n, 4)).astype(np.float32)
    scales = rng.uniform(0.01, 0.1, (n, 3)).astype(np.float32)
    opac = rng.uniform(0.2, 1.0, n).astype(np.float32)
    sh = (0.1 * rng.normal(size=(n, k, 3))).astype(np.float32)
    return pos, quat, scales, opac, sh


def _relight():
    from .sh_transfer import relight_sh_coefficients

    _, _, _, _, sh = _gaussians()
    relight_sh_coefficients(sh, np.ones((sh.shape[0], 3), np.float32), 1.0)


def _transfer():
    from .sh_transfer import transfer_scale_sh

    pos = _gaussians()[0]
    transfer_scale_sh(pos, np.ones((9, 3)))


def _probe_fit():
    from .probe_fit import fit_sh_lstsq

    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(32, 3))
    fit_sh_lstsq(dirs / np.linalg.norm(dirs, axis=1)[:, None], np.ones(32), np.ones((32, 3)), 2)


def _rasterize():
    from .rasterize import rasterize

    pos, quat, scales, opac, sh = _gaussians()
    view_rot = np.tile(np.eye(3), (6, 1, 1))
    view_t = np.tile([0.0, 0.0, 3.0], (6, 1))
    intr = np.tile([8.0, 8.0, 8.0, 8.0], (6, 1))
    nearfar = np.tile([0.01, 100.0], (6, 1))
    rasterize(pos, quat, scales, opac, sh, view_rot, view_t, intr, nearfar, -view_t, 16, 16)


def _normals():
    from .normals import gaussian_normals, local_normals_to_world, normals_to_local

    pos, quat, scales, opac, _ = _gaussians(256)
    nrm = gaussian_normals(pos, quat, scales, opac)
    local_normals_to_world(quat, normals_to_local(quat, nrm))


def _lights():
    from .light_estimation import estimate_lights_arrays

    pos, _, _, opac, sh = _gaussians(256)
    cfg = SimpleNamespace(roi_radius=6.0, min_opacity=1.0 / 255.0, max_weight=0.25, clip_percentile=99.9,
                          clip_knee_factor=1.0, stability_power=1.0, dominance_power=1.0, tail_fraction=0.02,
                          min_candidates=16, max_candidates=64, peak_radius=0.3, peak_inner_radius=0.1,
                          peak_eps=1.0, peak_power=1.0, nms_distance=1.0, refine_radius=0.1,
                          refine_min_fraction=0.5)
    estimate_lights_arrays(pos, opac, sh, np.zeros(3), np.eye(3), 2, cfg)


#: reverse order of first use in ``usdgs process`` (lights, normals, shadows, probes, transfer, relight)
STEPS = (("relight", _relight), ("transfer", _transfer), ("probe_fit", _probe_fit), ("rasterize", _rasterize),
         ("normals", _normals), ("lights", _lights))


def main(argv: list[str] | None = None) -> int:
    t0 = time.perf_counter()
    for name, step in STEPS:
        step()
        print(f"precompile {time.perf_counter() - t0:6.1f} s {name}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
