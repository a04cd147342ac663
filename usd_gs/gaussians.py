"""The Gaussian set: one structure of arrays for N 3D Gaussians.

Conventions (shared/DESIGN.md section 1):

- ``positions``    (N, 3) float32, centres (world or prim-local space, see ``space``).
- ``orientations`` (N, 4) float32, unit quaternions ordered (w, x, y, z).
- ``scales``       (N, 3) float32, per-axis standard deviation (linear sigma, > 0).
- ``opacities``    (N,)   float32, linear opacity in [0, 1].
- ``sh``           (N, (d+1)^2, 3) float32, SH coefficients in the 3DGS basis
  (``usd_gs.sh3dgs``), particle-major, coefficient 0 is the raw DC term ``f_dc``.
- ``sh_degree``    int d in 0..3, always equal to ``sqrt(sh.shape[1]) - 1``.

Optional lossless side data, kept so that PLY -> USD -> PLY is bit-exact even where
float32 ``exp``/``sigmoid`` are not invertible:

- ``log_scales``      (N, 3) float32 raw PLY ``scale_*`` (natural log of sigma) or None.
- ``logit_opacities`` (N,)   float32 raw PLY ``opacity`` (logit) or None.
- ``extras``          dict name -> (N,) array, other per-particle PLY fields (normals...).

Covariance: ``Sigma = R diag(s)^2 R^T`` with ``R`` the rotation matrix of the quaternion
acting on column vectors (world = R @ local).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace

import numpy as np

from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError, first_bad_index

#: opacities are clamped to [OPACITY_EPS, 1 - OPACITY_EPS] before the logit when no raw
#: logit is available, so that 0 and 1 give finite logits (about -16.1 and +16.1).
OPACITY_EPS = 1e-7
_TINY32 = float(np.finfo(np.float32).tiny)


# --------------------------------------------------------------------------- activations
def scales_from_log(log_scales: np.ndarray) -> np.ndarray:
    """Linear sigma ``exp(log_scales)`` computed in float64, returned as float32.

    Values below the float32 normal range become ``finfo(float32).tiny`` so that every
    scale stays > 0; the caller must reject values above ``log(float32 max)``.
    """
    s = np.exp(np.asarray(log_scales, dtype=np.float64))
    np.maximum(s, _TINY32, out=s)
    return s.astype(np.float32)


def opacities_from_logit(logits: np.ndarray) -> np.ndarray:
    """Stable sigmoid in float64, returned as float32; ``-inf``/``+inf`` give 0/1 exactly."""
    x = np.asarray(logits, dtype=np.float64)
    e = np.exp(-np.abs(x))
    out = np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e))
    return out.astype(np.float32)


def logit_from_opacities(opacities: np.ndarray) -> np.ndarray:
    """``log(p / (1 - p))`` in float64 after clamping ``p`` to [OPACITY_EPS, 1 - OPACITY_EPS]."""
    p = np.clip(np.asarray(opacities, dtype=np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    return (np.log(p) - np.log1p(-p)).astype(np.float32)



def _as_f32(name: str, a, shape_tail: tuple, label: str) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a), dtype=np.float32)
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        raise GaussianDataError(
            f"{label}: '{name}' must have shape (N, {', '.join(map(str, shape_tail))}) "
            f"but has shape {tuple(arr.shape)}".replace("(N, )", "(N,)")
        )
    return arr


@dataclass
class GaussianSet:
    """N Gaussians as a structure of arrays; see the module docstring for conventions."""

    positions: np.ndarray
    orientations: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    log_scales: np.ndarray | None = None
    logit_opacities: np.ndarray | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    label: str = "<gaussians>"

    def __post_init__(self) -> None:
        lb = self.label
        self.positions = _as_f32("positions", self.positions, (3,), lb)
        self.orientations = _as_f32("orientations", self.orientations, (4,), lb)
        self.scales = _as_f32("scales", self.scales, (3,), lb)
        self.opacities = _as_f32("opacities", self.opacities, (), lb)
        sh = np.asarray(self.sh)
        if sh.ndim != 3 or sh.shape[2] != 3:
            raise GaussianDataError(
                f"{lb}: 'sh' must have shape (N, (d+1)^2, 3) but has shape {tuple(sh.shape)}")
        try:
            degree = sh3dgs.degree_from_num_coeffs(sh.shape[1])
        except ValueError as exc:
            raise GaussianDataError(f"{lb}: 'sh': {exc}") from None
        if degree > sh3dgs.MAX_DEGREE:
            raise GaussianDataError(f"{lb}: 'sh' has degree {degree}, more than {sh3dgs.MAX_DEGREE}")
        self.sh = np.ascontiguousarray(sh, dtype=np.float32)
        n = self.positions.shape[0]
        for name in ("orientations", "scales", "opacities", "sh"):
            m = getattr(self, name).shape[0]
            if m != n:
                raise GaussianDataError(f"{lb}: '{name}' has {m} elements but 'positions' has {n}")
        if self.log_scales is not None:
            self.log_scales = _as_f32("log_scales", self.log_scales, (3,), lb)
            if self.log_scales.shape[0] != n:
                raise GaussianDataError(f"{lb}: 'log_scales' has {self.log_scales.shape[0]} elements, expected {n}")
        if self.logit_opacities is not None:
            self.logit_opacities = _as_f32("logit_opacities", self.logit_opacities, (), lb)
            if self.logit_opacities.shape[0] != n:
                raise GaussianDataError(
                    f"{lb}: 'logit_opacities' has {self.logit_opacities.shape[0]} elements, expected {n}")
        for key, arr in list(self.extras.items()):
            arr = np.ascontiguousarray(arr)
            if arr.shape[:1] != (n,):
                raise GaussianDataError(f"{lb}: extra field '{key}' has {arr.shape[:1]} elements, expected {n}")
            self.extras[key] = arr

    # ------------------------------------------------------------------ basics
    @property
    def count(self) -> int:
        return int(self.positions.shape[0])

    def __len__(self) -> int:
        return self.count

    @property
    def sh_degree(self) -> int:
        return sh3dgs.degree_from_num_coeffs(self.sh.shape[1])

    @classmethod
    def empty(cls, degree: int = 0, label: str = "<gaussians>") -> GaussianSet:
        return cls(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0,)),
                   np.zeros((0, sh3dgs.num_coeffs(degree), 3)), label=label)

    def with_label(self, label: str) -> GaussianSet:
        return replace(self, label=label, extras=dict(self.extras))

    # ------------------------------------------------------------- validation
    def problems(self) -> list[str]:
        """All data-contract violations, each naming attribute and first bad element.

        Checks: finite values everywhere, scales > 0, opacities in [0, 1], quaternion norm
        within 1 +/- 1e-3 (the VG.035 rule). Returns an empty list when the set is valid.
        """
        out = []
        checks = [
            ("positions", ~np.isfinite(self.positions), "is not finite"),
            ("orientations", ~np.isfinite(self.orientations), "is not finite"),
            ("scales", ~np.isfinite(self.scales), "is not finite"),
            ("scales", self.scales <= 0, "is not > 0"),
            ("opacities", ~np.isfinite(self.opacities), "is not finite"),
            ("opacities", (self.opacities < 0) | (self.opacities > 1), "is outside [0, 1]"),
            ("sh", ~np.isfinite(self.sh), "is not finite"),
        ]
        qn = np.linalg.norm(self.orientations.astype(np.float64), axis=1)
        checks.append(("orientations", ~(np.abs(qn - 1.0) <= 1e-3),
                       "is not a unit quaternion (|q| outside 1 +/- 1e-3)"))
        for name, bad, what in checks:
            i = first_bad_index(bad) if len(bad) else -1
            if i >= 0:
                nbad = int(np.asarray(bad).reshape(len(bad), -1).any(axis=1).sum())
                value = getattr(self, name)[i]
                shown = np.array2string(np.asarray(value), precision=6)
                out.append(f"{self.label}: '{name}' element {i} {what} (value {shown}; "
                           f"{nbad} bad element{'s' if nbad != 1 else ''})")
        return out

    def check(self) -> GaussianSet:
        """Raise ``GaussianDataError`` listing every problem; return self when valid."""
        probs = self.problems()
        if probs:
            raise GaussianDataError("; ".join(probs))
        return self

    # ----------------------------------------------------------- derived data
    def unit_quaternions(self) -> np.ndarray:
        """(N, 4) float64 normalised (w, x, y, z); a zero quaternion becomes identity."""
        q = self.orientations.astype(np.float64)
        sq = q * q
        n = ((sq[:, 0] + sq[:, 1]) + sq[:, 2]) + sq[:, 3]  # np.linalg.norm's order, its bits (tested)
        n = np.sqrt(n, out=n)[:, None]
        positive = n > 0
        if positive.all():
            q /= n
            return q
        return np.where(positive, q / np.where(positive, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))

    def rotation_matrices(self) -> np.ndarray:
        """(N, 3, 3) float64 rotation matrices of the (normalised) quaternions."""
        return quaternion_to_matrix(self.unit_quaternions())

    def covariances(self) -> np.ndarray:
        """(N, 3, 3) float64 ``R diag(s^2) R^T``."""
        r = self.rotation_matrices()
        s2 = self.scales.astype(np.float64) ** 2
        return np.einsum("nij,nj,nkj->nik", r, s2, r)

    def precisions(self) -> np.ndarray:
        """(N, 3, 3) float64 inverse covariances ``R diag(s^-2) R^T``."""
        r = self.rotation_matrices()
        inv_s2 = 1.0 / self.scales.astype(np.float64) ** 2
        return np.einsum("nij,nj,nkj->nik", r, inv_s2, r)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) of the centres, float64 (3,) each; NaN for an empty set."""
        if self.count == 0:
            nan = np.full(3, np.nan)
            return nan, nan.copy()
        p = self.positions.astype(np.float64)
        return p.min(axis=0), p.max(axis=0)

    def extent(self, n_sigma: float = 3.0) -> np.ndarray:
        """(2, 3) float32 axis-aligned box around every Gaussian's ``n_sigma`` ellipsoid.

        Float64 math; a zero quaternion counts as identity. Per axis i the half-width is
        ``n_sigma * sqrt(sum_j R_ij^2 s_j^2)``, computed row by row without (N, 3, 3) arrays.
        ``GaussianDataError`` names the first element whose box does not fit in float32.
        In a process that has loaded numba, one kernel pass (``numba_kernels.extent``: the same
        operations, the same bits) computes the box.
        """
        if self.count == 0:
            return np.zeros((2, 3), np.float32)
        if "numba" in sys.modules:  # (loading numba only for this would cost more than it saves)
            from numba_kernels.extent import gaussian_extent

            box = gaussian_extent(self.positions, self.orientations, self.scales, n_sigma)
            if box is not None:
                return box.astype(np.float32)
        w, x, y, z = self.unit_quaternions().T
        s2 = self.scales.astype(np.float64) ** 2
        rows = (
            (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        )
        p = self.positions
        lo, hi = np.empty(3), np.empty(3)
        big = float(np.finfo(np.float32).max)
        for i, (a, b, c) in enumerate(rows):
            half = n_sigma * np.sqrt(a * a * s2[:, 0] + b * b * s2[:, 1] + c * c * s2[:, 2])
            lo_i, hi_i = p[:, i] - half, p[:, i] + half
            bad = ~(np.abs(lo_i) <= big) | ~(np.abs(hi_i) <= big)
            if bad.any():
                j = first_bad_index(bad)
                raise GaussianDataError(
                    f"{self.label}: the {n_sigma:g}-sigma extent of element {j} (scales {self.scales[j].tolist()}) "
                    f"is not finite in float32 ({int(bad.sum())} such elements); the scales are too large")
            lo[i] = np.min(lo_i)
            hi[i] = np.max(hi_i)
        return np.stack([lo, hi]).astype(np.float32)

    # ------------------------------------------------------------ operations
    def subset(self, index) -> GaussianSet:
        """Gaussians selected by an integer index array, slice or boolean mask."""
        def take(a):
            return None if a is None else a[index]
        if isinstance(index, slice) or (isinstance(index, np.ndarray) and index.ndim == 1
                                        and index.dtype.kind in "biu"):
            # rows of a valid set are a valid set: made contiguous float32 as __post_init__ does, not checked again
            out = object.__new__(GaussianSet)

            def c(a):
                return np.ascontiguousarray(a, dtype=np.float32)
            out.positions, out.orientations, out.scales = c(self.positions[index]), c(self.orientations[index]), \
                c(self.scales[index])
            out.opacities, out.sh = c(self.opacities[index]), c(self.sh[index])
            out.log_scales = None if self.log_scales is None else c(self.log_scales[index])
            out.logit_opacities = None if self.logit_opacities is None else c(self.logit_opacities[index])
            out.extras = {k: np.ascontiguousarray(v[index]) for k, v in self.extras.items()}
            out.label = self.label
            return out
        return GaussianSet(
            self.positions[index], self.orientations[index], self.scales[index],
            self.opacities[index], self.sh[index], take(self.log_scales),
            take(self.logit_opacities), {k: v[index] for k, v in self.extras.items()},
            label=self.label)

    def occluder_subset(self, index) -> GaussianSet:
        """The rows ``index`` (integer index array, slice or boolean mask) as occluders: positions,
        orientations, scales and opacities as :meth:`subset` gives them, and zero degree-0 SH (no raw
        values, no extras): what a shadow map packs, without copying the colours it does not read."""
        out = object.__new__(GaussianSet)

        def c(a):
            return np.ascontiguousarray(a, dtype=np.float32)
        out.positions, out.orientations, out.scales = c(self.positions[index]), c(self.orientations[index]), \
            c(self.scales[index])
        out.opacities = c(self.opacities[index])
        out.sh = np.zeros((out.positions.shape[0], 1, 3), np.float32)
        out.log_scales = out.logit_opacities = None
        out.extras = {}
        out.label = self.label
        return out

    def with_sh_degree(self, degree: int) -> GaussianSet:
        """Same Gaussians with SH truncated or zero-padded to ``degree``."""
        k = sh3dgs.num_coeffs(degree)
        sh = np.zeros((self.count, k, 3), np.float32)
        m = min(k, self.sh.shape[1])
        sh[:, :m] = self.sh[:, :m]
        return replace(self, sh=sh, extras=dict(self.extras))

    def transformed(self, matrix, label: str | None = None, rotate_sh: bool = True) -> GaussianSet:
        """Apply a similarity transform given as a USD 4x4 matrix (row-vector convention).

        ``matrix`` is what ``Gf.Matrix4d`` holds (``np.array(m)``): a point maps as
        ``p' = [p, 1] @ matrix``. Its 3x3 part must be ``s * Q`` with ``Q`` orthogonal
        (rotation or reflection) and ``s > 0``; a non-uniform scale or shear raises
        ``GaussianDataError`` naming ``label``. Positions are transformed in float64,
        orientations rotated, scales multiplied by ``s``, and (if ``rotate_sh``) SH bands
        1..3 rotated by the exact per-band matrices so view-dependent colour follows
        the Gaussian. ``log_scales`` shift by ``log(s)``; extras are kept as they are.
        """
        label = label or self.label
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise GaussianDataError(f"{label}: transform is not a finite 4x4 matrix")
        if np.array_equal(m[:3, :3], np.eye(3)) and not np.any(m[:3, 3]) and m[3, 3] == 1.0:
            # Pure translation (or identity): every value but the positions stays bit-exact.
            pos = self.positions if not np.any(m[3, :3]) else self.positions.astype(np.float64) + m[3, :3]
            return replace(self, positions=np.array(pos, dtype=np.float32), label=label, extras=dict(self.extras))
        if np.max(np.abs(m[:3, 3])) > 1e-9 or abs(m[3, 3] - 1.0) > 1e-9:
            raise GaussianDataError(f"{label}: transform is projective, not a similarity transform")
        lin = m[:3, :3].T  # column-vector convention: p' = lin @ p + t
        t = m[3, :3]
        det = np.linalg.det(lin)
        if det == 0:
            raise GaussianDataError(f"{label}: transform is singular (determinant 0)")
        s = abs(det) ** (1.0 / 3.0)
        q = lin / s
        err = np.max(np.abs(q.T @ q - np.eye(3)))
        if err > 1e-5:
            raise GaussianDataError(
                f"{label}: transform has a non-uniform scale or shear (|Q^T Q - I| = {err:.3g}); "
                "only rotations, translations, reflections and uniform scales are supported")
        # Orthonormalise Q exactly (polar decomposition) so rotations stay unit.
        u, _, vt = np.linalg.svd(q)
        q = u @ vt
        from numba_kernels.similarity import similarity_transform

        reflect = bool(np.linalg.det(q) < 0)
        # a reflection: Q = Q' F with F = diag(-1, 1, 1) and Q' a rotation. The new frame Q R F (its
        # first local axis flipped: same covariance, det +1) is Q' (F R F), and F R F has the
        # quaternion (w, x, -y, -z). Positions, orientations and scales in one threaded pass
        # (numba_kernels.similarity: the float64 formulas of unit_quaternions and quaternion_multiply)
        proper = q @ np.diag([-1.0, 1.0, 1.0]) if reflect else q
        pos, quat, scales = similarity_transform(self.positions, self.orientations, self.scales, lin, t, s,
                                                 matrix_to_quaternion(proper[None])[0], reflect)
        sh = sh3dgs.rotate_coefficients(self.sh, q) if (rotate_sh and self.sh_degree > 0) else self.sh.copy()
        log_scales = None if self.log_scales is None else (self.log_scales.astype(np.float64) + np.log(s))
        return GaussianSet(pos, quat, scales, self.opacities.copy(), sh,
                           log_scales, None if self.logit_opacities is None else self.logit_opacities.copy(),
                           dict(self.extras), label=label)

    @staticmethod
    def concatenate(sets: list[GaussianSet], label: str = "<gaussians>", finite: list | None = None) -> GaussianSet:
        """One set holding all Gaussians of ``sets`` in order.

        SH is zero-padded to the highest degree among the inputs. Raw ``log_scales`` /
        ``logit_opacities`` are kept only if every input has them; ``extras`` only for
        keys (with equal trailing shape) present in every input. ``finite``: None, or a list to
        which one bool is appended: whether every position, orientation, scale, opacity and SH
        coefficient of the result is finite (each value tested as it is copied,
        ``numba_kernels.copy_finite``: no second pass over the inputs).
        """
        if not sets:
            return GaussianSet.empty(label=label)
        degree = max(g.sh_degree for g in sets)

        def cat(name):
            vals = [getattr(g, name) for g in sets]
            return None if any(v is None for v in vals) else np.concatenate(vals)

        # the fields and the SH written straight into the result (no padded copy of each input's SH
        # first: a large degree-0 scene beside a degree-3 avatar would be copied twice at 16
        # coefficients); a large result's rows are filled in threads (its fresh pages fault in there)
        starts = np.cumsum([0] + [g.count for g in sets])
        n = int(starts[-1])
        out = {"positions": np.empty((n, 3), np.float32), "orientations": np.empty((n, 4), np.float32),
               "scales": np.empty((n, 3), np.float32), "opacities": np.empty(n, np.float32),
               "sh": np.empty((n, sh3dgs.num_coeffs(degree), 3), np.float32)}

        bad: list = []  # row ranges with a value that is not finite (where ``finite`` is asked for)
        if finite is not None:
            from numba_kernels.copy_finite import copy_finite, copy_finite_padded

        def fill(lo: int, hi: int) -> None:
            for i in range(int(np.searchsorted(starts, lo, "right")) - 1, len(sets)):
                a, b = max(lo, int(starts[i])), min(hi, int(starts[i + 1]))
                if a >= hi:
                    break
                if b <= a:
                    continue
                g, r0, r1 = sets[i], a - int(starts[i]), b - int(starts[i])
                k = g.sh.shape[1]
                if finite is None:
                    for name in ("positions", "orientations", "scales", "opacities"):
                        out[name][a:b] = getattr(g, name)[r0:r1]
                    out["sh"][a:b, :k] = g.sh[r0:r1]
                    out["sh"][a:b, k:] = 0.0
                    continue
                # each value read once: copied and checked in one pass (numba_kernels.copy_finite)
                ok = all([copy_finite(np.ascontiguousarray(getattr(g, name)[r0:r1]), out[name][a:b])
                          for name in ("positions", "orientations", "scales", "opacities")])
                sh = np.ascontiguousarray(g.sh[r0:r1])
                kk = out["sh"].shape[1]
                ok &= (copy_finite(sh, out["sh"][a:b]) if k == kk else
                       copy_finite_padded(sh, out["sh"][a:b], 3 * k, 3 * kk))
                if not ok:
                    bad.append((a, b))

        if sum(a.nbytes for a in out.values()) >= PARALLEL_COPY_BYTES:
            from numba_kernels.thread_chunks import run_chunks

            run_chunks(fill, n, chunks_per_thread=1, min_chunk=1 << 16)
        else:
            fill(0, n)
        if finite is not None:
            finite.append(not bad)
        keys = set(sets[0].extras)
        for g in sets[1:]:
            keys &= {k for k in g.extras if g.extras[k].shape[1:] == sets[0].extras.get(k, np.zeros(0)).shape[1:]}
        extras = {k: np.concatenate([g.extras[k] for g in sets]) for k in sorted(keys)}
        return GaussianSet(out["positions"], out["orientations"], out["scales"], out["opacities"], out["sh"],
                           cat("log_scales"), cat("logit_opacities"), extras, label=label)


def all_finite(arr: np.ndarray) -> bool:
    """True when every element of the float array is finite. One pass without an array-sized
    temporary: a NaN or an infinity makes the sum NaN or infinite, so a finite sum proves every
    element finite; a sum that overflows (or a non-finite element) is decided element by element."""
    if arr.size == 0:
        return True
    flat = arr.reshape(-1)
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(flat, dtype=flat.dtype)):
            return True
    return bool(np.isfinite(flat).all())


