"""Read and write antimatter15 ``.splat`` files (the WebGL viewer's flat splat layout).

Quantisation: position and linear scale float32, colour and opacity u8 (1/255), quaternion
u8 per component as ``q*128+128`` (step 1/128), no SH above the DC term.

File layout: no header, one 32-byte little-endian record per Gaussian:

- bytes 0..11   ``x, y, z`` float32 centre (file units, no axis conversion: a Y-down capture
                stays Y-down).
- bytes 12..23  ``sx, sy, sz`` float32 per-axis standard deviation, LINEAR (not log).
- bytes 24..27  ``r, g, b, a`` u8: display colour ``0.5 + C0 * f_dc`` and linear opacity,
                both times 255.
- bytes 28..31  quaternion ``(w, x, y, z)`` u8, each component ``q*128 + 128`` clamped to
                0..255.

Mapping to :class:`usd_gs.gaussians.GaussianSet`: ``sh[:, 0] = (rgb/255 - 0.5) / C0`` with
``C0 = 0.28209479177387814`` (degree 0), ``opacities = a/255``, ``orientations`` =
``(u - 128)/128`` normalised in float64 (antimatter15's own decode; PlayCanvas
splat-transform decodes ``u/255*2 - 1`` instead, which differs by < 0.01 per component),
``scales`` as stored. ``log_scales`` is ``log(scales)`` so an INRIA PLY export writes the
same values splat-transform writes.
"""

from __future__ import annotations

import numpy as np

from usd_gs.errors import GaussianDataError, InputFormatError, first_bad_index
from usd_gs.gaussians import GaussianSet
from usd_gs.io.atomic import atomic_output
from usd_gs.io.checks import existing_file

SH_C0 = 0.28209479177387814
RECORD_BYTES = 32

_RECORD = np.dtype([("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
assert _RECORD.itemsize == RECORD_BYTES


def _load_bytes(label: str, path) -> bytes | np.ndarray:
    p = existing_file(path)
    try:
        return np.fromfile(str(p), dtype=np.uint8)
    except OSError as exc:
        raise InputFormatError(f"{label}: cannot be read ({exc})") from None


def decode_splat(label: str, data) -> GaussianSet:
    """Decode the bytes of a ``.splat`` file (see the module docstring) into a GaussianSet.

    Raises :class:`InputFormatError` naming ``label`` and the field for a size that is not a
    positive multiple of 32, a non-finite position or scale, a scale <= 0 and a zero
    quaternion (all four bytes 128).
    """
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    size = buf.size
    if size == 0:
        raise InputFormatError(f"{label}: empty .splat file (no 32-byte records)")
    if size % RECORD_BYTES:
        raise InputFormatError(f"{label}: file size {size} bytes is not a multiple of the 32-byte .splat record "
                               f"({size // RECORD_BYTES} whole records and {size % RECORD_BYTES} bytes over)")
    rec = buf.view(_RECORD)
    n = rec.shape[0]
    positions = np.array(rec["pos"], dtype=np.float32)
    scales = np.array(rec["scale"], dtype=np.float32)
    for name, arr in (("position", positions), ("scale", scales)):
        bad = ~np.isfinite(arr)
        i = first_bad_index(bad)
        if i >= 0:
            raise InputFormatError(f"{label}: record {i} field '{name}' is not finite ({arr[i].tolist()})")
    i = first_bad_index(scales <= 0)
    if i >= 0:
        raise InputFormatError(f"{label}: record {i} field 'scale' is not > 0 ({scales[i].tolist()})")
    rgba = rec["rgba"]
    sh = ((rgba[:, :3].astype(np.float64) / 255.0 - 0.5) / SH_C0).astype(np.float32).reshape(n, 1, 3)
    opacities = (rgba[:, 3].astype(np.float64) / 255.0).astype(np.float32)
    q = (rec["rot"].astype(np.float64) - 128.0) / 128.0
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    i = first_bad_index(norm == 0)
    if i >= 0:
        raise InputFormatError(f"{label}: record {i} field 'rotation' is a zero quaternion (bytes 128,128,128,128)")
    orientations = (q / norm[:, None]).astype(np.float32)
    with np.errstate(divide="ignore"):
        log_scales = np.log(scales.astype(np.float64)).astype(np.float32)
    return GaussianSet(positions, orientations, scales, opacities, sh, log_scales=log_scales, label=label)


def read_splat(path) -> GaussianSet:
    """Read an antimatter15 ``.splat`` file (module docstring) into a :class:`GaussianSet`.

    Raises :class:`InputFormatError` naming the file and the record/field on bad input.
    """
    label = str(path)
    return decode_splat(label, _load_bytes(label, path))


def _u8(x: np.ndarray) -> np.ndarray:
    """float -> nearest u8, clamped to 0..255 (in place on ``x``)."""
    np.rint(x, out=x)
    np.clip(x, 0, 255, out=x)
    return x.astype(np.uint8)


def encode_splat(gaussians: GaussianSet) -> np.ndarray:
    """The 32-byte records of ``gaussians`` as a ``(N,)`` structured array (module layout).

    SH above degree 0 is dropped; colours and opacity are rounded to the nearest u8 and
    clamped (float32 arithmetic); quaternions are normalised in float64 (a zero one becomes
    the identity), then ``round(q*128 + 128)`` clamped to 0..255.
    """
    g = gaussians
    n = g.count
    for name, arr in (("positions", g.positions), ("scales", g.scales), ("sh", g.sh[:, 0, :]),
                      ("opacities", g.opacities), ("orientations", g.orientations)):
        with np.errstate(over="ignore", invalid="ignore"):
            if np.isfinite(arr.sum()):
                continue
        bad = ~np.isfinite(arr)
        i = first_bad_index(bad.reshape(len(arr), -1)) if len(arr) else -1
        if i >= 0:
            raise GaussianDataError(f"{g.label}: cannot write .splat: '{name}' element {i} is not finite")
    out = np.empty((n, RECORD_BYTES), np.uint8)
    f = out.view(np.float32)  # (n, 8): position, scale, then the 8 bytes of colour and rotation
    f[:, 0:3] = g.positions
    f[:, 3:6] = g.scales
    rgb = g.sh[:, 0, :] * np.float32(SH_C0)
    rgb += np.float32(0.5)
    rgb *= np.float32(255.0)
    out[:, 24:27] = _u8(rgb)
    out[:, 27] = _u8(g.opacities * np.float32(255.0))
    q = g.orientations.astype(np.float64)
    n2 = np.einsum("ij,ij->i", q, q)
    zero = n2 == 0
    if zero.any():
        q[zero] = (1.0, 0.0, 0.0, 0.0)
        n2[zero] = 1.0
    q /= np.sqrt(n2)[:, None]
    q *= 128.0
    q += 128.0
    out[:, 28:32] = _u8(q)
    return out.view(_RECORD).reshape(n)


def write_splat(path, gaussians: GaussianSet) -> None:
    """Write ``gaussians`` as an antimatter15 ``.splat`` (see :func:`encode_splat`), atomically."""
    rec = encode_splat(gaussians)
    with atomic_output(path) as tmp:
        rec.tofile(str(tmp))
