"""Read and write 3D Gaussian Splat PLY files in the INRIA (graphdeco 3DGS) layout.

File layout (one ``vertex`` element, one row per Gaussian):

- ``x, y, z``                 centre, file units (no axis conversion is applied: a Y-up
                                capture stays Y-up, a Y-down COLMAP capture stays Y-down).
- ``f_dc_0..2``               SH DC term per channel (raw 3DGS coefficient, not a colour).
- ``f_rest_0..f_rest_{M-1}``  higher SH bands, CHANNEL-major: with ``K = (d+1)^2``
                                coefficients per channel, ``f_rest[c*(K-1) + j]`` is
                                coefficient ``j+1`` of channel ``c``. ``M`` is 0, 9, 24 or 45
                                (SH degree 0..3); any other count is an error.
- ``opacity``                 logit of the linear opacity.
- ``scale_0..2``              natural log of the per-axis standard deviation.
- ``rot_0..3``                quaternion ``(w, x, y, z)``, not necessarily unit.

Mapping to :class:`usd_gs.gaussians.GaussianSet` (shared/DESIGN.md section 1):

- ``scales = exp(scale_*)`` and ``opacities = sigmoid(opacity)``, evaluated in float64 and
  rounded once to float32 (a stable sigmoid: logits of ``-inf``/``+inf`` give exactly 0/1).
  A log-scale below the float32 range gives the smallest normal float32 instead of 0.
- ``sh = concat(f_dc[:, None], f_rest.reshape(N, 3, K-1).transpose(0, 2, 1))``, shape
  ``(N, K, 3)``, particle-major, coefficient-major within a particle.
- ``orientations`` are the ``rot_*`` quaternions normalised in float64 (those whose norm is
  already 1 within 2^-22 are kept bit for bit, so that re-reading a written file is exact).
- the raw ``scale_*`` and ``opacity`` float32 values are kept in ``log_scales`` and
  ``logit_opacities`` so that PLY -> GaussianSet -> PLY is bit-exact.
- every other vertex property (``nx, ny, nz``, ...) is kept in ``extras`` under its PLY
  name with its PLY dtype and written back after ``x, y, z``.

Properties stored as another numeric type (double, int...) are accepted and converted to
float32. Both binary (little or big endian) and ASCII files are read; binary files are
memory-mapped and converted with whole-column numpy operations.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile

from usd_gs import sh3dgs
from usd_gs.errors import GaussianDataError, InputFormatError, first_bad_index
from usd_gs.gaussians import (  # noqa: F401  (raw <-> linear conversions, re-exported)
    OPACITY_EPS,
    GaussianSet,
    logit_from_opacities,
    opacities_from_logit,
    scales_from_log,
)
from usd_gs.io.atomic import atomic_output
from usd_gs.io.checks import existing_file

#: number of ``f_rest_*`` properties -> SH degree
REST_COUNT_TO_DEGREE = {0: 0, 9: 1, 24: 2, 45: 3}


_POS = ("x", "y", "z")
_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
_SCALE = ("scale_0", "scale_1", "scale_2")
_ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
_REQUIRED = _POS + _DC + ("opacity",) + _SCALE + _ROT

# exp() of log-scales outside this range leaves the float32 normal range
_LOG_SCALE_MAX = float(np.log(np.finfo(np.float32).max))
# a float32 quaternion whose float64 norm is this close to 1 is unit to float32 precision
_UNIT_TOL = 2.0 ** -22

# numpy dtype kind/size -> PLY type name (what plyfile writes)
_PLY_TYPES = {
    np.dtype(np.int8): "i1", np.dtype(np.uint8): "u1", np.dtype(np.int16): "i2",
    np.dtype(np.uint16): "u2", np.dtype(np.int32): "i4", np.dtype(np.uint32): "u4",
    np.dtype(np.float32): "f4", np.dtype(np.float64): "f8",
}




# ------------------------------------------------------------------------------- reading
class _Columns:
    """Column access to a PLY element's structured array without per-row Python loops.

    When every property is a native float32 (the usual 3DGS file), the structured array is
    viewed as an (N, P) float32 matrix so that runs of consecutive properties are sliced
    as blocks; otherwise each property is converted column by column.
    """

    def __init__(self, data: np.ndarray, names: list[str]):
        self.data = data
        self.names = names
        self.index = {n: i for i, n in enumerate(names)}
        self.matrix = None
        dt = data.dtype
        f4 = np.dtype(np.float32)
        if (dt.itemsize == 4 * len(names)
                and all(dt.fields[n][0] == f4 and dt.fields[n][1] == 4 * i for i, n in enumerate(names))):
            try:
                self.matrix = np.ndarray((len(data), len(names)), dtype=np.float32, buffer=data,
                                         strides=(dt.itemsize, 4))
            except (TypeError, ValueError):
                self.matrix = None

    def _run(self, names) -> slice | None:
        idx = [self.index[n] for n in names]
        if idx == list(range(idx[0], idx[0] + len(idx))):
            return slice(idx[0], idx[0] + len(idx))
        return None

    def block(self, names, copy: bool = False) -> np.ndarray:
        """(N, len(names)) float32; a view of the file data where possible unless ``copy``."""
        if self.matrix is not None:
            run = self._run(names)
            if run is not None:
                view = self.matrix[:, run]
                return np.array(view) if copy else view
            return self.matrix[:, [self.index[n] for n in names]]  # fancy index: a new array
        out = np.empty((len(self.data), len(names)), dtype=np.float32)
        for j, n in enumerate(names):
            out[:, j] = self.data[n]
        return out

    def raw(self, name: str) -> np.ndarray:
        """One property as a new native-byte-order array of its own dtype."""
        col = self.data[name]
        return np.array(col, dtype=col.dtype.newbyteorder("="))


def _rest_names(label: str, names: list[str]) -> list[str]:
    rest = [n for n in names if n.startswith("f_rest_")]
    m = len(rest)
    if m not in REST_COUNT_TO_DEGREE:
        raise InputFormatError(
            f"{label}: element 'vertex' has {m} 'f_rest_*' properties; expected 0, 9, 24 or 45 "
            "(SH degree 0..3)")
    expected = [f"f_rest_{i}" for i in range(m)]
    missing = sorted(set(expected) - set(rest), key=lambda s: int(s[7:]) if s[7:].isdigit() else -1)
    if missing:
        raise InputFormatError(
            f"{label}: element 'vertex' has {m} 'f_rest_*' properties but lacks {', '.join(missing)}")
    return expected


def _first_bad(arr: np.ndarray, allow_inf: bool = False) -> tuple[int, int, int] | None:
    """(row, column, number of bad rows) of the first NaN (or Inf) in ``arr``, else None.

    A cheap sum is tried first: any NaN/Inf makes it non-finite; only then (or when finite
    values overflow the sum) is the element-wise mask built.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(arr.sum()):
            return None
    flat = arr.reshape(len(arr), -1)
    bad = np.isnan(flat) if allow_inf else ~np.isfinite(flat)
    i = first_bad_index(bad) if len(bad) else -1
    if i < 0:
        return None
    return i, int(np.flatnonzero(bad[i])[0]), int(bad.any(axis=1).sum())


