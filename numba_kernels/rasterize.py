"""CPU 3D Gaussian Splatting rasteriser (numba): the standard 3DGS forward pass.

Image formation (shared by :mod:`numba_kernels.reference.rasterize`, which implements the
same definition by brute force in float64):

1. View transform. Each camera k is given as ``view_rot[k]`` (3x3) and ``view_t[k]`` (3,)
   mapping a world point ``p`` to *view coordinates* ``q = view_rot @ p + view_t`` with
   ``q = (x right, y down, z depth)``; ``z > 0`` in front of the camera. (For a USD camera,
   which looks down its local -Z with +Y up, ``view_rot = diag(1, -1, -1) @ R^T`` where
   ``R`` is world-from-camera; see ``usd_gs/render/camera.py``.) Pixel coordinates of the centre:
   ``u = fx x / z + cx``, ``v = fy y / z + cy``; the image spans ``[0, W] x [0, H]`` and
   pixel (row i, column j) has its centre at ``(j + 0.5, i + 0.5)``.
2. Culling: a Gaussian is dropped for a camera when ``z <= near`` or ``z > far``, when its
   opacity is below 1/255, when its 2D covariance is singular, or when its support (below)
   contains no pixel centre of the image.
3. EWA projection (Zwicker et al. 2002, as in graphdeco-inria diff-gaussian-rasterization):
   ``J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]]`` with ``x'/z`` and ``y'/z``
   clamped to the guard band ``c +- guard * h`` where ``[c - h, c + h]`` is the image's
   extent in ``x/z`` (resp. ``y/z``); ``guard = 1.3`` as in 3DGS. 2D covariance
   ``Sigma2 = J V Sigma V^T J^T + dilation * I`` (``V = view_rot``, ``Sigma = R diag(s)^2 R^T``,
   ``dilation = 0.3`` px^2 is the 3DGS low-pass filter), conic ``= Sigma2^-1``.
4. Support: pixel centres with Mahalanobis distance ``d^T conic d <= 9`` (the 3-sigma ellipse).
   3DGS evaluates every pixel of the 16x16 tiles that the square of radius
   ``ceil(3 sqrt(lambda_max))`` touches; we cut at the ellipse instead so that the image
   does not depend on the tile size (the difference is at most ``opacity * exp(-4.5)`` for
   each pixel just outside the ellipse). Tile binning uses the ellipse's exact bounding box
   ``3 sqrt(Sigma2_xx)`` by ``3 sqrt(Sigma2_yy)`` (tighter than the 3DGS square for
   elongated splats), shrunk further where ``opacity * exp(-q/2) < 1/255`` anyway.
5. Per pixel: ``alpha = min(0.99, opacity exp(-q/2))``; skipped when ``alpha < 1/255``.
   Front-to-back in order of increasing ``float32(z)``, ties broken by lower Gaussian
   index: ``C += c alpha T``, ``T *= 1 - alpha``; a Gaussian that would bring ``T`` below
   1e-4 is not blended and ends the pixel (3DGS early termination).
6. Colour ``c = max(0, 0.5 + SH(dir))`` in the 3DGS basis (``usd_gs/sh3dgs.py``), degree
   0..3, with ``dir = normalise(mu - camera centre)`` (world space).
7. Outputs per camera: premultiplied colour ``sum c alpha T`` (f32, add ``T * background``
   for the final image), final transmittance ``T`` (alpha = 1 - T) and the expected depth
   ``sum(z alpha T) / (1 - T)`` (the weights sum to 1 - T exactly; 0 where nothing blended).

Pipeline (all numba, prange over independent work):
1. ``_cull`` (prange over Gaussians): a conservative per-camera visibility bit mask from a
   cheap bound on the footprint (no quaternion work): off-screen splats, and sub-pixel splats
   whose bounding square holds no pixel centre (most of a far scene's in a small probe face),
   cost ~30 flops instead of a full projection.
2. prefix sum of the visible counts per chunk of ``_CHUNK`` Gaussians, then ``_write_entries``
   (prange over Gaussians): the full EWA projection and SH colour of each visible (Gaussian, camera) pair, written to a
   compacted 64-byte float32 record (colour evaluated once per camera centre, so the six
   cube faces share it).
3. ``_bin_tiles``: parallel stable counting sort of entries into tiles (per-chunk
   histograms, prefix sum, scatter); no Python lists.
4. ``_blend`` (prange over tiles in a fixed shuffled order for load balance): stable radix
   sort of the tile's list (which is in increasing entry index) by float32 depth bits, so
   the order is deterministic (depth, then Gaussian index); records are copied in batches of
   64 into a local buffer (overlapping the cache misses of the random reads); then blend
   Gaussian-major: each splat visits only the pixels of its ellipse's exact per-row span
   inside the tile, skips rows whose pixels have all terminated, and the tile stops once
   every pixel has terminated. The result does not depend on the tile size or thread count.
Several cameras of equal size (e.g. the six cube faces) are rendered in one call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .jit_options import threaded
from .quaternion import quat_to_rotation
from .sh_real import SH_C0, SH_C1, SH_C2, SH_C3
from .thread_chunks import run_chunks

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
SUPPORT_Q = 9.0  # 3 sigma
#: the largest support cut ``_support_q`` returns, and its square root
SUPPORT_Q_MAX = SUPPORT_Q * (1.0 + 1e-5)
SQRT_Q_MAX = math.sqrt(SUPPORT_Q_MAX)
DEFAULT_DILATION = 0.3
DEFAULT_GUARD = 1.3
TILE = 16

# entry record columns (float32, padded to 16 = 64 bytes): centre (px), conic, opacity,
# colour, view depth, pixel bounding box (inclusive), support cut q
_MX, _MY, _CA, _CB, _CC, _OP, _R, _G, _B, _Z, _J0, _J1, _I0, _I1, _QC = range(15)
_NF = 16
_GATHER = 64  # records copied per batch in _blend_tile
_CHUNK = 256  # Gaussians per call of the parallel loop's body in _write_entries (_write_range)
_CULL_ROWS = 512  # entries _cull gathers into columns at a time (its work arrays stay in the L1/L2 cache)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _support_q(opacity):
    """Largest Mahalanobis distance^2 where alpha can reach 1/255 (<= 9), with a small
    conservative margin (it only sizes bounding boxes); -1 when opacity < 1/255."""
    if not opacity >= ALPHA_MIN:
        return -1.0
    q = 2.0 * math.log(opacity / ALPHA_MIN)
    q = q * (1.0 + 1e-5) + 1e-5
    return min(SUPPORT_Q * (1.0 + 1e-5), q)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _pixel_range(m, e, n):
    """Inclusive pixel index range with centres (k + 0.5) in [m - e, m + e], clamped to [0, n-1];
    empty (hi < lo) when m or e is not finite."""
    if not (math.isfinite(m) and math.isfinite(e)):
        return 0, -1
    lo = math.ceil(m - e - 0.5)
    hi = math.floor(m + e - 0.5)
    if lo < 0:
        lo = 0
    if hi > n - 1:
        hi = n - 1
    return int(lo), int(hi)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _misses_centres(m, a):
    """True when no pixel centre ``k + 0.5`` lies within ``sqrt(SUPPORT_Q_MAX a) (1 + 1e-6) + 1e-6`` of
    ``m``: the largest half-extent the cull's ``sqrt(q a) (1 + 1e-6) + 1e-6`` can take (``q`` <=
    ``_support_q``'s cap), so :func:`_pixel_range` of any such extent is empty - decided without the
    support's log and the square root (most sub-pixel splats of a far scene end here). The nearest
    centre is taken without the image's bounds (which only shrink the range), with a margin far
    above the rounding of ``_pixel_range``'s own sums. False where anything is not finite."""
    t = m - 0.5
    d = abs(t - math.floor(t + 0.5)) - (1e-6 + 1e-9)
    return d > 0.0 and d * d > SUPPORT_Q_MAX * a * ((1.0 + 1e-6) ** 2 * (1.0 + 1e-12))


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _jacobian(x, y, z, intr, clamp):
    """Non-zero entries (j00, j02, j11, j12) of the projection Jacobian at the point clamped
    to the guard band ``clamp = (x/z min, x/z max, y/z min, y/z max)``."""
    iz = 1.0 / z
    tx = min(clamp[1], max(clamp[0], x * iz))
    ty = min(clamp[3], max(clamp[2], y * iz))
    return intr[0] * iz, -intr[0] * tx * iz, intr[1] * iz, -intr[1] * ty * iz


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _rotation_scale(qw, qx, qy, qz, sx, sy, sz):
    """R diag(s) (row-major 9-tuple) for the normalised quaternion (w, x, y, z); zero or
    non-finite -> identity (``quaternion.quat_to_rotation``)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotation(qw, qx, qy, qz)
    sx = abs(sx)
    sy = abs(sy)
    sz = abs(sz)
    return (r00 * sx, r01 * sy, r02 * sz,
            r10 * sx, r11 * sy, r12 * sz,
            r20 * sx, r21 * sy, r22 * sz)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _project_full(x, y, z, rs, vr, intr, clamp, width, height, dilation, qcut):
    """EWA projection. Returns (ok, u, v, conic_a, conic_b, conic_c, j0, j1, i0, i1, comp) with
    ``comp = sqrt(det(Sigma2 - dilation I) / det(Sigma2))``, the opacity factor that keeps a
    dilated splat's integral equal to the undilated one (antialiased mode)."""
    j00, j02, j11, j12 = _jacobian(x, y, z, intr, clamp)
    # M = J V (2x3)
    m00 = j00 * vr[0, 0] + j02 * vr[2, 0]
    m01 = j00 * vr[0, 1] + j02 * vr[2, 1]
    m02 = j00 * vr[0, 2] + j02 * vr[2, 2]
    m10 = j11 * vr[1, 0] + j12 * vr[2, 0]
    m11 = j11 * vr[1, 1] + j12 * vr[2, 1]
    m12 = j11 * vr[1, 2] + j12 * vr[2, 2]
    # A = M R diag(s); Sigma2 = A A^T + dilation I
    a00 = m00 * rs[0] + m01 * rs[3] + m02 * rs[6]
    a01 = m00 * rs[1] + m01 * rs[4] + m02 * rs[7]
    a02 = m00 * rs[2] + m01 * rs[5] + m02 * rs[8]
    a10 = m10 * rs[0] + m11 * rs[3] + m12 * rs[6]
    a11 = m10 * rs[1] + m11 * rs[4] + m12 * rs[7]
    a12 = m10 * rs[2] + m11 * rs[5] + m12 * rs[8]
    ca = a00 * a00 + a01 * a01 + a02 * a02 + dilation
    cb = a00 * a10 + a01 * a11 + a02 * a12
    cc = a10 * a10 + a11 * a11 + a12 * a12 + dilation
    det = ca * cc - cb * cb
    if not (det > 0.0 and math.isfinite(det)):
        return (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0, -1, 0, -1, 0.0)
    u = intr[0] * x / z + intr[2]
    v = intr[1] * y / z + intr[3]
    j0, j1 = _pixel_range(u, math.sqrt(qcut * ca), width)
    i0, i1 = _pixel_range(v, math.sqrt(qcut * cc), height)
    if j1 < j0 or i1 < i0:
        return (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0, -1, 0, -1, 0.0)
    idet = 1.0 / det
    det0 = (ca - dilation) * (cc - dilation) - cb * cb
    comp = math.sqrt(det0 * idet) if det0 > 0.0 else 0.0
    return (True, u, v, cc * idet, -cb * idet, ca * idet, j0, j1, i0, i1, comp)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _sh_color(sh, g, dx, dy, dz):
    """(r, g, b) = max(0, 0.5 + SH(dir)) for Gaussian g, dir = (dx, dy, dz) unit (3DGS basis)."""
    k = sh.shape[1]
    r = SH_C0 * np.float64(sh[g, 0, 0])
    gg = SH_C0 * np.float64(sh[g, 0, 1])
    b = SH_C0 * np.float64(sh[g, 0, 2])
    if k >= 4:
        b1 = -SH_C1 * dy
        b2 = SH_C1 * dz
        b3 = -SH_C1 * dx
        r += b1 * sh[g, 1, 0] + b2 * sh[g, 2, 0] + b3 * sh[g, 3, 0]
        gg += b1 * sh[g, 1, 1] + b2 * sh[g, 2, 1] + b3 * sh[g, 3, 1]
        b += b1 * sh[g, 1, 2] + b2 * sh[g, 2, 2] + b3 * sh[g, 3, 2]
    if k >= 9:
        xx = dx * dx
        yy = dy * dy
        zz = dz * dz
        xy = dx * dy
        yz = dy * dz
        xz = dx * dz
        basis = (SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy))
        for m in range(5):
            r += basis[m] * sh[g, 4 + m, 0]
            gg += basis[m] * sh[g, 4 + m, 1]
            b += basis[m] * sh[g, 4 + m, 2]
        if k >= 16:
            basis3 = (SH_C3[0] * dy * (3.0 * xx - yy), SH_C3[1] * xy * dz, SH_C3[2] * dy * (4.0 * zz - xx - yy),
                      SH_C3[3] * dz * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * dx * (4.0 * zz - xx - yy),
                      SH_C3[5] * dz * (xx - yy), SH_C3[6] * dx * (xx - 3.0 * yy))
            for m in range(7):
                r += basis3[m] * sh[g, 9 + m, 0]
                gg += basis3[m] * sh[g, 9 + m, 1]
                b += basis3[m] * sh[g, 9 + m, 2]
    r += 0.5
    gg += 0.5
    b += 0.5
    # max(0, .) that also maps NaN to 0
    return (r if r > 0.0 else 0.0), (gg if gg > 0.0 else 0.0), (b if b > 0.0 else 0.0)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _centre_and_bounds(x, y, z, smax, fx, fy, cx, cy, l0, l1, l2, l3, dilation):
    """``(u, v, ax, ay)``: the projected centre and the squared half-extent bounds along u and v
    before the support factor (``_cull``'s docstring: ``smax^2 |J_row|^2 + dilation`` with the
    Jacobian's guard-band clamp ``l0..l3``), written without branches for the vectorised passes."""
    iz = 1.0 / z
    u = fx * x * iz + cx
    v = fy * y * iz + cy
    xi = x * iz
    yi = y * iz
    tx = xi if xi > l0 else l0
    tx = tx if tx < l1 else l1
    ty = yi if yi > l2 else l2
    ty = ty if ty < l3 else l3
    s2 = smax * smax
    return u, v, s2 * (fx * iz) ** 2 * (1.0 + tx * tx) + dilation, s2 * (fy * iz) ** 2 * (1.0 + ty * ty) + dilation


