"""Reference of :mod:`numba_kernels.similarity` in numpy, from its module docstring."""

from __future__ import annotations

import numpy as np


def similarity_transform(positions, orientations, scales, lin, t, s: float, rq, flip: bool):
    pos = np.asarray(positions, np.float64) @ np.asarray(lin, np.float64).T + np.asarray(t, np.float64)
    q = np.asarray(orientations, np.float64)
    sq = q * q
    n = np.sqrt(((sq[:, 0] + sq[:, 1]) + sq[:, 2]) + sq[:, 3])[:, None]
    q = np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    if flip:
        q[:, 2:] *= -1.0
    aw, ax, ay, az = np.asarray(rq, np.float64)
    bw, bx, by, bz = q.T
    quat = np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=1)
    return (pos.astype(np.float32), quat.astype(np.float32),
            (np.asarray(scales, np.float64) * s).astype(np.float32))
