"""High-intensity light source estimation (paper section 3.1) as numba kernels.

Input: scene Gaussians as arrays, all in one world frame (positions (N, 3) float32 in scene
units, linear opacities (N,) float32, SH coefficients (N, (d+1)^2, 3) float32 in the 3DGS
basis of ``usd_gs/sh3dgs.py``, degree 0..3), the avatar's alpha-weighted centroid ``c`` (3,)
and the viewpoints ``v_1..v_V`` (V, 3) near the character (built by the caller, see
``usd_gs.relight.light_estimation.make_viewpoints``). Distances in ``cfg`` are in scene units (the wrapper
converts metres). Nothing depends on the up axis except the viewpoint layout.

The steps, with the defaults of ``usd_gs.relight.light_estimation.LightEstimationConfig``:

1. ROI: Gaussian i takes part when ``|p_i - c| <= roi_radius`` (6 m), its opacity
   ``a_i >= min_opacity`` (1/255) and all its values are finite.
2. Per-view colour (3DGS convention, direction from the viewer toward the Gaussian):
   ``col_iv = max(0, 0.5 + SH_i(normalize(p_i - v_v)))`` per channel;
   luminance ``Y_iv = 0.2126 R + 0.7152 G + 0.0722 B`` (linear Rec.709).
   Cues: ``meanY_i`` and ``maxY_i`` over the V views; angular stability
   ``stab_i = clip(1 - std_v(Y_iv) / (meanY_i + 1e-12), 0, 1)`` (population std);
   DC dominance ``dom_i = |a|^2 / (|a|^2 + sum_{k>=1,c} sh_ikc^2 / (4 pi))`` with
   ``a = 0.5 + SH_C0 sh_i0`` the view-independent colour: the share of the sphere-averaged
   squared colour that does not depend on the view (the SH basis is orthonormal, so the
   view-dependent part has mean square ``sum c_k^2 / 4 pi``). Using ``0.5 + SH_C0 f_dc`` instead
   of the raw ``f_dc`` keeps a grey Gaussian (f_dc = 0) from counting as pure view dependence.
   Degree 0 gives ``stab = dom = 1``.
3. Luminance cue ``L_i = (1 - max_weight) meanY_i + max_weight maxY_i`` (max_weight 0.25).
4. Soft clipping of outliers: knee ``K = clip_knee_factor * q`` with ``q`` the element of rank
   ``floor(clip_percentile / 100 * (n - 1))`` of the sorted ROI ``L`` values (99.9, the
   "lower" percentile); ``L'_i = L_i`` for ``L_i <= K`` else ``K (1 + log(1 + (L_i - K) / K))``
   (continuous, slope 1 at the knee, strictly increasing so the order is kept, logarithmic
   growth so a single exploding SH value cannot dwarf real emitters). No clipping if K <= 0.
5. Base score ``s_i = a_i * L'_i * stab_i^stability_power * dom_i^dominance_power`` (powers 1, 1),
   and the same with the unclipped cue, ``raw_i = a_i * L_i * stab_i^.. * dom_i^..``.
   No term depends on the Gaussian's scale or volume (no bias toward large Gaussians).
   Unit: linear luminance of the capture's radiance as seen from near the character.
6. Tail: the ``n_tail = min(max(ceil(tail_fraction n_roi), min_candidates), max_candidates)``
   (2 %, 1000, 20000) best ``s_i > 0``; ties broken by the lower index.
7. Peakness against the neighbourhood of ALL ROI Gaussians:
   ``mean_i = mean{s_j : peak_inner_radius <= |p_j - p_i| <= peak_radius}`` (0.1 m, 0.3 m;
   0 if the shell is empty; with inner radius 0 the candidate itself counts),
   ``peak_i = s_i / (mean_i + eps)`` with ``eps = peak_eps * mean_ROI(s) + 1e-12``
   (peak_eps 1.0), final score
   ``f_i = s_i * peak_i ^ peak_power`` (1). A broad emitter has neighbours as bright as itself
   (peak about 1); a compact one is surrounded by darker Gaussians (peak > 1). The inner
   radius keeps a compact emitter made of many Gaussians from being its own neighbourhood:
   with a full ball (inner 0) a 40-Gaussian lamp gets peak ~1.02 and the edge of a bright
   window (half of its ball dark wall) out-ranks it. ``eps`` of the order of the mean scene
   score bounds the peakness of isolated Gaussians (empty shell) by ``s_i / eps``.
8. Greedy NMS: visit the tail by decreasing ``f`` (ties by lower index), accept a candidate
   unless it lies closer than ``nms_distance`` (1 m) to an accepted one, stop at k.
   Steps 7-8 evaluate peakness lazily, only for candidates that can still win (exact; see
   ``_peak_nms``): in the generated 1M-Gaussian room 1 536 of the 20 000 tail candidates.
9. Per light: winner w; refinement set ``S = {j in tail : |p_j - p_w| <= refine_radius,
   s_j >= refine_min_fraction * s_w}`` (0.1 m, 0.5; always contains w);
   position = ``sum_S s_j p_j / sum_S s_j`` (float64); colour = the same weighted mean of
   ``max(0, 0.5 + SH_j(normalize(p_j - c)))`` (linear RGB the character sees; unclipped by
   step 4); intensity = ``raw_w`` (the base score without the soft clip, so that intensities
   stay proportional to the emitters' luminance even when the knee lies below them; clipping
   only shapes the selection); score = ``f_w``. Lights are returned sorted by decreasing
   intensity (ties by NMS order).

Planar emitters (windows, panels; ``usd_gs.relight.light_estimation.estimate_rect_lights``)
reuse steps 1-6 and cut the bright part of the tail into single-linkage clusters with
:func:`linked_clusters` (hash-grid neighbours within the link distance, then union-find in
:func:`link_components`).

Every kernel is deterministic: parallel loops only write per-Gaussian outputs; sums run
serially in a fixed order.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, prange

from .grid_neighbours import build_grid, grid_values, radius_neighbours, radius_sum
from .jit_options import threaded
from .sh_real import SH_C0, SH_C1, SH_C2, SH_C3
from .thread_chunks import run_chunks

LUMA = (0.2126, 0.7152, 0.0722)

STATUS_OUTSIDE = 0  # outside the ROI or below min_opacity
STATUS_IN_ROI = 1
STATUS_NONFINITE = -1  # position, opacity or an SH coefficient is NaN/Inf

_CHUNK = 256  # Gaussians per call of score_cues's parallel loop body


@njit(inline="always")
def _sh_rgb(sh, i, deg, x, y, z):
    """``0.5 + SH_i(x, y, z)`` per channel, 3DGS basis and signs (unclamped, float64).

    The basis is evaluated once and shared by the three channels."""
    r = 0.5 + SH_C0 * np.float64(sh[i, 0, 0])
    g = 0.5 + SH_C0 * np.float64(sh[i, 0, 1])
    b = 0.5 + SH_C0 * np.float64(sh[i, 0, 2])
    if deg >= 1:
        b1 = -SH_C1 * y
        b2 = SH_C1 * z
        b3 = -SH_C1 * x
        r += b1 * sh[i, 1, 0] + b2 * sh[i, 2, 0] + b3 * sh[i, 3, 0]
        g += b1 * sh[i, 1, 1] + b2 * sh[i, 2, 1] + b3 * sh[i, 3, 1]
        b += b1 * sh[i, 1, 2] + b2 * sh[i, 2, 2] + b3 * sh[i, 3, 2]
        if deg >= 2:
            xx = x * x
            yy = y * y
            zz = z * z
            b4 = SH_C2[0] * (x * y)
            b5 = SH_C2[1] * (y * z)
            b6 = SH_C2[2] * (2.0 * zz - xx - yy)
            b7 = SH_C2[3] * (x * z)
            b8 = SH_C2[4] * (xx - yy)
            r += b4 * sh[i, 4, 0] + b5 * sh[i, 5, 0] + b6 * sh[i, 6, 0] + b7 * sh[i, 7, 0] + b8 * sh[i, 8, 0]
            g += b4 * sh[i, 4, 1] + b5 * sh[i, 5, 1] + b6 * sh[i, 6, 1] + b7 * sh[i, 7, 1] + b8 * sh[i, 8, 1]
            b += b4 * sh[i, 4, 2] + b5 * sh[i, 5, 2] + b6 * sh[i, 6, 2] + b7 * sh[i, 7, 2] + b8 * sh[i, 8, 2]
            if deg >= 3:
                b9 = SH_C3[0] * y * (3.0 * xx - yy)
                b10 = SH_C3[1] * (x * y) * z
                b11 = SH_C3[2] * y * (4.0 * zz - xx - yy)
                b12 = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
                b13 = SH_C3[4] * x * (4.0 * zz - xx - yy)
                b14 = SH_C3[5] * z * (xx - yy)
                b15 = SH_C3[6] * x * (xx - 3.0 * yy)
                r += (b9 * sh[i, 9, 0] + b10 * sh[i, 10, 0] + b11 * sh[i, 11, 0] + b12 * sh[i, 12, 0]
                      + b13 * sh[i, 13, 0] + b14 * sh[i, 14, 0] + b15 * sh[i, 15, 0])
                g += (b9 * sh[i, 9, 1] + b10 * sh[i, 10, 1] + b11 * sh[i, 11, 1] + b12 * sh[i, 12, 1]
                      + b13 * sh[i, 13, 1] + b14 * sh[i, 14, 1] + b15 * sh[i, 15, 1])
                b += (b9 * sh[i, 9, 2] + b10 * sh[i, 10, 2] + b11 * sh[i, 11, 2] + b12 * sh[i, 12, 2]
                      + b13 * sh[i, 13, 2] + b14 * sh[i, 14, 2] + b15 * sh[i, 15, 2])
    return r, g, b


@njit(inline="always")
def _unit(dx, dy, dz):
    """Normalised direction; (0, 0, 1) for a zero vector (Gaussian exactly at the viewer)."""
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    if n > 0.0:
        return dx / n, dy / n, dz / n
    return 0.0, 0.0, 1.0


@njit(inline="always")
def _cues_one(i, positions, opacities, sh, deg, centroid, viewpoints, r2, min_opacity, max_weight,
              status, mean_y, max_y, stability, dominance, lum):
    """Steps 1-3 for Gaussian i (see :func:`score_cues`)."""
    k = sh.shape[1]
    nv = viewpoints.shape[0]
    inv4pi = 1.0 / (4.0 * math.pi)
    px = np.float64(positions[i, 0])
    py = np.float64(positions[i, 1])
    pz = np.float64(positions[i, 2])
    a = np.float64(opacities[i])
    finite = np.isfinite(px) and np.isfinite(py) and np.isfinite(pz) and np.isfinite(a)
    e_view = 0.0
    for j in range(k):
        for c in range(3):
            s = np.float64(sh[i, j, c])
            if not np.isfinite(s):
                finite = False
            if j > 0:
                e_view += s * s
    if not finite:
        status[i] = STATUS_NONFINITE
        return
    dx = px - centroid[0]
    dy = py - centroid[1]
    dz = pz - centroid[2]
    if dx * dx + dy * dy + dz * dz > r2 or not a >= min_opacity:
        return
    status[i] = STATUS_IN_ROI
    mu = 0.0  # Welford running mean / sum of squared deviations (stable, one pass)
    m2 = 0.0
    m_y = 0.0
    for v in range(nv):
        ux, uy, uz = _unit(px - viewpoints[v, 0], py - viewpoints[v, 1], pz - viewpoints[v, 2])
        r, g, b = _sh_rgb(sh, i, deg, ux, uy, uz)
        y = LUMA[0] * max(0.0, r) + LUMA[1] * max(0.0, g) + LUMA[2] * max(0.0, b)
        d = y - mu
        mu += d / (v + 1)
        m2 += d * (y - mu)
        if y > m_y:
            m_y = y
    std = math.sqrt(max(m2, 0.0) / nv)
    st = 1.0 - std / (mu + 1e-12)
    stability[i] = min(1.0, max(0.0, st))
    e_dc = 0.0
    for c in range(3):
        dc = 0.5 + SH_C0 * np.float64(sh[i, 0, c])
        e_dc += dc * dc
    tot = e_dc + e_view * inv4pi
    dominance[i] = e_dc / tot if tot > 0.0 else 0.0
    mean_y[i] = mu
    max_y[i] = m_y
    lum[i] = (1.0 - max_weight) * mu + max_weight * m_y


@njit(cache=True, fastmath=False)
def _cues_range(i0, i1, positions, opacities, sh, deg, centroid, viewpoints, r2, min_opacity, max_weight,
                status, mean_y, max_y, stability, dominance, lum):
    """Gaussians i0..i1-1: one chunk of :func:`score_cues`'s parallel loop. A called function, not
    an inlined body: numba types and optimises a parallel loop's body twice (measured: half the
    kernel's compile time); chunks keep the call overhead negligible."""
    for i in range(i0, i1):
        _cues_one(i, positions, opacities, sh, deg, centroid, viewpoints, r2, min_opacity, max_weight,
                  status, mean_y, max_y, stability, dominance, lum)


