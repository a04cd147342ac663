"""The axis-aligned box of a Gaussian set's n-sigma ellipsoids, fast and with the float64 bits.

:func:`gaussian_extent` gives ``GaussianSet.extent`` bit for bit from a float32 pre-filter and the
float64 extent of the few Gaussians that can reach the box's faces; :class:`ExtentOfParts` the
same for a set decoded part by part. numpy only (a SOG decoder runs them before pxr loads).
"""

from __future__ import annotations

import numpy as np


def _near_bounds(p: np.ndarray, lo: np.ndarray, hi: np.ndarray, lo_up: np.ndarray, hi_down: np.ndarray,
                 size: np.ndarray, pick: np.ndarray) -> bool:
    """Mark in ``pick`` the rows whose box ``[lo, hi]`` on this axis can hold the minimum or the
    maximum over all rows, given that each row's exact box lies within ``[lo, lo_up]`` ..
    ``[hi_down, hi]`` (float32, with a 1e-5 relative margin for their rounding). False when
    something is not finite."""
    lo_min, hi_max = lo_up.min(), hi_down.max()
    tol = np.float32(1e-5) * (np.abs(p).max() + size.max()) + np.float32(1e-30)
    if not (np.isfinite(lo_min) and np.isfinite(hi_max) and np.isfinite(tol)):
        return False
    pick |= lo <= lo_min + tol
    pick |= hi >= hi_max - tol
    return True


def gaussian_extent(g, n_sigma: float = 3.0) -> np.ndarray:
    """``g.extent(n_sigma)`` ((2, 3) float32 box of every Gaussian's ``n_sigma`` ellipsoid), same bits.

    Each Gaussian's half-width on an axis lies between ``n_sigma`` times its smallest and its
    largest scale (the rotation's rows are unit vectors); in float32, with a wide margin for
    rounding, that bounds which Gaussians can reach the box's minimum or maximum on some axis.
    When those are many, float32 half-widths of the rotated ellipsoids narrow them down. Only
    those few go through the float64 ``GaussianSet.extent``. Any non-finite value, a
    near-zero quaternion or an error on that subset falls back to ``g.extent`` on the whole
    set (which names the element).
    """
    from usd_gs.errors import GaussianDataError

    n = g.count
    if n < 4096:
        return g.extent(n_sigma)
    k = np.float32(n_sigma)
    with np.errstate(all="ignore"):
        s = g.scales
        big = np.maximum(np.maximum(s[:, 0], s[:, 1]), s[:, 2])
        big *= k * np.float32(1.0 + 1e-5)
        small = np.minimum(np.minimum(s[:, 0], s[:, 1]), s[:, 2])
        small *= k * np.float32(1.0 - 1e-5)
        pick = np.zeros(n, bool)
        lo, hi, lo_up, hi_down = (np.empty(n, s.dtype) for _ in range(4))  # reused over the axes
        for i in range(3):
            p = g.positions[:, i]
            np.subtract(p, big, out=lo)
            np.add(p, big, out=hi)
            np.subtract(p, small, out=lo_up)
            np.add(p, small, out=hi_down)
            if not _near_bounds(p, lo, hi, lo_up, hi_down, big, pick):
                return g.extent(n_sigma)
        idx = np.flatnonzero(pick)
        if len(idx) > 4096:
            fine = _rotated_candidates(g, idx, k)
            if fine is None:
                return g.extent(n_sigma)
            idx = idx[fine]
    if len(idx) > n // 4:
        return g.extent(n_sigma)
    from usd_gs.gaussians import GaussianSet

    sub = GaussianSet(g.positions[idx], g.orientations[idx], g.scales[idx], g.opacities[idx],
                      np.zeros((len(idx), 1, 3), np.float32), label=g.label)
    try:
        return sub.extent(n_sigma)
    except GaussianDataError:
        return g.extent(n_sigma)


class ExtentOfParts:
    """The :func:`gaussian_extent` of a set computed part by part (rows of it, added in any order
    and from any thread as they become ready), the same bits as that of the whole set: the
    float32 rounding of the float64 minima and maxima is monotonic, so the least of the parts'
    rounded minima is the rounded minimum of the whole. A part whose extent fails (a scale too
    large) leaves :meth:`box` None, so the caller computes the whole set's extent and its error."""

    def __init__(self, n_sigma: float = 3.0):
        import threading

        self.n_sigma = n_sigma
        self._parts: list = []  # (rows, box or None when they are none)
        self._failed = False
        self._lock = threading.Lock()

    def add(self, rows) -> None:
        """Add the extent of ``rows`` (a ``GaussianSet``)."""
        try:
            box = gaussian_extent(rows, self.n_sigma) if rows.count else None
        except Exception:  # noqa: BLE001 - the whole set's extent reports it (see box)
            box, self._failed = None, True
        with self._lock:
            self._parts.append((rows.count, box))

    def box(self, count: int) -> np.ndarray | None:
        """The (2, 3) float32 extent once parts holding ``count`` rows in all were added; else None."""
        with self._lock:
            boxes = [b for _, b in self._parts if b is not None]
            if self._failed or not boxes or sum(n for n, _ in self._parts) != count:
                return None
        return np.stack([np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)])


def _rotated_candidates(g, idx: np.ndarray, k: np.float32) -> np.ndarray | None:
    """Of the rows ``idx``, those whose float32 rotated box can reach the minimum or maximum (a
    boolean mask over ``idx``); None for a near-zero quaternion or a non-finite value."""
    q = g.orientations[idx]
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    n2 = w * w + x * x + y * y + z * z
    if not (n2.min() > 1e-20 and np.isfinite(n2).all()):
        return None
    inv = np.float32(2.0) / n2  # 2/|q|^2: the rotation of the normalised quaternion
    s2 = g.scales[idx] ** 2
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = ((1 - inv * (yy + zz), inv * (xy - wz), inv * (xz + wy)),
            (inv * (xy + wz), 1 - inv * (xx + zz), inv * (yz - wx)),
            (inv * (xz - wy), inv * (yz + wx), 1 - inv * (xx + yy)))
    pick = np.zeros(len(idx), bool)
    for i, (a, b, c) in enumerate(rows):
        half = k * np.sqrt(a * a * s2[:, 0] + b * b * s2[:, 1] + c * c * s2[:, 2])
        p = g.positions[idx, i]
        lo, hi = p - half, p + half
        if not _near_bounds(p, lo, hi, lo, hi, half, pick):
            return None
    return pick
