"""Read PlayCanvas ``.compressed.ply`` files (SuperSplat / splat-transform's packed PLY).

Quantisation: per 256-splat chunk min/max; position and log-scale 11-10-11 bits, quaternion
2-10-10-10 (largest component dropped), colour and opacity 8 bits each, SH 8 bits in [-4, 4].

File layout (binary little-endian PLY, three elements in this order):

- ``chunk`` (``ceil(N / 256)`` rows, float32): ``min_x, min_y, min_z, max_x, max_y, max_z``,
  ``min_scale_x..z, max_scale_x..z`` (natural-log sigma) and optionally ``min_r, min_g, min_b,
  max_r, max_g, max_b`` (display colour ``0.5 + C0 * f_dc``). Row ``i // 256`` bounds
  Gaussian ``i``.
- ``vertex`` (N rows, uint32): ``packed_position`` and ``packed_scale`` (x in bits 21..31, y in
  11..20, z in 0..10, each a unorm ``t`` giving ``min + (max - min) * t``), ``packed_rotation``
  (bits 30..31: index of the largest component in (w, x, y, z) order, which is positive; the
  other three in file order in bits 20..29, 10..19, 0..9, each ``(t - 0.5) * sqrt(2)``),
  ``packed_color`` (r, g, b, opacity unorm8 from the high byte down; r, g, b interpolate the
  chunk colour bounds when present, else are the colour itself).
- ``sh`` (optional, N rows of 9, 24 or 45 uint8 ``f_rest_*``, channel-major like INRIA PLY):
  byte ``b`` gives ``(t - 0.5) * 8`` with ``t = 0`` for 0, 1 for 255, else ``(b + 0.5) / 256``.

Mapping to :class:`usd_gs.gaussians.GaussianSet`: ``log_scales`` are the interpolated values
(``scales = exp``), ``opacities`` the linear unorm8 alpha, ``sh[:, 0] = (colour - 0.5) / C0``,
quaternions normalised in float64. Values are computed in float64 and rounded once to
float32, the decode PlayCanvas splat-transform uses.
"""

from __future__ import annotations

import numpy as np

from usd_gs.errors import InputFormatError, first_bad_index
from usd_gs.gaussians import GaussianSet
from usd_gs.io.checks import existing_file
from usd_gs.io.ply import _LOG_SCALE_MAX, REST_COUNT_TO_DEGREE, open_plydata, scales_from_log

SH_C0 = 0.28209479177387814
CHUNK = 256
_POS_B = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")
_SCALE_B = ("min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z")
_COL_B = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
_PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
# unpacked quaternion component order per largest-index (w, x, y, z positions of a, b, c)
_OTHERS = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))