@njit(**threaded(), cache=True, fastmath=False)
def _cues_chunks(c0, c1, positions, opacities, sh, deg, centroid, viewpoints, r2, min_opacity, max_weight, status,
                 mean_y, max_y, stability, dominance, lum):
    """Chunks ``c0..c1-1`` of ``_CHUNK`` Gaussians of :func:`score_cues` (threads: ``thread_chunks``)."""
    n = positions.shape[0]
    for ch in range(c0, c1):
        _cues_range(np.int64(ch) * _CHUNK, min(n, (np.int64(ch) + 1) * _CHUNK), positions, opacities, sh, deg,
                    centroid, viewpoints, r2, min_opacity, max_weight, status, mean_y, max_y, stability, dominance,
                    lum)


def score_cues(positions, opacities, sh, centroid, viewpoints, roi_radius, min_opacity, max_weight):
    """Steps 1-3: per-Gaussian status and photometric cues.

    positions (N, 3) f32, opacities (N,) f32, sh (N, K, 3) f32 (K = 1, 4, 9 or 16),
    centroid (3,) f64, viewpoints (V, 3) f64 (V >= 1), roi_radius / min_opacity / max_weight floats.
    Returns ``status`` (N,) int8 (STATUS_*), ``mean_y``, ``max_y``, ``stability``, ``dominance``,
    ``lum`` (N,) float64; all zero where status != STATUS_IN_ROI.
    """
    n = positions.shape[0]
    k = sh.shape[1]
    deg = 0 if k < 4 else (1 if k < 9 else (2 if k < 16 else 3))
    status = np.zeros(n, dtype=np.int8)
    mean_y = np.zeros(n)
    max_y = np.zeros(n)
    stability = np.zeros(n)
    dominance = np.zeros(n)
    lum = np.zeros(n)
    r2 = float(roi_radius) * float(roi_radius)
    run_chunks(_cues_chunks, (n + _CHUNK - 1) // _CHUNK, positions, opacities, sh, deg,
               np.asarray(centroid, np.float64), np.ascontiguousarray(viewpoints, np.float64), r2, float(min_opacity),
               float(max_weight), status, mean_y, max_y, stability, dominance, lum)
    return status, mean_y, max_y, stability, dominance, lum