@njit(cache=True, fastmath=False, error_model="numpy")
def _early_pass(m, px_, py_, pz_, smax_, cams, k, width, height, sdil, dilation, out):
    """``out[j]``: camera ``k`` keeps rows ``j < m`` of the gathered centres and largest scales
    after the cull's tests that need no log or square root (``_cull``'s docstring: depth range,
    division-free side rejects, ``_misses_centres``), the same float64 operations in the same order
    as those tests; written without an early exit, so that the loop vectorises."""
    c0, c1, c2, c3, c4, c5 = cams[k, 0], cams[k, 1], cams[k, 2], cams[k, 3], cams[k, 4], cams[k, 5]
    c6, c7, c8, t0, t1, t2 = cams[k, 6], cams[k, 7], cams[k, 8], cams[k, 9], cams[k, 10], cams[k, 11]
    fx, fy, cx, cy = cams[k, 12], cams[k, 13], cams[k, 14], cams[k, 15]
    near, far = cams[k, 16], cams[k, 17]
    l0, l1, l2, l3 = cams[k, 18], cams[k, 19], cams[k, 20], cams[k, 21]
    jb = cams[k, 22]
    wr = width - 0.5
    hr = height - 0.5
    for j in range(m):
        px, py, pz, smax = px_[j], py_[j], pz_[j], smax_[j]
        z = c6 * px + c7 * py + c8 * pz + t2
        x = c0 * px + c1 * py + c2 * pz + t0
        y = c3 * px + c4 * py + c5 * pz + t1
        ez = (SQRT_Q_MAX * (smax * jb + sdil * z)) * 1.001 + 1e-3 * z
        ux = fx * x + cx * z
        vy = fy * y + cy * z
        keep = (z > near) & (z <= far)
        keep = keep & ~((ux + ez < 0.5 * z) | (ux - ez > wr * z) | (vy + ez < 0.5 * z) | (vy - ez > hr * z))
        u, v, ax, ay = _centre_and_bounds(x, y, z, smax, fx, fy, cx, cy, l0, l1, l2, l3, dilation)
        miss = _misses_centres(u, ax) | _misses_centres(v, ay)
        out[j] = keep & ~miss


