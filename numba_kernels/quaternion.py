"""Quaternion -> rotation matrix for numba kernels (one inlined helper shared by all kernels).

Quaternions are ``(w, x, y, z)`` (scalar first, as ``usd_gs.gaussians.GaussianSet.orientations``)
and need not be unit length: the helper normalises them. The matrix is the usual Hamilton
rotation (column-vector convention, ``world = R @ local``); its columns are the Gaussian's local
axes in the world frame.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, fastmath=False, inline="always")
def quat_to_rotation(w, x, y, z):
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (float64 scalars) as the row-major
    9-tuple ``(r00, r01, r02, r10, r11, r12, r20, r21, r22)``.

    The quaternion is normalised first; a zero or non-finite quaternion gives the identity (so
    no NaN/Inf leaves the helper). Inlined into the calling kernel by numba (no call cost).
    """
    qn = math.sqrt(w * w + x * x + y * y + z * z)
    if qn > 0.0 and math.isfinite(qn):
        w, x, y, z = w / qn, x / qn, y / qn, z / qn
    else:
        w, x, y, z = 1.0, 0.0, 0.0, 0.0
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
