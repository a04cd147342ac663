"""Slow, obvious numpy version of ``numba_kernels.light_estimation`` (tests and benchmarks).

Same steps and formulas as the module docstring of ``light_estimation``, written directly:
SH colours through ``reference.sh_real.threedgs_color`` (the 3DGS basis from scipy's complex
SH, independent of the kernel's polynomials; ``C0 = Y_00 = 1 / (2 sqrt(pi))``), statistics with
``np.mean`` / ``np.std`` / ``np.max``, the percentile with ``np.percentile(method="lower")``,
the tail with a stable ``argsort``, neighbourhoods by a dense O(M N) distance matrix, NMS and
refinement with Python loops over the k lights. Memory is O(M N): use it on small scenes only.
"""

from __future__ import annotations

import math

import numpy as np

from .sh_real import threedgs_color

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _colors_from(sh, positions, viewer):
    d = positions - viewer
    n = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(n > 0, d / np.where(n > 0, n, 1.0), np.array([0.0, 0.0, 1.0]))
    return np.maximum(threedgs_color(sh, d), 0.0)


def score_cues(positions, opacities, sh, centroid, viewpoints, cfg):
    """In-ROI mask and per-Gaussian (mean_y, max_y, stability, dominance, lum), zero outside."""
    p = positions.astype(np.float64)
    a = opacities.astype(np.float64)
    sh64 = sh.astype(np.float64)
    finite = np.isfinite(p).all(1) & np.isfinite(a) & np.isfinite(sh64).all((1, 2))
    in_roi = finite & (((p - centroid) ** 2).sum(1) <= cfg.roi_radius ** 2) & (a >= cfg.min_opacity)
    ys = np.stack([_colors_from(sh64, p, v) @ LUMA for v in viewpoints], axis=1)  # (N, V)
    mean_y = ys.mean(1)
    max_y = ys.max(1)
    stab = np.clip(1.0 - ys.std(1) / (mean_y + 1e-12), 0.0, 1.0)
    dc = 0.5 + 0.5 / math.sqrt(math.pi) * sh64[:, 0, :]
    e_dc = (dc ** 2).sum(1)
    e_view = (sh64[:, 1:, :] ** 2).sum((1, 2)) / (4.0 * math.pi)
    dom = np.where(e_dc + e_view > 0, e_dc / np.where(e_dc + e_view > 0, e_dc + e_view, 1.0), 0.0)
    lum = (1.0 - cfg.max_weight) * mean_y + cfg.max_weight * max_y
    z = lambda x: np.where(in_roi, x, 0.0)  # noqa: E731
    return in_roi, z(mean_y), z(max_y), z(stab), z(dom), z(lum)


def estimate_lights_arrays(positions, opacities, sh, centroid, viewpoints, k, cfg) -> dict:
    """Same outputs as ``light_estimation.estimate_lights_arrays`` (minus ``status``)."""
    p = positions.astype(np.float64)
    centroid = np.asarray(centroid, dtype=np.float64)
    in_roi, _my, _xy, stab, dom, lum = score_cues(positions, opacities, sh, centroid, viewpoints, cfg)
    roi = np.flatnonzero(in_roi)
    knee = 0.0
    if roi.size:
        knee = cfg.clip_knee_factor * float(np.percentile(lum[roi], cfg.clip_percentile, method="lower"))
    clipped = lum.copy()
    if knee > 0:
        hi = lum > knee
        clipped[hi] = knee * (1.0 + np.log(1.0 + (lum[hi] - knee) / knee))
    base = opacities.astype(np.float64) * clipped * stab ** cfg.stability_power * dom ** cfg.dominance_power
    base = np.where(in_roi, base, 0.0)
    raw = np.where(in_roi, opacities.astype(np.float64) * lum * stab ** cfg.stability_power
                   * dom ** cfg.dominance_power, 0.0)
    n_tail = min(max(math.ceil(cfg.tail_fraction * roi.size), cfg.min_candidates), cfg.max_candidates)
    positive = np.flatnonzero(base > 0)
    tail = np.sort(positive[np.argsort(-base[positive], kind="stable")][:n_tail])
    out = {"n_roi": int(roi.size), "n_tail": int(tail.size), "knee": knee, "base": base, "raw": raw}
    if tail.size == 0 or k <= 0:
        out.update(index=np.zeros(0, dtype=np.int64), position=np.zeros((0, 3)), color=np.zeros((0, 3)),
                   intensity=np.zeros(0), score=np.zeros(0))
        return out
    dist = np.sqrt(((p[tail][:, None, :] - p[roi][None, :, :]) ** 2).sum(-1))  # (M, n_roi)
    shell = (dist <= cfg.peak_radius) & (dist >= cfg.peak_inner_radius)
    mean_nb = (shell * base[roi]).sum(1) / np.maximum(shell.sum(1), 1)
    eps = cfg.peak_eps * base[roi].mean() + 1e-12
    final = base[tail] * (base[tail] / (mean_nb + eps)) ** cfg.peak_power
    chosen = []
    for j in np.argsort(-final, kind="stable"):
        if len(chosen) == k:
            break
        if all(np.linalg.norm(p[tail[j]] - p[tail[c]]) >= cfg.nms_distance for c in chosen):
            chosen.append(j)
    chosen = np.array(chosen, dtype=np.int64)
    winners = tail[chosen]
    pos, col = [], []
    tail_cols = _colors_from(sh.astype(np.float64)[tail], p[tail], centroid)
    for w in winners:
        d = np.linalg.norm(p[tail] - p[w], axis=1)
        sel = ((d <= cfg.refine_radius) & (base[tail] >= cfg.refine_min_fraction * base[w])) | (tail == w)
        wts = base[tail][sel]
        pos.append((wts[:, None] * p[tail][sel]).sum(0) / wts.sum())
        col.append((wts[:, None] * tail_cols[sel]).sum(0) / wts.sum())
    inten = raw[winners]
    order = np.argsort(-inten, kind="stable")
    out.update(index=winners[order], position=np.array(pos)[order], color=np.array(col)[order],
               intensity=inten[order], score=final[chosen][order])
    return out


def linked_clusters(points, link_distance):
    """Single-linkage labels (smallest index of each cluster) by a dense distance matrix and
    repeated minimum propagation over the adjacency (O(M^2) memory: small inputs only)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    adj = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)) <= link_distance
    labels = np.arange(p.shape[0])
    while True:
        new = np.where(adj, labels[None, :], p.shape[0]).min(1)
        if np.array_equal(new, labels):
            return labels
        labels = new