def _check_finite(label: str, arrays, allow_inf: bool = False) -> None:
    """Raise naming the first property (in the given order) holding NaN (or Inf)."""
    for names, arr in arrays:
        hit = _first_bad(arr, allow_inf)
        if hit is None:
            continue
        i, j, nbad = hit
        what = "NaN" if allow_inf else "not finite"
        raise InputFormatError(
            f"{label}: vertex property '{names[j]}' element {i} is {what} "
            f"(value {arr.reshape(len(arr), -1)[i, j]!r}); {nbad} bad element{'s' if nbad != 1 else ''}")


_PLY_TYPE_BYTES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
                   "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8,
                   "float64": 8}


def _check_claimed_size(label: str, p: Path) -> None:
    """``InputFormatError`` when the header's element counts need more bytes than the file holds
    (a corrupt or hostile header claiming 1e12 vertices would otherwise be allocated before the
    data is read): each row needs at least its binary size, or 2 bytes a value in ASCII."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return  # plyfile reports what is wrong
    body = p.stat().st_size - (head.find(b"\n", end) + 1)
    ascii_ = b"format ascii" in head[:end]
    need, elements = 0, []
    for line in head[:end].decode("ascii", "replace").splitlines():
        w = line.split()
        if len(w) >= 3 and w[0] == "element":
            try:
                elements.append([w[1], int(w[2]), 0])
            except ValueError:
                return
        elif len(w) >= 3 and w[0] == "property" and elements:
            elements[-1][2] += 1 if ascii_ else (1 if w[1] == "list" else _PLY_TYPE_BYTES.get(w[1], 1))
    for name, count, row in elements:
        per_row = 2 * max(row, 1) if ascii_ else max(row, 1)
        need += count * per_row
        if count < 0 or need > body + 1:
            raise InputFormatError(f"{label}: element '{name}': the header claims {count:,} rows, more than the "
                                   f"{max(body, 0):,} bytes of data can hold (the file is truncated or corrupt)")


def open_plydata(label: str, p) -> plyfile.PlyData:
    """``plyfile.PlyData`` of the PLY file ``p`` (memory-mapped); ``InputFormatError`` naming
    ``label`` and, where plyfile says, the element, property and row of a bad or truncated file."""
    try:
        return plyfile.PlyData.read(str(p), mmap="r")
    except plyfile.PlyHeaderParseError as exc:
        raise InputFormatError(f"{label}: not a PLY file or bad PLY header ({exc})") from None
    except plyfile.PlyElementParseError as exc:
        elt = exc.element.name if exc.element is not None else "?"
        where = f" at row {exc.row}" if exc.row is not None else ""
        prop = f", property '{exc.prop.name}'" if exc.prop is not None else ""
        what = "file is truncated" if "end-of-file" in exc.message else exc.message
        raise InputFormatError(f"{label}: element '{elt}'{prop}: {what}{where}") from None
    except (OSError, ValueError, UnicodeDecodeError, OverflowError, MemoryError) as exc:  # Overflow: ASCII -1, uchar
        raise InputFormatError(f"{label}: cannot be read as PLY ({exc})") from None


def read_ply(path) -> GaussianSet:
    """Read an INRIA-layout 3DGS PLY file (binary or ASCII) into a :class:`GaussianSet`.

    See the module docstring for the field mapping. ``label`` is the file path. Raises
    :class:`InputFormatError` (message names the file and the element/property) for a
    missing or unreadable file, a non-PLY file, a truncated file, no ``vertex`` element,
    missing required properties, an f_rest count other than 0/9/24/45, NaN/Inf in a
    required property (opacity may be +/-inf, not NaN), a log-scale whose exp overflows
    float32, and a zero quaternion.
    """
    label = str(path)
    p = existing_file(path)
    _check_claimed_size(label, p)
    ply = open_plydata(label, p)

    names_elt = [e.name for e in ply.elements]
    if "vertex" not in names_elt:
        raise InputFormatError(f"{label}: no 'vertex' element (elements: {', '.join(names_elt) or 'none'})")
    el = ply["vertex"]
    list_props = [pr.name for pr in el.properties if isinstance(pr, plyfile.PlyListProperty)]
    if list_props:
        raise InputFormatError(f"{label}: element 'vertex' has list properties {', '.join(list_props)}")
    names = [pr.name for pr in el.properties]
    missing = [n for n in _REQUIRED if n not in names]
    if missing:
        raise InputFormatError(f"{label}: element 'vertex' lacks required properties: {', '.join(missing)}")
    rest = _rest_names(label, names)
    k = sh3dgs.num_coeffs(REST_COUNT_TO_DEGREE[len(rest)])

    cols = _Columns(el.data, names)
    n = len(el.data)
    positions = cols.block(_POS, copy=True)
    sh = np.empty((n, k, 3), dtype=np.float32)
    sh[:, 0, :] = cols.block(_DC)
    if k > 1:
        sh[:, 1:, :] = cols.block(rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    log_scales = cols.block(_SCALE, copy=True)
    logits = np.array(cols.block(("opacity",))[:, 0])
    rot = cols.block(_ROT, copy=True)

    _check_finite(label, [(_POS, positions), (_DC, sh[:, 0, :])])
    if k > 1:
        _check_finite(label, [([f"f_rest_{c * (k - 1) + j}" for j in range(k - 1) for c in range(3)],
                               sh[:, 1:, :])])
    _check_finite(label, [(("opacity",), logits)], allow_inf=True)
    _check_finite(label, [(_SCALE, log_scales), (_ROT, rot)])
    big = log_scales > _LOG_SCALE_MAX
    i = first_bad_index(big) if n else -1
    if i >= 0:
        j = int(np.flatnonzero(big[i])[0])
        raise InputFormatError(
            f"{label}: vertex property '{_SCALE[j]}' element {i} is {log_scales[i, j]!r}: "
            "exp() of it overflows float32")

    q64 = rot.astype(np.float64)
    norm = np.sqrt(np.einsum("ij,ij->i", q64, q64))
    i = first_bad_index(norm == 0) if n else -1
    if i >= 0:
        raise InputFormatError(
            f"{label}: vertex properties 'rot_0..rot_3' element {i} are a zero quaternion")
    q64 /= norm[:, None]
    orientations = q64.astype(np.float32)
    # Quaternions already unit to float32 precision are kept bit for bit, so that
    # read -> write -> read is idempotent (re-normalising can move the last bit).
    keep = np.abs(norm - 1.0) <= _UNIT_TOL
    orientations[keep] = rot[keep]
    del q64, rot

    extras = {}
    used = set(_REQUIRED) | set(rest)
    for name in names:
        if name not in used:
            extras[name] = cols.raw(name)
    del cols, el, ply

    return GaussianSet(positions, orientations, scales_from_log(log_scales), opacities_from_logit(logits),
                       sh, log_scales=log_scales, logit_opacities=logits, extras=extras, label=label)


# ------------------------------------------------------------------------------- writing
def _extra_columns(g: GaussianSet) -> list[tuple[str, np.ndarray]]:
    """Extras as (PLY name, 1-D array) pairs; (N, k) extras become name_0..name_{k-1}."""
    out = []
    reserved = set(_REQUIRED)
    for key, arr in g.extras.items():
        a = np.asarray(arr)
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        if a.dtype.newbyteorder("=") not in _PLY_TYPES:
            raise GaussianDataError(
                f"{g.label}: extra field '{key}' has dtype {a.dtype}, which PLY cannot store")
        a = a.astype(a.dtype.newbyteorder("="), copy=False)
        if a.ndim == 1:
            parts = [(key, a)]
        else:
            flat = a.reshape(len(a), -1)
            parts = [(f"{key}_{i}", flat[:, i]) for i in range(flat.shape[1])]
        for name, col in parts:
            if name in reserved or name.startswith("f_rest_") or any(name == o[0] for o in out):
                raise GaussianDataError(f"{g.label}: extra field '{name}' clashes with a 3DGS PLY property")
            if not name or any(ch.isspace() for ch in name):
                raise GaussianDataError(f"{g.label}: extra field name {name!r} is not a valid PLY property name")
            out.append((name, col))
    return out


def _check_output(g: GaussianSet, arrays, allow_inf: bool = False) -> None:
    for names, arr in arrays:
        hit = _first_bad(arr, allow_inf)
        if hit is not None:
            i, j, _ = hit
            raise GaussianDataError(
                f"{g.label}: PLY property '{names[j]}' element {i} would be "
                f"{arr.reshape(len(arr), -1)[i, j]!r} (not finite)")


def write_ply(path, gaussians: GaussianSet, binary: bool = True) -> None:
    """Write ``gaussians`` as an INRIA-layout 3DGS PLY (binary little-endian or ASCII).

    Property order: ``x, y, z``, the extras (original order; an (N, k) extra is written as
    ``name_0..name_{k-1}``), ``f_dc_0..2``, ``f_rest_*`` (channel-major), ``opacity``,
    ``scale_0..2``, ``rot_0..3`` (w, x, y, z). ``opacity`` and ``scale_*`` are the raw
    ``logit_opacities`` / ``log_scales`` when the set has them (bit-exact round trip),
    otherwise ``logit(clip(opacities, 1e-7, 1 - 1e-7))`` and ``log(scales)`` computed in
    float64. Non-finite output values raise :class:`GaussianDataError` naming the property
    and element. The file is written to a temporary file in the same directory and moved
    into place with ``os.replace`` (no partial file on error; no fsync).
    """
    g = gaussians
    n = g.count
    k = g.sh.shape[1]
    rest = [f"f_rest_{i}" for i in range(3 * (k - 1))]
    extras = _extra_columns(g)
    logit = g.logit_opacities if g.logit_opacities is not None else logit_from_opacities(g.opacities)
    if g.log_scales is not None:
        log_scales = g.log_scales
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            log_scales = np.log(g.scales.astype(np.float64)).astype(np.float32)
    _check_output(g, [(_POS, g.positions), (_DC, g.sh[:, 0, :]),
                      ([f"f_rest_{c * (k - 1) + j}" for j in range(k - 1) for c in range(3)], g.sh[:, 1:, :]),
                      (_SCALE, log_scales), (_ROT, g.orientations)])
    _check_output(g, [(("opacity",), logit)], allow_inf=True)

    names = list(_POS) + [e[0] for e in extras] + list(_DC) + rest + ["opacity"] + list(_SCALE) + list(_ROT)
    dtypes = ["f4"] * 3 + [_PLY_TYPES[e[1].dtype] for e in extras] + ["f4"] * (len(names) - 3 - len(extras))
    struct = np.dtype([(nm, "<" + t if t not in ("i1", "u1") else t) for nm, t in zip(names, dtypes, strict=True)])
    nx = len(extras)
    a_dc = 3 + nx
    a_rest = a_dc + 3
    a_op = a_rest + len(rest)
    a_sc = a_op + 1
    a_rot = a_sc + 3
    if all(t == "f4" for t in dtypes):
        mat = np.empty((n, len(names)), dtype=np.float32)
        mat[:, 0:3] = g.positions
        for j, (_, col) in enumerate(extras):
            mat[:, 3 + j] = col
        mat[:, a_dc:a_rest] = g.sh[:, 0, :]
        if k > 1:
            np.reshape(mat[:, a_rest:a_op], (n, 3, k - 1), copy=False)[...] = g.sh[:, 1:, :].transpose(0, 2, 1)
        mat[:, a_op] = logit
        mat[:, a_sc:a_rot] = log_scales
        mat[:, a_rot:] = g.orientations
        arr = mat.view(struct).reshape(n)
    else:
        arr = np.empty(n, dtype=struct)
        for j, nm in enumerate(_POS):
            arr[nm] = g.positions[:, j]
        for nm, col in extras:
            arr[nm] = col
        for c, nm in enumerate(_DC):
            arr[nm] = g.sh[:, 0, c]
        for c in range(3):
            for j in range(k - 1):
                arr[rest[c * (k - 1) + j]] = g.sh[:, 1 + j, c]
        arr["opacity"] = logit
        for j, nm in enumerate(_SCALE):
            arr[nm] = log_scales[:, j]
        for j, nm in enumerate(_ROT):
            arr[nm] = g.orientations[:, j]

    ply = plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")], text=not binary, byte_order="<")
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        ply.write(f)