@njit(cache=True, fastmath=False)  # serial: see jit_options.SERIAL_NOTE
def base_scores(status, lum, stability, dominance, opacities, knee, stability_power, dominance_power):
    """Steps 4-5: base scores from the soft-clipped and from the raw luminance cue.

    Returns ``(score, raw)`` (N,) float64, zero outside the ROI; ``raw`` skips the clipping.
    """
    n = status.shape[0]
    out = np.zeros(n)
    raw = np.zeros(n)
    for i in prange(n):
        if status[i] != STATUS_IN_ROI:
            continue
        x = lum[i]
        if knee > 0.0 and x > knee:
            x = knee * (1.0 + math.log1p((x - knee) / knee))
        f = np.float64(opacities[i])
        if stability_power != 0.0:
            f *= stability[i] ** stability_power
        if dominance_power != 0.0:
            f *= dominance[i] ** dominance_power
        out[i] = f * x
        raw[i] = f * lum[i]
    return out, raw


def select_tail(scores: np.ndarray, n_tail: int) -> np.ndarray:
    """Step 6: indices (ascending) of the ``n_tail`` largest positive scores, ties to lower index.

    Vectorised numpy, O(N) (``np.partition`` for the threshold; numba's partition is slow to compile).
    """
    positive = np.flatnonzero(scores > 0.0)
    n_tail = min(int(n_tail), positive.size)
    if n_tail <= 0:
        return np.zeros(0, dtype=np.int64)
    vals = scores[positive]
    thr = np.partition(vals, vals.size - n_tail)[vals.size - n_tail]  # the n_tail-th largest value
    above = positive[vals > thr]
    equal = positive[vals == thr][:n_tail - above.size]
    return np.sort(np.concatenate([above, equal])).astype(np.int64)