@njit(cache=True, fastmath=False, error_model="numpy")
def _support_pass(m, px_, py_, pz_, smax_, qcut_, cams, k, width, height, dilation, out):
    """``out[j]``: camera ``k``'s image holds a pixel centre within the support bound of rows ``j < m``
    (``qcut_``: each row's ``_support_q``), :func:`_pixel_range` of both half-extents not empty, the
    same float64 operations in the same order as ``_cull``'s last test; vectorises as
    :func:`_early_pass`."""
    c0, c1, c2, c3, c4, c5 = cams[k, 0], cams[k, 1], cams[k, 2], cams[k, 3], cams[k, 4], cams[k, 5]
    c6, c7, c8, t0, t1, t2 = cams[k, 6], cams[k, 7], cams[k, 8], cams[k, 9], cams[k, 10], cams[k, 11]
    fx, fy, cx, cy = cams[k, 12], cams[k, 13], cams[k, 14], cams[k, 15]
    l0, l1, l2, l3 = cams[k, 18], cams[k, 19], cams[k, 20], cams[k, 21]
    for j in range(m):
        px, py, pz, smax, qcut = px_[j], py_[j], pz_[j], smax_[j], qcut_[j]
        z = c6 * px + c7 * py + c8 * pz + t2
        x = c0 * px + c1 * py + c2 * pz + t0
        y = c3 * px + c4 * py + c5 * pz + t1
        u, v, ax, ay = _centre_and_bounds(x, y, z, smax, fx, fy, cx, cy, l0, l1, l2, l3, dilation)
        ebx = math.sqrt(qcut * ax) * (1.0 + 1e-6) + 1e-6
        eby = math.sqrt(qcut * ay) * (1.0 + 1e-6) + 1e-6
        j0, j1 = _pixel_range(u, ebx, width)
        i0, i1 = _pixel_range(v, eby, height)
        out[j] = (j1 >= j0) & (i1 >= i0)