def is_compressed_ply(path) -> bool:
    """True when ``path`` is a PLY whose header declares ``packed_position`` (the marker)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    end = head.find(b"end_header")
    header = head if end < 0 else head[:end]
    return head.startswith(b"ply") and b"packed_position" in header


def _unorm(v: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((v >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float64) / float((1 << bits) - 1)


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1.0 - t) + hi * t


def _unpack3(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    out = np.empty((len(v), 3), np.float64)
    for j, (shift, bits) in enumerate(((21, 11), (11, 10), (0, 11))):
        out[:, j] = _lerp(lo[:, j], hi[:, j], _unorm(v, shift, bits))
    return out


def read_compressed_ply(path) -> GaussianSet:
    """Read a PlayCanvas ``.compressed.ply`` (module docstring) into a :class:`GaussianSet`.

    Raises :class:`InputFormatError` naming the file and the element/property for: a missing
    or non-PLY file, a truncated file, missing ``chunk``/``vertex`` elements or packed
    properties, a chunk count other than ``ceil(N / 256)``, an ``sh`` element whose row count
    differs from ``vertex`` or whose ``f_rest`` count is not 9/24/45, and non-finite bounds.
    """
    label = str(path)
    p = existing_file(path)
    ply = open_plydata(label, p)

    elements = {e.name: e for e in ply.elements}
    for name in ("chunk", "vertex"):
        if name not in elements:
            raise InputFormatError(f"{label}: compressed PLY has no '{name}' element "
                                   f"(elements: {', '.join(elements) or 'none'})")
    ch, vx = elements["chunk"], elements["vertex"]
    cnames = [pr.name for pr in ch.properties]
    vnames = [pr.name for pr in vx.properties]
    for elt, names, need in (("chunk", cnames, _POS_B + _SCALE_B), ("vertex", vnames, _PACKED)):
        missing = [n for n in need if n not in names]
        if missing:
            raise InputFormatError(f"{label}: element '{elt}' lacks properties: {', '.join(missing)}")
    n = len(vx.data)
    n_chunks = len(ch.data)
    if n_chunks != (n + CHUNK - 1) // CHUNK:
        raise InputFormatError(f"{label}: element 'chunk' has {n_chunks} rows but 'vertex' has {n} rows, which "
                               f"need {(n + CHUNK - 1) // CHUNK} chunks of {CHUNK}")
    has_col = all(c in cnames for c in _COL_B)

    def bounds(names):
        b = np.stack([np.asarray(ch.data[c], dtype=np.float64) for c in names], axis=1)
        bad = ~np.isfinite(b)
        i = first_bad_index(bad) if len(b) else -1
        if i >= 0:
            j = int(np.flatnonzero(bad[i])[0])
            raise InputFormatError(f"{label}: element 'chunk' property '{names[j]}' row {i} is not finite")
        rows = np.arange(n) // CHUNK
        return b[rows, :3], b[rows, 3:]

    def packed(name):
        return np.asarray(vx.data[name]).astype(np.uint32)

    lo, hi = bounds(_POS_B)
    positions = _unpack3(packed("packed_position"), lo, hi).astype(np.float32)
    lo, hi = bounds(_SCALE_B)
    log_scales = _unpack3(packed("packed_scale"), lo, hi).astype(np.float32)
    for name, arr, limit in (("packed_position", positions, np.inf), ("packed_scale", log_scales, _LOG_SCALE_MAX)):
        bad = ~(np.abs(arr) <= limit)
        i = first_bad_index(bad) if n else -1
        if i >= 0:
            raise InputFormatError(f"{label}: element 'vertex' property '{name}' row {i} decodes to "
                                   f"{arr[i].tolist()}, outside the float32 range")

    pr = packed("packed_rotation")
    largest = (pr >> np.uint32(30)).astype(np.intp)
    abc = np.stack([(_unorm(pr, s, 10) - 0.5) * np.sqrt(2.0) for s in (20, 10, 0)], axis=1)
    q = np.empty((n, 4), np.float64)
    q[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", abc, abc)))
    others = np.asarray(_OTHERS)[largest]
    q[np.arange(n)[:, None], others] = abc
    q /= np.sqrt(np.einsum("ij,ij->i", q, q))[:, None]  # never zero: the largest is >= 0.5 or abc non-zero
    orientations = q.astype(np.float32)

    pc = packed("packed_color")
    rgb = np.stack([_unorm(pc, s, 8) for s in (24, 16, 8)], axis=1)
    if has_col:
        clo, chi = bounds(_COL_B)
        rgb = _lerp(clo, chi, rgb)
    opacities = _unorm(pc, 0, 8).astype(np.float32)

    degree = 0
    rest = None
    if "sh" in elements:
        sh_el = elements["sh"]
        snames = [pr_.name for pr_ in sh_el.properties]
        m = len(snames)
        if m not in REST_COUNT_TO_DEGREE or m == 0:
            raise InputFormatError(f"{label}: element 'sh' has {m} properties; expected 9, 24 or 45 f_rest_*")
        expected = [f"f_rest_{i}" for i in range(m)]
        missing = [e for e in expected if e not in snames]
        if missing:
            raise InputFormatError(f"{label}: element 'sh' lacks properties: {', '.join(missing)}")
        if len(sh_el.data) != n:
            raise InputFormatError(f"{label}: element 'sh' has {len(sh_el.data)} rows but 'vertex' has {n}")
        degree = REST_COUNT_TO_DEGREE[m]
        b = np.stack([np.asarray(sh_el.data[e]).astype(np.float64) for e in expected], axis=1)
        t = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
        rest = (t - 0.5) * 8.0
    k = (degree + 1) ** 2
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = (rgb - 0.5) / SH_C0
    if rest is not None:
        sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    del ply, elements
    return GaussianSet(positions, orientations, scales_from_log(log_scales), opacities, sh,
                       log_scales=log_scales, label=label)