def greedy_nms(positions, final, k, min_distance):
    """Step 8: positions (M, 3) float, final (M,) scores. Returns accepted rows (<= k), best first.

    The visiting order (decreasing score, ties by lower index) is a stable NumPy argsort: numba's
    own mergesort costs about 1 s of compile time for a few microseconds of work."""
    order = np.argsort(-np.asarray(final), kind="stable").astype(np.int64)
    return _greedy_nms_ordered(positions, order, int(k), float(min_distance))


@njit(cache=True, fastmath=False)
def _greedy_nms_ordered(positions, order, k, min_distance):
    """Greedy NMS visiting rows in ``order`` (M,) int64 (see :func:`greedy_nms`)."""
    m = order.shape[0]
    chosen = np.empty(min(k, m), dtype=np.int64)
    nc = 0
    d2min = min_distance * min_distance
    for t in range(m):
        if nc >= k:
            break
        j = order[t]
        ok = True
        for q in range(nc):
            w = chosen[q]
            dx = np.float64(positions[j, 0]) - positions[w, 0]
            dy = np.float64(positions[j, 1]) - positions[w, 1]
            dz = np.float64(positions[j, 2]) - positions[w, 2]
            if dx * dx + dy * dy + dz * dz < d2min:
                ok = False
                break
        if ok:
            chosen[nc] = j
            nc += 1
    return chosen[:nc]