#: bytes from which :meth:`GaussianSet.concatenate` fills its result in threads
PARALLEL_COPY_BYTES = 64 << 20


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions (w, x, y, z), broadcasting (..., 4) float64.
    The rotation of ``a * b`` applies ``b`` first, then ``a``."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) -> (N, 3, 3) float64 rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    r = np.empty((q.shape[0], 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - w * z)
    r[:, 0, 2] = 2 * (x * z + w * y)
    r[:, 1, 0] = 2 * (x * y + w * z)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - w * x)
    r[:, 2, 0] = 2 * (x * z - w * y)
    r[:, 2, 1] = 2 * (y * z + w * x)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (w, x, y, z), w >= 0.

    Shepperd's method: pick the largest of (w, x, y, z) to divide by, stable for every
    rotation including 180 degrees.
    """
    r = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((r.shape[0], 4))
    # case w largest
    s = np.sqrt(np.maximum(1.0 + tr, 1e-300)) * 2
    qw = np.stack([0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                   (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
    s = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300)) * 2
    qx = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                   (r[:, 0, 2] + r[:, 2, 0]) / s], axis=1)
    s = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 1e-300)) * 2
    qy = np.stack([(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s,
                   (r[:, 1, 2] + r[:, 2, 1]) / s], axis=1)
    s = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 1e-300)) * 2
    qz = np.stack([(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                   (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s], axis=1)
    for idx, cq in enumerate((qw, qx, qy, qz)):
        sel = k == idx
        q[sel] = cq[sel]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q


def alpha_weighted_centroid(gaussians: GaussianSet) -> np.ndarray:
    """``sum_i a_i p_i / sum_i a_i`` in float64 (plain mean if every opacity is 0). Raises on an empty set."""
    if gaussians.count == 0:
        raise GaussianDataError(f"{gaussians.label}: cannot take the centroid of an empty Gaussian set")
    a = gaussians.opacities.astype(np.float64)
    p = gaussians.positions.astype(np.float64)
    w = a.sum()
    c = (a @ p) / w if w > 0 else p.mean(axis=0)
    if not np.all(np.isfinite(c)):
        raise GaussianDataError(f"{gaussians.label}: 'positions'/'opacities' give a non-finite centroid")
    return c