@njit(**threaded(), cache=True, fastmath=False, error_model="numpy")
def _cull(i0_, i1_, positions, scales, opacities, include, order, cams, width, height, dilation, bstart, bmask,
          vis):
    """Fill ``vis`` int64: per Gaussian (per entry ``k`` of ``order``, Gaussian ``order[k]``, when
    ``order`` is not empty), the bit mask of the cameras whose image its support may touch
    (conservative). Entries ``bstart[b] .. bstart[b+1]-1`` test only the cameras of ``bmask[b]``
    (:func:`_block_cameras`: the others reject every Gaussian of the block); entries outside the
    blocks (or with ``bstart`` empty) test every camera.

    cams (K, 23) float64 rows: view_rot (9, row-major), view_t (3), fx, fy, cx, cy, near, far,
    guard-band clamp (x/z min, max, y/z min, max), and ``A`` with ``||J||_F <= A / z`` inside the
    guard band, as built by ``rasterize``.

    A camera the splat misses by far (the other faces of a cube render, most of a wide scene) is
    rejected first without the support's log: with ``e <= sqrt(q) (smax A / z + sqrt(dilation))
    <= SQRT_Q_MAX (...)`` (the half-extent bound below, ``sqrt(a + b) <= sqrt(a) + sqrt(b)``), the
    centre's pixel ``u = fx x / z + cx`` lies left of the image by more than ``e`` when ``fx x +
    (cx - 0.5) z + SQRT_Q_MAX (smax A + sqrt(dilation) z) < 0`` (likewise right, above, below); the
    test keeps a relative margin of 1e-3 and 1e-3 px, so it rejects only what the full test
    rejects. A splat on the image whose largest possible half-extents (``_misses_centres``) hold
    no pixel centre along u or v is rejected next (a far scene's sub-pixel splats). What passes
    gets the full bound: the bounding box's half-extents along u and v are ``sqrt(q)`` times the
    square roots of the projected covariance's diagonal, ``|J_row V R S|^2 + dilation <= smax^2
    |J_row|^2 + dilation`` (V and R orthonormal), with ``|J_row0|^2 = (fx / z)^2 (1 + tx^2)`` and
    likewise for v, ``q = _support_q(opacity)``; the bit is set where both
    :func:`_pixel_range` are not empty.

    Layout: the entries are taken :data:`_CULL_ROWS` at a time; the kept ones' centres and largest
    scales are gathered into float64 columns, then each candidate camera's tests without a log
    (:func:`_early_pass`) and, for the pairs that pass, the full bound (:func:`_support_pass`) run
    as branch-free loops over those columns (vectorised), each the same float64 operations as the
    per-pair test: the bits are those of testing pair by pair.
    """
    n = positions.shape[0]
    ncam = cams.shape[0]
    use_mask = include.shape[0] == n
    use_order = order.shape[0] > 0
    sdil = math.sqrt(max(dilation, 0.0))
    nb = bstart.shape[0] - 1
    every = (np.int64(1) << ncam) - 1
    # the gathered rows' columns (centre x, y, z, largest scale, opacity) and, gathered again, those
    # of the rows some camera kept (centre, largest scale, support cut); their entries, bits, positions
    cols = np.empty((5, _CULL_ROWS))
    px, py, pz, smax, op = cols[0], cols[1], cols[2], cols[3], cols[4]
    kept_cols = np.empty((5, _CULL_ROWS))
    qx, qy, qz, qs, qcut = kept_cols[0], kept_cols[1], kept_cols[2], kept_cols[3], kept_cols[4]
    rows, bits, at = np.empty(_CULL_ROWS, np.int64), np.empty(_CULL_ROWS, np.int64), np.empty(_CULL_ROWS, np.int64)
    passed = np.empty(_CULL_ROWS, np.bool_)
    blk = np.searchsorted(bstart, i0_, side="right") - 1 if nb > 0 else -1
    e = i0_
    while e < i1_:
        # the next run of entries with one camera set: a block, or the entries outside every block
        if nb > 0 and blk < 0:
            end, cand = min(i1_, bstart[0]), every
        elif 0 <= blk < nb:
            end, cand = min(i1_, bstart[blk + 1]), bmask[blk]
        else:
            end, cand = i1_, every
        if cand == 0:
            vis[e:end] = 0
        for s0 in range(e, end if cand != 0 else e, _CULL_ROWS):
            s1 = min(end, s0 + _CULL_ROWS)
            m = 0
            for k_ in range(s0, s1):
                vis[k_] = 0
                g = order[k_] if use_order else k_
                o = np.float64(opacities[g])
                if not o >= ALPHA_MIN or (use_mask and not include[g]):  # (also drops NaN)
                    continue
                rows[m] = k_
                op[m] = min(1.0, o)
                px[m] = np.float64(positions[g, 0])
                py[m] = np.float64(positions[g, 1])
                pz[m] = np.float64(positions[g, 2])
                smax[m] = max(abs(np.float64(scales[g, 0])), max(abs(np.float64(scales[g, 1])),
                                                                 abs(np.float64(scales[g, 2]))))
                bits[m] = 0
                m += 1
            for k in range(ncam):
                if (cand >> k) & 1:
                    _early_pass(m, px, py, pz, smax, cams, k, width, height, sdil, dilation, passed)
                    bit = np.int64(1) << k
                    for j in range(m):
                        if passed[j]:
                            bits[j] |= bit
            kept = 0
            seen = np.int64(0)
            for j in range(m):
                if bits[j] != 0:
                    at[kept] = j
                    qx[kept], qy[kept], qz[kept], qs[kept] = px[j], py[j], pz[j], smax[j]
                    qcut[kept] = _support_q(op[j])
                    seen |= bits[j]
                    kept += 1
            for k in range(ncam):
                if (seen >> k) & 1:
                    _support_pass(kept, qx, qy, qz, qs, qcut, cams, k, width, height, dilation, passed)
                    clear = ~(np.int64(1) << k)
                    for t in range(kept):
                        if not passed[t]:
                            bits[at[t]] &= clear
            for j in range(m):
                vis[rows[j]] = bits[j]
        e = end
        blk += 1


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _never_below(g0, g1, g2, h, cs, c, radius, smax):
    """True when ``g . p + h + cs s < 0`` holds for every point ``p`` within ``radius`` of ``c`` and
    every ``0 <= s <= smax`` (``cs >= 0``): its largest value there, ``g . c + |g| radius + h + cs
    smax``, is below zero by more than a relative 1e-6 of the terms' sizes (the cull evaluates the
    same linear form per Gaussian in float64: its rounding is far smaller). False where anything
    is not finite."""
    gc = g0 * c[0] + g1 * c[1] + g2 * c[2]
    gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    top = gc + gn * radius + h + cs * smax
    size = abs(gc) + gn * (abs(c[0]) + abs(c[1]) + abs(c[2]) + radius) + abs(h) + cs * smax
    return top < -1e-6 * size and math.isfinite(size)


@njit(cache=True, error_model="numpy")  # serial: see jit_options.SERIAL_NOTE
def _block_cameras(cams, width, height, dilation, centres, radii, smax):
    """(B,) int64 camera bit masks: camera k is left out of block b's mask only when the cull's
    division-free reject (``_cull``) drops every Gaussian whose centre lies within ``radii[b]`` of
    ``centres[b]`` and whose largest ``|scale|`` is at most ``smax[b]``: the centre's depth range
    lies before ``near`` or beyond ``far``, or one of the four sides' reject forms (linear in the
    centre and the scale) stays negative over the whole ball. Each other camera stays in the mask."""
    nb = centres.shape[0]
    ncam = cams.shape[0]
    sdil = math.sqrt(max(dilation, 0.0))
    kappa = 1.001 * SQRT_Q_MAX * sdil + 1e-3  # ez = cs smax + kappa z (the cull's bound)
    out = np.zeros(nb, np.int64)
    for b in range(nb):
        c = centres[b]
        r = radii[b] * (1.0 + 1e-9)
        s = smax[b]
        bits = np.int64(0)
        for k in range(ncam):
            cs = 1.001 * SQRT_Q_MAX * cams[k, 22]
            z0, z1, z2, tz = cams[k, 6], cams[k, 7], cams[k, 8], cams[k, 11]
            # depth z = (z0, z1, z2) . p + tz before near everywhere (z - near < 0), or beyond far (far - z < 0)
            off = (_never_below(z0, z1, z2, tz - cams[k, 16], 0.0, c, r, 0.0)
                   or _never_below(-z0, -z1, -z2, cams[k, 17] - tz, 0.0, c, r, 0.0))
            for axis in range(2):  # u (x, fx, cx, width), then v (y, fy, cy, height)
                if off:
                    break
                q0, q1, q2, tq = cams[k, 3 * axis], cams[k, 3 * axis + 1], cams[k, 3 * axis + 2], cams[k, 9 + axis]
                f, cc = cams[k, 12 + axis], cams[k, 14 + axis]
                size = width if axis == 0 else height
                lo = cc + kappa - 0.5  # before the first pixel centre: f q + cc z + ez - z / 2 < 0
                hi = size - 0.5 - cc + kappa  # past the last one: (size - 1/2) z - f q - cc z + ez < 0
                off = (_never_below(f * q0 + lo * z0, f * q1 + lo * z1, f * q2 + lo * z2, f * tq + lo * tz, cs, c, r, s)
                       or _never_below(hi * z0 - f * q0, hi * z1 - f * q1, hi * z2 - f * q2, hi * tz - f * tq, cs, c,
                                       r, s))
            if not off:
                bits |= np.int64(1) << k
        out[b] = bits
    return out