@njit(cache=True, fastmath=False)
def refine_lights(positions, sh, base, tail, winners, centroid, refine_radius, min_fraction):
    """Step 9: score-weighted position and colour toward the character around each winner.

    tail (M,) Gaussian indices, winners (L,) Gaussian indices. Returns positions (L, 3) and
    colours (L, 3) float64.
    """
    k = sh.shape[1]
    deg = 0 if k < 4 else (1 if k < 9 else (2 if k < 16 else 3))
    nl = winners.shape[0]
    pos = np.zeros((nl, 3))
    col = np.zeros((nl, 3))
    r2 = refine_radius * refine_radius
    for q in range(nl):
        w = winners[q]
        wsum = 0.0
        for t in range(tail.shape[0]):
            j = tail[t]
            dx = np.float64(positions[j, 0]) - positions[w, 0]
            dy = np.float64(positions[j, 1]) - positions[w, 1]
            dz = np.float64(positions[j, 2]) - positions[w, 2]
            if j != w and (dx * dx + dy * dy + dz * dz > r2 or base[j] < min_fraction * base[w]):
                continue
            s = base[j]
            ux, uy, uz = _unit(positions[j, 0] - centroid[0], positions[j, 1] - centroid[1],
                               positions[j, 2] - centroid[2])
            r, g, b = _sh_rgb(sh, j, deg, ux, uy, uz)
            col[q, 0] += s * max(0.0, r)
            col[q, 1] += s * max(0.0, g)
            col[q, 2] += s * max(0.0, b)
            for c in range(3):
                pos[q, c] += s * np.float64(positions[j, c])
            wsum += s
        for c in range(3):
            pos[q, c] /= wsum
            col[q, c] /= wsum
    return pos, col


