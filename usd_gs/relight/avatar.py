"""The main job's relighting of one avatar or object: probe render, probe fit, transfer factor.

One cube render of everything but the prim (``usd_gs.relight.probe``, radiance: no display dilation) at
its alpha-weighted centroid ``c`` gives

- the probe written to the output (``usdgs:probe:shCoefficients``, SH ``probe_degree`` in the
  3DGS basis, fitted by eq. 7), and
- the transfer factor ``s(n)`` of eq. 10 for every Gaussian, from SH of ``transfer_degree``
  (default 4: with the clamped cosine of q = 1 the band l = 3 carries nothing, l = 4 halves
  the truncation error of a degree-2/3 probe on the ground truth's lamp and sun) at
  ``probe_points`` points of the prim (default 8; 1 is the paper's single probe at ``c``):
  parallax-corrected probes from the same render (``usd_gs.relight.parallax``), blended per
  Gaussian by distance.

Both ``ShotProcessor`` and the known-light ground truth (``usd_gs.evaluation.relight_groundtruth``) call
:func:`relight_factors`, so the measured accuracy is the main job's.
"""

from __future__ import annotations

import numpy as np

from usd_gs.relight.probe import PROBE_DILATION, SHProbe, fit_probe, render_probe_faces


def relight_factors(g, everything, mask: np.ndarray, centre, normals: np.ndarray, blend, opts,
                    dilation: float = PROBE_DILATION) -> tuple[np.ndarray, SHProbe]:
    """``(scale (N, 3) float32 s(n), probe)`` for the Gaussians ``g`` (world space) with unit
    outward ``normals`` (N, 3), seen from ``everything`` where ``mask`` (bool, len
    ``everything.count``) is True; ``centre`` (3,) metres; ``blend`` the prim's
    ``probe_parallax.ProbeBlend`` for the shot (None: one probe); ``opts`` a
    ``ProcessOptions`` (probe_size, probe_supersample, probe_degree, transfer_degree, relight_q,
    relight_t_max)."""
    from usd_gs.relight.parallax import cube_texels, reprojected_probes
    from usd_gs.relight.transfer import relight_scale

    rgb, alpha, depth = render_probe_faces(everything, centre, opts.probe_size, mask, dilation, opts.probe_supersample)
    probe = fit_probe(rgb, degree=opts.probe_degree, alpha=alpha, center=centre)
    q, t_max = opts.relight_q, opts.relight_t_max
    if blend is None or blend.k == 1:
        tp = probe if opts.transfer_degree == opts.probe_degree else fit_probe(rgb, degree=opts.transfer_degree,
                                                                              alpha=alpha, center=centre)
        return relight_scale(normals, tp, q=q, t_max=t_max), probe
    probes = reprojected_probes(cube_texels(rgb, alpha, depth, centre), blend.centres(g.positions),
                                opts.transfer_degree)
    return relight_scale(normals, probes, q=q, t_max=t_max, probe_basis="rh", blend=blend.weights), probe