@njit(cache=True, error_model="numpy")
def _popcount(x):
    c = 0
    while x:
        x &= x - 1
        c += 1
    return c


@njit(cache=True, error_model="numpy")
def _visible_offsets(vis, off):
    """Fill ``off`` (C+1,) with the exclusive prefix sum of the camera counts of ``vis``'s chunks
    of ``_CHUNK`` Gaussians (C chunks): the first entry of each chunk; ``off[C]`` is the total."""
    n = vis.shape[0]
    acc = 0
    for c in range(off.shape[0] - 1):
        off[c] = acc
        for g in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            b = vis[g]
            if b != 0:
                acc += _popcount(b)
    off[off.shape[0] - 1] = acc


@njit(cache=True, error_model="numpy")
def _increasing_within(order, n):
    """True when ``order`` holds strictly increasing indices in ``[0, n)``."""
    last = -1
    for k in range(order.shape[0]):
        g = order[k]
        if g <= last or g >= n:
            return False
        last = g
    return True


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _write_gaussian(g, e, bits, positions, quats, scales, opacities, sh, view_rot, view_t, intr, clamp, cam_pos,
                    width, height, dilation, antialiased, rec, info, depth32):
    """Entries ``e``, ``e + 1``... of Gaussian g for the cameras in ``bits`` (see ``_write_entries``)."""
    ncam = view_rot.shape[0]
    op = min(1.0, np.float64(opacities[g]))  # >= 1/255 (checked by _cull)
    qcut = _support_q(op)
    px = np.float64(positions[g, 0])
    py = np.float64(positions[g, 1])
    pz = np.float64(positions[g, 2])
    rs = _rotation_scale(np.float64(quats[g, 0]), np.float64(quats[g, 1]), np.float64(quats[g, 2]),
                         np.float64(quats[g, 3]), np.float64(scales[g, 0]), np.float64(scales[g, 1]),
                         np.float64(scales[g, 2]))
    last = -1
    col = (0.0, 0.0, 0.0)
    for k in range(ncam):
        if not (bits >> k) & 1:
            continue
        vr = view_rot[k]
        x = vr[0, 0] * px + vr[0, 1] * py + vr[0, 2] * pz + view_t[k, 0]
        y = vr[1, 0] * px + vr[1, 1] * py + vr[1, 2] * pz + view_t[k, 1]
        z = vr[2, 0] * px + vr[2, 1] * py + vr[2, 2] * pz + view_t[k, 2]
        res = _project_full(x, y, z, rs, vr, intr[k], clamp[k], width, height, dilation, qcut)
        if not res[0]:
            info[e, 0] = -1
            depth32[e] = np.inf
            e += 1
            continue
        if last < 0 or (cam_pos[k, 0] != cam_pos[last, 0] or cam_pos[k, 1] != cam_pos[last, 1]
                        or cam_pos[k, 2] != cam_pos[last, 2]):
            dx = px - cam_pos[k, 0]
            dy = py - cam_pos[k, 1]
            dz = pz - cam_pos[k, 2]
            dn = math.sqrt(dx * dx + dy * dy + dz * dz)
            if dn > 0.0:
                dx /= dn
                dy /= dn
                dz /= dn
            col = _sh_color(sh, g, dx, dy, dz)
            last = k
        rec[e, _MX] = res[1]
        rec[e, _MY] = res[2]
        rec[e, _CA] = res[3]
        rec[e, _CB] = res[4]
        rec[e, _CC] = res[5]
        rec[e, _OP] = op * res[10] if antialiased else op
        rec[e, _R] = col[0]
        rec[e, _G] = col[1]
        rec[e, _B] = col[2]
        rec[e, _Z] = z
        rec[e, _J0] = res[6]
        rec[e, _J1] = res[7]
        rec[e, _I0] = res[8]
        rec[e, _I1] = res[9]
        rec[e, _QC] = qcut
        info[e, 0] = k
        info[e, 1] = res[6]
        info[e, 2] = res[7]
        info[e, 3] = res[8]
        info[e, 4] = res[9]
        depth32[e] = np.float32(z)
        e += 1