def lower_percentile(values: np.ndarray, percentile: float) -> float:
    """Element of rank ``floor(percentile / 100 * (n - 1))`` of sorted ``values`` (numpy 'lower')."""
    n = values.shape[0]
    if n == 0:
        return 0.0
    rank = int(np.floor(percentile / 100.0 * (n - 1)))
    rank = min(max(rank, 0), n - 1)
    return float(np.partition(values, rank)[rank])


def estimate_lights_arrays(positions, opacities, sh, centroid, viewpoints, k, cfg, lazy=True,
                           peak_batch=512) -> dict:
    """Run steps 1-9 (see the module docstring) on arrays.

    positions (N, 3), opacities (N,), sh (N, K, 3) (converted to contiguous float32 if needed),
    centroid (3,), viewpoints (V, 3) in scene units, k >= 0 lights; ``cfg`` has the attributes
    of ``usd_gs.relight.light_estimation.LightEstimationConfig`` with distances already in scene units.

    Returns a dict of numpy arrays: ``index`` (L,) winner Gaussian indices, ``position`` (L, 3),
    ``color`` (L, 3), ``intensity`` (L,), ``score`` (L,) (all float64, sorted by decreasing
    intensity, L <= k), diagnostics ``n_roi``, ``n_tail``, ``n_peak_evaluated``, ``knee``,
    ``status`` (N,) int8, ``base`` and ``raw`` (N,) float64 scores (clipped / unclipped),
    ``timings`` (seconds per stage: cues, clip_tail, peak_nms, refine).
    Non-finite inputs get status STATUS_NONFINITE and are ignored; the caller decides whether
    to raise. ``lazy=False`` evaluates peakness for every tail candidate (same lights);
    ``peak_batch`` is the first lazy batch size (same lights for any value).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float32)
    opacities = np.ascontiguousarray(opacities, dtype=np.float32)
    sh = np.ascontiguousarray(sh, dtype=np.float32)
    centroid = np.ascontiguousarray(centroid, dtype=np.float64).reshape(3)
    viewpoints = np.ascontiguousarray(viewpoints, dtype=np.float64).reshape(-1, 3)
    if viewpoints.shape[0] == 0:
        raise ValueError("need at least one viewpoint")
    t0 = time.perf_counter()
    status, _my, _xy, stab, dom, lum = score_cues(positions, opacities, sh, centroid, viewpoints,
                                                  float(cfg.roi_radius), float(cfg.min_opacity),
                                                  float(cfg.max_weight))
    t1 = time.perf_counter()
    roi = np.flatnonzero(status == STATUS_IN_ROI)
    knee = float(cfg.clip_knee_factor) * lower_percentile(lum[roi], float(cfg.clip_percentile))
    base, raw = base_scores(status, lum, stab, dom, opacities, knee, float(cfg.stability_power),
                            float(cfg.dominance_power))
    n_roi = int(roi.shape[0])
    n_tail = min(max(math.ceil(cfg.tail_fraction * n_roi), int(cfg.min_candidates)), int(cfg.max_candidates))
    tail = select_tail(base, n_tail)
    t2 = time.perf_counter()
    timings = {"cues": t1 - t0, "clip_tail": t2 - t1, "peak_nms": 0.0, "refine": 0.0}
    empty = np.zeros((0, 3))
    result = {"index": np.zeros(0, dtype=np.int64), "position": empty, "color": empty.copy(),
              "intensity": np.zeros(0), "score": np.zeros(0), "n_roi": n_roi, "n_tail": int(tail.shape[0]),
              "n_peak_evaluated": 0, "knee": knee, "status": status, "base": base, "raw": raw,
              "timings": timings}
    if tail.shape[0] == 0 or k <= 0:
        return result
    final, n_eval, rows = _peak_nms(positions, base, roi, tail, int(k), cfg, lazy, int(peak_batch))
    winners = tail[rows]
    t3 = time.perf_counter()
    pos, col = refine_lights(positions, sh, base, tail, winners, centroid, float(cfg.refine_radius),
                             float(cfg.refine_min_fraction))
    timings.update(peak_nms=t3 - t2, refine=time.perf_counter() - t3)
    inten = raw[winners]
    order = np.argsort(-inten, kind="stable")
    result.update(index=winners[order], position=pos[order], color=col[order], intensity=inten[order],
                  score=final[rows][order], n_peak_evaluated=n_eval)
    return result


def _peak_nms(positions, base, roi, tail, k, cfg, lazy=True, first_batch=512):
    """Steps 7-8. Returns (final (M,) with NaN where not evaluated, number evaluated, chosen rows).

    Lazy evaluation: since every neighbourhood mean is >= 0, ``ub = s (s / eps)^p`` bounds the
    final score from above. Greedy NMS is run on ``v = final`` where known, else ``ub``; when all
    the lights it picks are known, the result equals NMS on the exact finals (each pick has an
    exact value >= every other remaining ``v`` >= that candidate's exact final, and ties resolve
    by the same lower-index rule). Otherwise the picked unknowns plus the next batch of unknowns
    by decreasing ``ub`` (``first_batch``, doubling, so at most about log2(M) rounds and at most
    about twice the needed evaluations) are evaluated in parallel and NMS is re-run. With
    ``lazy=False`` every candidate is evaluated first (same result; for tests).
    """
    s_t = base[tail]
    m = tail.shape[0]
    p = float(cfg.peak_power)
    eps = float(cfg.peak_eps) * float(base[roi].mean()) + 1e-12
    tail_pos = positions[tail]
    if p == 0.0:
        return s_t.copy(), 0, greedy_nms(tail_pos, s_t, k, float(cfg.nms_distance))
    ub = s_t * (s_t / eps) ** p
    final = np.full(m, np.nan)
    known = np.zeros(m, dtype=np.bool_)
    radius = float(cfg.peak_radius)
    # cells of radius / 3: most cells of the shell are then summed whole (see grid_neighbours)
    grid = build_grid(positions[roi], radius / 3.0)
    gv = grid_values(grid, base[roi])

    def evaluate(rows):
        sums, counts = radius_sum(grid, tail_pos[rows], radius, gv, inner=float(cfg.peak_inner_radius))
        mean = sums / np.maximum(counts, 1)
        final[rows] = s_t[rows] * (s_t[rows] / (mean + eps)) ** p
        known[rows] = True

    if not lazy:
        evaluate(np.arange(m))
    by_ub = np.argsort(-ub, kind="stable")
    batch = max(1, first_batch)
    while True:
        rows = greedy_nms(tail_pos, np.where(known, final, ub), k, float(cfg.nms_distance))
        missing = rows[~known[rows]]
        if missing.size == 0:
            return final, int(known.sum()), rows
        more = by_ub[~known[by_ub]][:batch]  # the next unknowns by decreasing ub
        batch *= 2
        evaluate(np.unique(np.concatenate([missing, more])))


# ----------------------------------------------------------------------------- planar emitters
@njit(cache=True, fastmath=False)  # serial: union-find (see jit_options.SERIAL_NOTE)
def link_components(offsets, indices):
    """Connected components of a graph given as CSR: the neighbours of node i are
    ``indices[offsets[i]:offsets[i + 1]]`` (offsets (M+1,) int64, indices int64 in [0, M)).

    Returns labels (M,) int64: each node's label is the smallest node index of its component
    (deterministic: union by the smaller root, path halving)."""
    m = offsets.shape[0] - 1
    parent = np.arange(m)
    for i in range(m):
        for t in range(offsets[i], offsets[i + 1]):
            a = i
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            b = indices[t]
            while parent[b] != b:
                parent[b] = parent[parent[b]]
                b = parent[b]
            if a < b:
                parent[b] = a
            elif b < a:
                parent[a] = b
    labels = np.empty(m, dtype=np.int64)
    for i in range(m):
        a = i
        while parent[a] != a:
            a = parent[a]
        labels[i] = a
    return labels


def linked_clusters(points: np.ndarray, link_distance: float) -> np.ndarray:
    """(M,) int64 single-linkage cluster labels of ``points`` (M, 3): two points are linked when
    ``|p - q| <= link_distance`` (same units); a label is the smallest index of its cluster."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    r = max(float(link_distance), 1e-12)
    grid = build_grid(pts, r)
    offsets, indices = radius_neighbours(grid, pts, r)
    return link_components(offsets, indices.astype(np.int64))
