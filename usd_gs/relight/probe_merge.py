"""Moving prims drawn merged in the other prims' probes: one Gaussian per grid cell where the cell
is at most one probe texel across.

A relit prim's probe (``usd_gs.relight.avatar.probe_transfer``) is a low-resolution cube render
(``probe_size`` texels a face) fitted to low-order SH. Another avatar a metre or two away covers a
hundred or two of its texels yet is drawn with every one of its Gaussians (150,000 for the demo's
biker), in every other relit prim's probe: with N avatars, N - 1 full avatars per probe, the part of
the probe renders that grows faster than the avatar count. Here each moving prim is merged once per
frame into one Gaussian per occupied cell of ``cell`` metres (``numba_kernels.gaussian_merge``:
mass-weighted centre, the members' second moment as covariance, opacity x area and SH kept), and a
probe draws a cluster merged where the cell subtends at most one texel of its supersampled faces
(distance from the probe centre >= :func:`merged_distance`), its members as they are elsewhere.

The error this leaves (the relit colours against drawing every Gaussian, ``probe_merge_cell`` 0)
and the time it saves are measured in docs/benchmarks.md ("More avatars") and
tests/test_probe_merge.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from numba_kernels.gaussian_merge import merge_cells


def merged_distance(cell: float, size: int, supersample: int) -> float:
    """The distance from a probe centre beyond which a cell of ``cell`` (stage units, as the result)
    subtends at most one texel of faces ``size * supersample`` texels across (a face spans pi/2 at
    its centre, where its texels are widest)."""
    return float(cell) * 2.0 * int(size) * int(supersample) / math.pi


def merge_capacity(count: int) -> int:
    """Rows kept per prim for its merged Gaussians: a prim that merges into more clusters saves too
    little of a probe render for the merge to pay, and is drawn as it is."""
    return int(count) // 4


@dataclass
class MergedPrim:
    """A moving prim's merged Gaussians at one frame: ``labels`` (N,) int64 the cluster of each of
    its Gaussians, and the merged set's arrays (float32, stage units) in cluster order."""

    labels: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def centres(self) -> np.ndarray:
        """(M, 3) float64 the clusters' centres."""
        return self.positions.astype(np.float64)

    @classmethod
    def of(cls, g, cell: float) -> MergedPrim:
        """Set ``g`` (a ``GaussianSet``, world space) merged per cell of ``cell`` stage units."""
        labels, pos, quat, scales, opac, sh = merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh,
                                                          cell)
        return cls(labels, pos, quat, scales, opac, sh)

    def far_clusters(self, centre, distance: float) -> np.ndarray:
        """(M,) bool: the clusters whose centre lies at least ``distance`` from ``centre`` (3,)."""
        d = self.centres - np.asarray(centre, np.float64)
        return np.einsum("ij,ij->i", d, d) >= float(distance) ** 2