@njit(cache=True, fastmath=False, error_model="numpy")
def _write_range(g0, g1, positions, quats, scales, opacities, sh, order, vis, off, view_rot, view_t, intr, clamp,
                 cam_pos, width, height, dilation, antialiased, rec, info, depth32):
    """Entries of Gaussians g0..g1-1: one chunk of :func:`_write_entries`'s parallel loop (a called
    function, not an inlined body: numba types and optimises a parallel loop's body twice (measured: half
    the kernel's compile time); chunks keep the call overhead negligible)."""
    use_order = order.shape[0] > 0
    e = off[g0 // _CHUNK]  # (g0 starts a chunk)
    for k in range(g0, g1):
        bits = vis[k]
        if bits == 0:
            continue
        g = order[k] if use_order else k
        _write_gaussian(np.uint64(g), e, bits, positions, quats, scales, opacities, sh, view_rot, view_t, intr,
                        clamp, cam_pos, width, height, dilation, antialiased, rec, info, depth32)
        e += _popcount(bits)


@njit(cache=True, **threaded(), fastmath=False, error_model="numpy")
def _write_entries(c0, c1, positions, quats, scales, opacities, sh, order, vis, off, view_rot, view_t, intr, clamp,
                   cam_pos, width, height, dilation, antialiased, rec, info, depth32):
    """Project every (Gaussian, camera) pair that passed the cull, in Gaussian-major order, for
    the Gaussian chunks ``c0..c1-1`` (``_CHUNK`` Gaussians each; run in threads by
    ``thread_chunks.run_chunks``).

    Fills rec (M,16) float32 records (rows of rejected entries are left unset: never read),
    info (M,5) int32 (camera, or -1 when the exact test rejects it; pixel bbox j0, j1, i0, i1)
    and depth32 (M,) float32 view depth (inf when rejected).
    """
    n = vis.shape[0]
    for ch in range(c0, c1):
        _write_range(np.int64(ch) * _CHUNK, min(n, (np.int64(ch) + 1) * _CHUNK), positions, quats, scales,
                     opacities, sh, order, vis, off, view_rot, view_t, intr, clamp, cam_pos, width, height, dilation,
                     antialiased, rec, info, depth32)


@njit(cache=True, error_model="numpy")  # serial: see jit_options.SERIAL_NOTE
def _bin_tiles(info, ncam, tiles_x, tiles_y, tile, nchunks):
    """Stable counting sort of entries into tiles (per-chunk histograms, prefix sum, scatter).

    Returns tile_start (T+1,) and tile_list (P,) int32 entry indices, increasing within a tile.
    """
    m = info.shape[0]
    per_cam = tiles_x * tiles_y
    ntiles = per_cam * ncam
    bounds = np.linspace(0, m, nchunks + 1).astype(np.int64)
    hist = np.zeros((nchunks, ntiles), np.int64)
    for c in prange(nchunks):
        for r in range(bounds[c], bounds[c + 1]):
            k = info[r, 0]
            if k < 0:
                continue
            base = k * per_cam
            for ty in range(info[r, 3] // tile, info[r, 4] // tile + 1):
                for tx in range(info[r, 1] // tile, info[r, 2] // tile + 1):
                    hist[c, base + ty * tiles_x + tx] += 1
    tile_start = np.empty(ntiles + 1, np.int64)
    acc = 0
    for t in range(ntiles):
        tile_start[t] = acc
        for c in range(nchunks):
            cnt = hist[c, t]
            hist[c, t] = acc
            acc += cnt
    tile_start[ntiles] = acc
    tile_list = np.empty(acc, np.int32)
    for c in prange(nchunks):
        for r in range(bounds[c], bounds[c + 1]):
            k = info[r, 0]
            if k < 0:
                continue
            base = k * per_cam
            for ty in range(info[r, 3] // tile, info[r, 4] // tile + 1):
                for tx in range(info[r, 1] // tile, info[r, 2] // tile + 1):
                    t = base + ty * tiles_x + tx
                    tile_list[hist[c, t]] = r
                    hist[c, t] += 1
    return tile_start, tile_list


@njit(cache=True, error_model="numpy")
def _sort_by_depth(dkey, idx):
    """Sort ``idx`` (int64, increasing) by ``dkey`` (uint32 float32-depth bits), stably, in place.

    Stable LSD radix sort, 8-bit digits (passes whose digit is constant are skipped);
    insertion sort for short lists. Stability keeps equal depths in increasing index order.
    """
    n = dkey.shape[0]
    if n <= 48:
        for a in range(1, n):
            kd = dkey[a]
            ki = idx[a]
            b = a - 1
            while b >= 0 and dkey[b] > kd:
                dkey[b + 1] = dkey[b]
                idx[b + 1] = idx[b]
                b -= 1
            dkey[b + 1] = kd
            idx[b + 1] = ki
        return
    dk2 = np.empty_like(dkey)
    ix2 = np.empty_like(idx)
    count = np.empty(257, np.int64)
    for shift in range(0, 32, 8):
        sh = np.uint32(shift)
        for b in range(257):
            count[b] = 0
        for a in range(n):
            count[((dkey[a] >> sh) & np.uint32(255)) + 1] += 1
        skip = False
        for b in range(1, 257):
            if count[b] == n:
                skip = True
                break
        if skip:
            continue
        for b in range(1, 257):
            count[b] += count[b - 1]
        for a in range(n):
            d = (dkey[a] >> sh) & np.uint32(255)
            pos = count[d]
            count[d] = pos + 1
            dk2[pos] = dkey[a]
            ix2[pos] = idx[a]
        for a in range(n):  # element loops: slice assignment pulls in numba's costly shape-error path
            dkey[a] = dk2[a]
            idx[a] = ix2[a]


@njit(cache=True, fastmath=False, error_model="numpy")
def _blend_tile(rec, depth_bits, tile_start, tile_list, t, per_cam, tiles_x, width, height, tile, color, trans,
                depth, processed, evals):
    """Blend tile t's entries ``tile_list[tile_start[t]:tile_start[t+1]]`` into its camera's pixels;
    store the entries processed and pixel evaluations in ``processed[t]`` and ``evals[t]``.
    (The whole body of :func:`_blend`'s parallel loop, so that numba's second typing of that
    body, as an outlined gufunc, stays trivial.)"""
    s0 = tile_start[t]
    cnt = tile_start[t + 1] - s0
    if cnt == 0:
        return
    k = t // per_cam
    tt = t - k * per_cam
    ty = tt // tiles_x
    tx = tt - ty * tiles_x
    x0 = tx * tile
    y0 = ty * tile
    x1 = min(x0 + tile, width) - 1
    y1 = min(y0 + tile, height) - 1
    tw = x1 - x0 + 1
    npix = tw * (y1 - y0 + 1)
    dkey = np.empty(cnt, np.uint32)
    ent = np.empty(cnt, np.int64)
    for s in range(cnt):
        e = tile_list[s0 + s]
        ent[s] = e
        dkey[s] = depth_bits[e]
    _sort_by_depth(dkey, ent)
    T = np.ones(tile * tile, np.float64)
    C = np.zeros((tile * tile, 3), np.float64)
    D = np.zeros(tile * tile, np.float64)
    done = np.zeros(tile * tile, np.bool_)
    row_done = np.zeros(tile, np.int64)
    ndone = 0
    nev = 0
    s = 0
    # records are gathered in chunks into a local buffer: a tight copy loop overlaps the
    # cache misses of these random reads, the blending loop below would serialise them
    buf = np.empty((_GATHER, _NF), np.float32)
    while s < cnt and ndone < npix:
        b = s % _GATHER
        if b == 0:
            for c in range(min(_GATHER, cnt - s)):
                e = ent[s + c]
                for f in range(_NF):
                    buf[c, f] = rec[e, f]
        s += 1
        mx = np.float64(buf[b, _MX])
        my = np.float64(buf[b, _MY])
        ca = np.float64(buf[b, _CA])
        cb = np.float64(buf[b, _CB])
        cc = np.float64(buf[b, _CC])
        op = np.float64(buf[b, _OP])
        cr = np.float64(buf[b, _R])
        cg = np.float64(buf[b, _G])
        cbl = np.float64(buf[b, _B])
        z = np.float64(buf[b, _Z])
        qc = np.float64(buf[b, _QC])
        detc = ca * cc - cb * cb
        ja = max(int(buf[b, _J0]), x0)
        jb = min(int(buf[b, _J1]), x1)
        ia = max(int(buf[b, _I0]), y0)
        ib = min(int(buf[b, _I1]), y1)
        for i in range(ia, ib + 1):
            ri = i - y0
            if row_done[ri] == tw:
                continue
            dy = i + 0.5 - my
            disc = ca * qc - dy * dy * detc
            if disc < 0.0:
                continue
            sq = math.sqrt(disc)
            lo = math.ceil(mx + (-cb * dy - sq) / ca - 0.5 - 1e-4)
            hi = math.floor(mx + (-cb * dy + sq) / ca - 0.5 + 1e-4)
            jlo = max(ja, lo)
            jhi = min(jb, hi)
            row = ri * tw - x0
            for j in range(jlo, jhi + 1):
                p = row + j
                if done[p]:
                    continue
                nev += 1
                dx = j + 0.5 - mx
                q = ca * dx * dx + 2.0 * cb * dx * dy + cc * dy * dy
                if not q <= SUPPORT_Q:
                    continue
                a = min(ALPHA_MAX, op * math.exp(-0.5 * q))
                if a < ALPHA_MIN:
                    continue
                tp = T[p]
                tn = tp * (1.0 - a)
                if tn < T_MIN:
                    done[p] = True
                    ndone += 1
                    row_done[ri] += 1
                    continue
                w = a * tp
                C[p, 0] += cr * w
                C[p, 1] += cg * w
                C[p, 2] += cbl * w
                D[p] += z * w
                T[p] = tn
    for i in range(y0, y1 + 1):
        row = (i - y0) * tw - x0
        for j in range(x0, x1 + 1):
            p = row + j
            color[k, i, j, 0] = C[p, 0]
            color[k, i, j, 1] = C[p, 1]
            color[k, i, j, 2] = C[p, 2]
            trans[k, i, j] = T[p]
            wsum = 1.0 - T[p]
            depth[k, i, j] = D[p] / wsum if wsum > 0.0 else 0.0
    processed[t] = s
    evals[t] = nev


@njit(cache=True, **threaded(), fastmath=False, error_model="numpy")
def _blend(o0, o1, rec, depth_bits, tile_start, tile_list, order, tiles_x, tiles_y, tile, color, trans, depth,
           processed, evals):
    """Tiles ``order[o0:o1]`` (run in threads by ``thread_chunks.run_chunks``): order each tile's
    entries by (float32 depth, entry index), blend front to back.

    Fills colour (K,H,W,3) (zeros on entry), transmittance (K,H,W) (ones), expected depth (K,H,W)
    (zeros) float32 and, per tile (T,) int64, the number of entries processed before all its pixels
    terminated and of pixel evaluations (tiles without entries are left unchanged: zero).
    """
    height = color.shape[1]
    width = color.shape[2]
    per_cam = tiles_x * tiles_y
    for oi in range(o0, o1):
        _blend_tile(rec, depth_bits, tile_start, tile_list, order[oi], per_cam, tiles_x, width, height, tile, color,
                    trans, depth, processed, evals)


def camera_rows(view_rot, view_t, intr, nearfar, width: int, height: int, guard: float = DEFAULT_GUARD):
    """``(cams (K, 23), clamp (K, 4))`` float64: the cull's camera rows (``_cull``: view_rot (9,
    row-major), view_t (3), fx, fy, cx, cy, near, far, the guard-band clamp, and ``A`` with ``||J||_F <=
    A / z`` inside it) and the Jacobian's guard band ``clamp`` (x/z min, max, y/z min, max: the image's
    extent ``[c - h, c + h]`` widened to ``c +- guard h``), for cameras as :func:`rasterize` takes them
    (view_rot (K, 3, 3), view_t (K, 3), intr (K, 4), nearfar (K, 2) float64)."""
    ncam = view_rot.shape[0]
    lo_x, hi_x = -intr[:, 2] / intr[:, 0], (width - intr[:, 2]) / intr[:, 0]
    lo_y, hi_y = -intr[:, 3] / intr[:, 1], (height - intr[:, 3]) / intr[:, 1]
    cx_, hx_ = 0.5 * (lo_x + hi_x), 0.5 * (hi_x - lo_x)
    cy_, hy_ = 0.5 * (lo_y + hi_y), 0.5 * (hi_y - lo_y)
    clamp = np.ascontiguousarray(np.stack([cx_ - guard * hx_, cx_ + guard * hx_, cy_ - guard * hy_,
                                           cy_ + guard * hy_], axis=1))
    # ||J||_F^2 = (fx/z)^2 (1 + tx^2) + (fy/z)^2 (1 + ty^2) with tx, ty within the clamp: A^2 / z^2 at most
    tmax_x = np.maximum(np.abs(clamp[:, 0]), np.abs(clamp[:, 1]))
    tmax_y = np.maximum(np.abs(clamp[:, 2]), np.abs(clamp[:, 3]))
    jbound = np.sqrt(intr[:, 0] ** 2 * (1.0 + tmax_x**2) + intr[:, 1] ** 2 * (1.0 + tmax_y**2))
    cams = np.ascontiguousarray(np.concatenate([view_rot.reshape(ncam, 9), view_t, intr, nearfar, clamp,
                                                jbound[:, None]], axis=1))
    return cams, clamp


def _block_masks(blocks, order, n, cams, width, height, dilation):
    """``(bstart, bmask)`` for ``_cull``: the blocks' starts among the entries the cull goes over (the
    rows themselves, or their places in ``order``) and each block's cameras; empty without blocks."""
    if blocks is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts, centres, radii, smax = blocks
    starts = np.ascontiguousarray(starts, np.int64).reshape(-1)
    nb = starts.size - 1
    centres = np.ascontiguousarray(centres, np.float64).reshape(-1, 3)
    radii = np.ascontiguousarray(radii, np.float64).reshape(-1)
    smax = np.ascontiguousarray(smax, np.float64).reshape(-1)
    if nb < 1 or centres.shape[0] != nb or radii.shape[0] != nb or smax.shape[0] != nb or starts[0] != 0 \
            or starts[-1] > n or np.any(np.diff(starts) < 0):
        raise ValueError(f"rasterize: blocks must be B+1 increasing starts from 0 to at most {n} rows with B "
                         "centres, radii and largest scales")
    bstart = np.searchsorted(order, starts).astype(np.int64) if order.shape[0] else starts
    return bstart, _block_cameras(cams, int(width), int(height), float(dilation), centres, radii, smax)


def _aligned_empty(shape, dtype, align=64):
    """np.empty whose data pointer is a multiple of ``align`` bytes."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    buf = np.empty(nbytes + align, np.uint8)
    start = (-buf.ctypes.data) % align
    return buf[start:start + nbytes].view(dtype).reshape(shape)


def _tile_order(ntiles: int) -> np.ndarray:
    """Fixed pseudo-random permutation of tiles so static prange chunks get balanced work."""
    return np.random.default_rng(12345).permutation(ntiles).astype(np.int64)


def rasterize(positions, quats, scales, opacities, sh, view_rot, view_t, intr, nearfar, cam_pos,
              width, height, include=None, dilation=DEFAULT_DILATION, guard=DEFAULT_GUARD, tile=TILE,
              antialiased=False, order=None, blocks=None):
    """Render N Gaussians into K cameras of equal size (see module docstring).

    positions (N,3), quats (N,4) (w,x,y,z), scales (N,3) linear sigma, opacities (N,) linear,
    sh (N,(d+1)^2,3) 3DGS basis (float32 or float64). Cameras: view_rot (K,3,3) and
    view_t (K,3) world -> view (x right, y down, z depth), intr (K,4) = fx, fy, cx, cy in
    pixels, nearfar (K,2), cam_pos (K,3) world camera centres (for the SH direction); K <= 63.
    include: optional (N,) bool mask of the Gaussians to render; or ``order``: the increasing
    indices of the Gaussians to render (int64; the same image as the mask that selects them, bit
    for bit, without a pass over the others). dilation: px^2 added to the 2D
    covariance diagonal (3DGS: 0.3); guard: Jacobian clamp factor (3DGS: 1.3). antialiased:
    scale each splat's opacity by sqrt(det(Sigma2 - dilation I) / det(Sigma2)) so the dilation
    blurs small Gaussians without adding light (gsplat's "antialiased" mode; for renders whose
    radiance is measured, such as probes: a sub-pixel lamp keeps its energy).
    blocks: None, or ``(starts (B+1,) int64, centres (B, 3), radii (B,), smax (B,))`` float64: rows
    ``starts[b] .. starts[b+1]-1`` (increasing from 0; rows from ``starts[B]`` on belong to no block)
    have their centres within ``radii[b]`` of ``centres[b]`` and their largest ``|scale|`` at most
    ``smax[b]`` (NaN: unknown). The cull then skips, for a whole block, the cameras whose reject
    test would drop every Gaussian in it (``_block_cameras``): the same image, bit for bit, and
    fewer tests where a block lies in a few of the cameras (a cube render's far bricks).

    Returns (color (K,H,W,3) f32 premultiplied, transmittance (K,H,W) f32, expected depth
    (K,H,W) f32 = sum(z alpha T) / (1 - T) (0 where nothing was blended), stats dict with counts:
    culled_pass (pairs passing the cheap cull), entries (pairs projected), pairs (tile-entry
    pairs), pairs_blended (processed before tiles terminated), pixel_evals).
    """
    width = int(width)
    height = int(height)
    tile = int(tile)
    view_rot = np.ascontiguousarray(view_rot, np.float64).reshape(-1, 3, 3)
    ncam = view_rot.shape[0]
    if not 1 <= ncam <= 63:
        raise ValueError(f"rasterize: 1..63 cameras per call, got {ncam}")
    view_t = np.ascontiguousarray(view_t, np.float64).reshape(ncam, 3)
    intr = np.ascontiguousarray(intr, np.float64).reshape(ncam, 4)
    nearfar = np.ascontiguousarray(nearfar, np.float64).reshape(ncam, 2)
    cam_pos = np.ascontiguousarray(cam_pos, np.float64).reshape(ncam, 3)
    n = positions.shape[0]
    if n >= 2**31:
        raise ValueError("rasterize: at most 2**31 - 1 Gaussians")
    if include is not None and order is not None:
        raise ValueError("rasterize: give a mask or an order, not both")
    if order is not None:
        order = np.ascontiguousarray(order, np.int64).reshape(-1)
        if not _increasing_within(order, n):
            raise ValueError(f"rasterize: order must hold increasing indices in [0, {n})")
        if order.size == 0:  # nothing to draw: an all-false mask
            include, order = np.zeros(n, np.bool_), None
    if include is None:
        include = np.zeros(0, np.bool_)
    else:
        include = np.ascontiguousarray(include, np.bool_)
        if include.shape != (n,):
            raise ValueError(f"rasterize: mask has shape {include.shape}, expected ({n},)")
    order = np.zeros(0, np.int64) if order is None else order
    m_in = order.shape[0] if order.shape[0] else n  # Gaussians the passes go over
    dilation = float(dilation)
    guard = float(guard)
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    cams, clamp = camera_rows(view_rot, view_t, intr, nearfar, width, height, guard)
    # large buffers are allocated by numpy (huge-page advice: far fewer page faults than numba's allocator)
    bstart, bmask = _block_masks(blocks, order, n, cams, width, height, dilation)
    vis = np.empty(m_in, np.int64)
    run_chunks(_cull, m_in, positions, scales, opacities, include, order, cams, width, height, dilation, bstart,
               bmask, vis, min_chunk=4096)
    off = np.empty((m_in + _CHUNK - 1) // _CHUNK + 1, np.int64)  # each chunk's first entry
    _visible_offsets(vis, off)
    m = int(off[-1])
    if m >= 2**31:
        raise ValueError(f"rasterize: {m} (Gaussian, camera) pairs; at most 2**31 - 1 per call")
    rec = _aligned_empty((m, _NF), np.float32)  # one 64-byte cache line per record
    info = np.empty((m, 5), np.int32)
    depth32 = np.empty(m, np.float32)
    run_chunks(_write_entries, (m_in + _CHUNK - 1) // _CHUNK, positions, quats, scales, opacities, sh, order, vis, off,
               view_rot, view_t, intr, clamp, cam_pos, width, height, dilation, bool(antialiased), rec, info, depth32)
    tile_start, tile_list = _bin_tiles(info, ncam, tiles_x, tiles_y, tile, 16)
    ntiles = ncam * tiles_x * tiles_y
    color = np.zeros((ncam, height, width, 3), np.float32)
    trans = np.ones((ncam, height, width), np.float32)
    depth = np.zeros((ncam, height, width), np.float32)  # expected depth
    processed = np.zeros(ntiles, np.int64)
    evals = np.zeros(ntiles, np.int64)
    # positive float32 depths order like their bit patterns
    run_chunks(_blend, ntiles, rec, depth32.view(np.uint32), tile_start, tile_list, _tile_order(ntiles), tiles_x,
               tiles_y, tile, color, trans, depth, processed, evals)
    stats = {"culled_pass": int(off[-1]), "entries": int(np.count_nonzero(info[:, 0] >= 0)),
             "pairs": int(tile_list.shape[0]), "pairs_blended": int(processed.sum()),
             "pixel_evals": int(evals.sum())}
    return color, trans, depth, stats
