"""Read and write Niantic SPZ files (compressed 3D Gaussian Splats), versions 2, 3 and 4.

Container (all integers little-endian):

- versions 1..3: the whole file is one gzip stream holding a 16-byte header
  ``magic u32 = 0x5053474e ("NGSP"), version u32, numPoints u32, shDegree u8,
  fractionalBits u8, flags u8 (0x1 antialiased, 0x2 extensions follow), reserved u8``,
  then (if flag 0x2) extension records, then the attribute arrays.
- version 4: an uncompressed 32-byte header ``magic, version, numPoints, shDegree,
  fractionalBits, flags, numStreams u8, tocByteOffset u32, 12 reserved bytes``,
  extension records in ``[32, tocByteOffset)``, a table of ``numStreams`` entries
  ``(compressedSize u64, uncompressedSize u64)`` and then one zstd frame per non-empty
  attribute array, back to back. Reading or writing v4 needs the ``zstandard`` package.

Attribute arrays, in this order, N = numPoints, D = SH coefficients per channel minus 1
(0, 3, 8, 15 or 24 for degree 0..4):

- positions: N x 3 signed 24-bit fixed point, value = int24 / 2^fractionalBits.
- alphas:    N uint8, linear opacity = a / 255.
- colours:   N x 3 uint8, SH DC term ``f_dc = (c / 255 - 0.5) / 0.15``.
- scales:    N x 3 uint8, log sigma = s / 16 - 10.
- rotations: v2: N x 3 uint8 ``(x, y, z) = r / 127.5 - 1``, ``w = sqrt(1 - |xyz|^2)``;
  v3+: N x uint32 "smallest three": bits 30-31 index (in x, y, z, w order) of the largest
  component, then for the other three, highest index in the lowest bits, 10 bits each:
  9-bit magnitude ``m`` (value ``m / 511 * sqrt(1/2)``) and a sign bit (bit 9).
- SH:        N x D x 3 uint8, coefficient-major with the colour channel fastest,
  value ``(q - 128) / 128``.

Coordinates: SPZ stores positions, rotations and SH in its own frame (RUB: x right, y up,
z back). ``coordinates="native"`` (default) returns those values unchanged, which is
what PLY files converted from SPZ without an axis conversion hold (e.g. shared/data's
``biker.ply``); ``coordinates="rdf"`` converts to the RDF frame (x right, y down, z
forward; the COLMAP/INRIA-training convention of most PLY captures), i.e. negates y and
z, rotates quaternions by 180 degrees about x, and flips the odd SH coefficients.

Mapping to :class:`GaussianSet`: ``log_scales`` is kept raw (``scales = exp``),
``opacities = a / 255`` (``logit_opacities`` is left None: writers derive it),
``orientations`` are normalised (w, x, y, z), ``sh[:, 0] = f_dc``, ``sh[:, 1:]`` the
decoded SH. Degree-4 files are truncated to degree 3 (GaussianSet holds 0..3). The
antialiasing flag and extension records are not kept (except the Adobe SH-range
extension of v4 files, which changes how SH bytes decode).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from usd_gs.errors import GaussianDataError, InputFormatError, UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.io.atomic import atomic_output
from usd_gs.io.checks import existing_file
from usd_gs.io.ply import scales_from_log

SPZ_MAGIC = 0x5053474E
COLOR_SCALE = 0.15
SUPPORTED_READ_VERSIONS = (2, 3, 4)
FLAG_ANTIALIASED = 0x1
FLAG_EXTENSIONS = 0x2
EXT_SH_QUANTIZATION = 0xADBE0001
_SH_DIM = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}
_SQRT1_2 = float(np.sqrt(0.5))
_STREAMS = ("positions", "alphas", "colors", "scales", "rotations", "sh")
_COORDINATES = ("native", "rdf")
# Sign of SH coefficients 1..15 under (x, y, z) -> (x, -y, -z), from the parity of each
# 3DGS basis polynomial in y and z (the reference library's flipSh table with y = z = -1).
_RDF_SH_SIGN = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], dtype=np.float32)
_RDF_POS_SIGN = np.array([1, -1, -1], dtype=np.float32)
_RDF_QUAT_SIGN = np.array([1, 1, -1, -1], dtype=np.float32)  # (w, x, y, z)


def _coords(label: str, coordinates: str) -> bool:
    if coordinates not in _COORDINATES:
        raise UserError(f"{label}: coordinates must be one of {', '.join(_COORDINATES)}, got {coordinates!r}")
    return coordinates == "rdf"


# ------------------------------------------------------------------------------- reading
def _gunzip(label: str, data: bytes) -> bytes:
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        out = d.decompress(data)
    except zlib.error as exc:
        raise InputFormatError(f"{label}: bad gzip data in SPZ file ({exc})") from None
    if not d.eof:
        raise InputFormatError(f"{label}: SPZ file is truncated (gzip stream ends early)")
    return out


def _zstd(label: str, name: str, data: bytes, size: int) -> bytes:
    try:
        import zstandard
    except ImportError:
        raise UserError(f"{label}: SPZ version 4 needs the 'zstandard' package (pip install zstandard)") from None
    try:
        out = zstandard.ZstdDecompressor().decompress(data, max_output_size=max(size, 1))
    except zstandard.ZstdError as exc:
        raise InputFormatError(f"{label}: SPZ stream '{name}' is not valid zstd data ({exc})") from None
    if len(out) != size:
        raise InputFormatError(f"{label}: SPZ stream '{name}' decompresses to {len(out)} bytes, expected {size}")
    return out


def _stream_sizes(n: int, dim: int, rot_bytes: int) -> list[int]:
    return [9 * n, n, 3 * n, 3 * n, rot_bytes * n, 3 * dim * n]


def _sh_range_from_extensions(zone: bytes) -> tuple[float, float]:
    """(shMin, shMax) from length-delimited v4 extension records; (-1, 1) by default."""
    off = 0
    while off + 8 <= len(zone):
        typ, length = struct.unpack_from("<II", zone, off)
        payload = zone[off + 8: off + 8 + length]
        if typ == EXT_SH_QUANTIZATION and len(payload) >= 10:
            lo, hi = struct.unpack_from("<ff", payload, 2)
            if np.isfinite(lo) and np.isfinite(hi) and hi > lo:
                return float(lo), float(hi)
        off += 8 + length
    return -1.0, 1.0


def _parse_v4(label: str, data: bytes):
    if len(data) < 32:
        raise InputFormatError(f"{label}: SPZ file is truncated ({len(data)} bytes, the v4 header has 32)")
    _, version, n, degree, frac, flags, nstreams, toc = struct.unpack_from("<IIIBBBBI", data, 0)
    if degree not in _SH_DIM:
        raise InputFormatError(f"{label}: SPZ header has SH degree {degree}; 0..4 are defined")
    sizes = _stream_sizes(n, _SH_DIM[degree], 4)
    names = [nm for nm, s in zip(_STREAMS, sizes, strict=True) if s > 0]
    sizes = [s for s in sizes if s > 0]
    if nstreams != len(sizes):
        raise InputFormatError(f"{label}: SPZ v4 header has {nstreams} streams; {len(sizes)} expected "
                               f"for {n} points of SH degree {degree}")
    if toc < 32 or toc + 16 * nstreams > len(data):
        raise InputFormatError(f"{label}: SPZ file is truncated (table of contents at byte {toc} "
                               f"is beyond the end, {len(data)} bytes)")
    sh_range = _sh_range_from_extensions(data[32:toc]) if flags & FLAG_EXTENSIONS else (-1.0, 1.0)
    table = struct.unpack_from(f"<{2 * nstreams}Q", data, toc)
    off = toc + 16 * nstreams
    arrays = {}
    for i, (name, size) in enumerate(zip(names, sizes, strict=True)):
        csize, usize = table[2 * i], table[2 * i + 1]
        if usize != size:
            raise InputFormatError(f"{label}: SPZ stream '{name}' has {usize} bytes, expected {size}")
        if off + csize > len(data):
            raise InputFormatError(f"{label}: SPZ file is truncated (stream '{name}' ends at byte "
                                   f"{off + csize}, the file has {len(data)})")
        arrays[name] = np.frombuffer(_zstd(label, name, data[off: off + csize], size), dtype=np.uint8)
        off += csize
    for name in _STREAMS:
        arrays.setdefault(name, np.zeros(0, np.uint8))
    return version, n, degree, frac, arrays, sh_range


def _parse_legacy(label: str, raw: bytes):
    if len(raw) < 16:
        raise InputFormatError(f"{label}: SPZ file is truncated ({len(raw)} bytes after gunzip, the header has 16)")
    magic, version, n, degree, frac, flags, _ = struct.unpack_from("<IIIBBBB", raw, 0)
    if magic != SPZ_MAGIC:
        raise InputFormatError(f"{label}: not an SPZ file (magic 0x{magic:08x}, expected 0x{SPZ_MAGIC:08x} 'NGSP')")
    if version not in (2, 3):
        raise InputFormatError(f"{label}: SPZ version {version} is not supported "
                               f"(supported: {', '.join(map(str, SUPPORTED_READ_VERSIONS))})")
    if degree not in _SH_DIM:
        raise InputFormatError(f"{label}: SPZ header has SH degree {degree}; 0..4 are defined")
    sizes = _stream_sizes(n, _SH_DIM[degree], 4 if version >= 3 else 3)
    total = sum(sizes)
    # Extension records (flag 0x2) sit between the header and the arrays; their layout has
    # changed between library releases, so they are skipped by size, not parsed.
    start = len(raw) - total if flags & FLAG_EXTENSIONS else 16
    if start < 16 or start + total > len(raw):
        raise InputFormatError(f"{label}: SPZ file is truncated ({len(raw)} bytes after gunzip, "
                               f"{16 + total} needed for {n} points)")
    arrays = {}
    off = start
    for name, size in zip(_STREAMS, sizes, strict=True):
        arrays[name] = np.frombuffer(raw, dtype=np.uint8, count=size, offset=off)
        off += size
    return version, n, degree, frac, arrays, (-1.0, 1.0)


def _decode_rotations(r: np.ndarray, n: int, smallest_three: bool) -> np.ndarray:
    """(N, 4) float64 unit quaternions (w, x, y, z) from packed SPZ rotations."""
    q = np.zeros((n, 4))  # x, y, z, w as stored
    rows = np.arange(n)
    if smallest_three:
        b = r.reshape(n, 4).astype(np.uint32)
        comp = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16) | (b[:, 3] << 24)
        largest = (comp >> 30).astype(np.intp)
        for i in (3, 2, 1, 0):
            m = largest != i
            mag = (comp & 511).astype(np.float64) * (_SQRT1_2 / 511.0)
            q[:, i] = np.where(m, np.where((comp >> 9) & 1, -mag, mag), 0.0)
            comp = np.where(m, comp >> 10, comp)
        q[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", q, q)))
    else:
        q[:, :3] = r.reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        q[:, 3] = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", q[:, :3], q[:, :3])))
    q = q[:, [3, 0, 1, 2]]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q


def read_spz(path, coordinates: str = "native") -> GaussianSet:
    """Read an SPZ file (version 2, 3 or 4) into a :class:`GaussianSet` labelled with the path.

    ``coordinates``: ``"native"`` keeps SPZ's RUB frame, ``"rdf"`` converts to RDF (see the
    module docstring). Raises :class:`InputFormatError` naming the file for a missing file,
    bad magic, unsupported version, bad gzip/zstd data and truncated data.
    """
    label = str(path)
    flip = _coords(label, coordinates)
    p = existing_file(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise InputFormatError(f"{label}: cannot read ({exc})") from None
    if len(data) >= 8 and struct.unpack_from("<I", data, 0)[0] == SPZ_MAGIC:
        version = struct.unpack_from("<I", data, 4)[0]
        if version < 4:
            raise InputFormatError(f"{label}: uncompressed SPZ header with version {version}; "
                                   "versions 1..3 must be gzip-compressed")
        if version not in SUPPORTED_READ_VERSIONS:
            raise InputFormatError(f"{label}: SPZ version {version} is not supported "
                                   f"(supported: {', '.join(map(str, SUPPORTED_READ_VERSIONS))})")
        version, n, degree, frac, arrays, sh_range = _parse_v4(label, data)
    elif data[:2] == b"\x1f\x8b":
        version, n, degree, frac, arrays, sh_range = _parse_legacy(label, _gunzip(label, data))
    else:
        head = data[:4].hex() or "empty file"
        raise InputFormatError(f"{label}: not an SPZ file (starts with {head}; expected gzip data "
                               f"or the 'NGSP' magic of version 4)")

    if frac > 23:  # the writers' range (24-bit fixed point); above it every position collapses towards 0
        raise InputFormatError(f"{label}: header field 'fractionalBits' is {frac}, outside the format's 0..23")
    b = arrays["positions"].reshape(n, 3, 3).astype(np.int32)
    fixed = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    fixed = (fixed ^ 0x800000) - 0x800000  # sign-extend 24 bits
    positions = (fixed.astype(np.float64) * 2.0 ** -frac).astype(np.float32)
    opacities = (arrays["alphas"].astype(np.float64) / 255.0).astype(np.float32)
    log_scales = (arrays["scales"].reshape(n, 3).astype(np.float32) / np.float32(16.0) - np.float32(10.0))
    orientations = _decode_rotations(arrays["rotations"], n, version >= 3)

    k_file = _SH_DIM[degree]
    k = min(k_file, 15)
    sh = np.empty((n, k + 1, 3), dtype=np.float32)
    sh[:, 0, :] = (arrays["colors"].reshape(n, 3).astype(np.float64) / 255.0 - 0.5) / COLOR_SCALE
    if k:
        q = arrays["sh"].reshape(n, k_file, 3)[:, :k, :].astype(np.float32)
        lo, hi = sh_range
        if (lo, hi) == (-1.0, 1.0):
            sh[:, 1:, :] = (q - np.float32(128.0)) / np.float32(128.0)
        else:
            sh[:, 1:, :] = np.float32(lo) + q / np.float32(255.0) * np.float32(hi - lo)

    if flip:
        positions *= _RDF_POS_SIGN
        orientations *= _RDF_QUAT_SIGN
        sh[:, 1:, :] *= _RDF_SH_SIGN[:k, None]
    return GaussianSet(positions, orientations.astype(np.float32), scales_from_log(log_scales), opacities, sh,
                       log_scales=log_scales, label=label)


# ------------------------------------------------------------------------------- writing
def _to_u8(x: np.ndarray) -> np.ndarray:
    """Round half up and clamp to 0..255 (the reference ``toUint8`` for these inputs)."""
    return np.clip(np.floor(np.asarray(x, dtype=np.float64) + 0.5), 0, 255).astype(np.uint8)


def _pack_rotations(q_wxyz: np.ndarray, smallest_three: bool) -> np.ndarray:
    q = np.asarray(q_wxyz, dtype=np.float64)[:, [1, 2, 3, 0]]  # x, y, z, w
    n = len(q)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 0.0, 1.0]))
    if not smallest_three:
        q = q * np.where(q[:, 3:] < 0, -127.5, 127.5) + 127.5
        return _to_u8(q[:, :3]).reshape(-1)
    largest = np.argmax(np.abs(q), axis=1)
    negate = q[np.arange(n), largest] < 0
    comp = largest.astype(np.uint32)
    for i in range(4):
        m = largest != i
        neg = ((q[:, i] < 0) ^ negate).astype(np.uint32)
        mag = np.minimum(np.floor(511.0 * np.abs(q[:, i]) / _SQRT1_2 + 0.5), 511).astype(np.uint32)
        comp = np.where(m, (comp << 10) | (neg << 9) | mag, comp)
    return comp.astype("<u4").view(np.uint8)


def _pack_sh(x: np.ndarray, bits: int) -> np.ndarray:
    """Reference ``quantizeSHLegacy``: round(x * 128) + 128 (half away from zero), then to
    the nearest multiple of ``2^(8 - bits)`` (ties up), clamped to 0..255."""
    shift = 8 - bits
    v = np.clip(np.asarray(x, dtype=np.float32) * np.float32(128.0), -256.0, 256.0)  # exact: power of 2
    r = np.floor(np.abs(v) + np.float32(0.5))
    q = np.copysign(r, v).astype(np.int32) + 128
    q = ((q + ((1 << shift) >> 1)) >> shift) << shift  # floor division by a power of two
    return np.clip(q, 0, 255).astype(np.uint8)


def write_spz(path, gaussians: GaussianSet, version: int = 3, coordinates: str = "native",
              fractional_bits: int | None = None, sh1_bits: int = 5, sh_rest_bits: int = 4) -> None:
    """Write ``gaussians`` as SPZ ``version`` 2, 3 (gzip, default) or 4 (zstd streams).

    Quantisation follows the reference encoder: positions to 24-bit fixed point with
    ``fractional_bits`` (default: 12, lowered automatically when the positions need more
    range; a position beyond 2^23 units raises), ``round((log sigma + 10) * 16)``,
    ``round(opacity * 255)``, ``round(f_dc * 0.15 * 255 + 127.5)``, rotations as described
    in the module docstring, SH rounded to 1/128 then to buckets of ``sh1_bits`` (band 1)
    and ``sh_rest_bits`` (bands 2-3) significant bits. ``coordinates="rdf"`` means the set
    is in RDF and is converted to SPZ's RUB frame. The antialiasing flag is written as 0.
    Written atomically (temporary file + ``os.replace``).
    """
    g = gaussians
    label = g.label
    flip = _coords(label, coordinates)
    if version not in (2, 3, 4):
        raise UserError(f"{path}: cannot write SPZ version {version} (2, 3 or 4)")
    for name, bits in (("sh1_bits", sh1_bits), ("sh_rest_bits", sh_rest_bits)):
        if not 1 <= bits <= 8:
            raise UserError(f"{path}: {name} must be 1..8, got {bits}")
    problems = [p for p in g.problems() if "unit quaternion" not in p]
    if problems:
        raise GaussianDataError("; ".join(problems))
    n = g.count
    pos = g.positions.astype(np.float64)
    if flip:
        pos = pos * _RDF_POS_SIGN
    limit = 2.0 ** 23 - 1
    maxabs = float(np.abs(pos).max()) if n else 0.0
    if fractional_bits is None:
        frac = 12
        while frac > 0 and maxabs * 2.0 ** frac > limit:
            frac -= 1
    else:
        frac = int(fractional_bits)
        if not 0 <= frac <= 23:
            raise UserError(f"{path}: fractional_bits must be 0..23, got {frac}")
    fixed = np.sign(pos) * np.floor(np.abs(pos) * 2.0 ** frac + 0.5)
    over = np.abs(fixed) > limit
    if over.any():
        i = int(np.flatnonzero(over.any(axis=1))[0])
        raise GaussianDataError(f"{label}: 'positions' element {i} ({g.positions[i]}) is outside the SPZ "
                                f"24-bit range with {frac} fractional bits")
    packed_pos = (fixed.astype(np.int64) & 0xFFFFFF).astype("<u4").view(np.uint8).reshape(n, 3, 4)[:, :, :3]

    log_s = g.log_scales if g.log_scales is not None else np.log(g.scales.astype(np.float64))
    q = g.orientations.astype(np.float64)
    sh = g.sh.astype(np.float64)
    if flip:
        q = q * _RDF_QUAT_SIGN
        sh[:, 1:, :] *= _RDF_SH_SIGN[: sh.shape[1] - 1, None]
    degree = g.sh_degree
    streams = [
        np.ascontiguousarray(packed_pos).reshape(-1),
        _to_u8(g.opacities.astype(np.float64) * 255.0),
        _to_u8(sh[:, 0, :] * (COLOR_SCALE * 255.0) + 127.5).reshape(-1),
        _to_u8((np.asarray(log_s, np.float64) + 10.0) * 16.0).reshape(-1),
        _pack_rotations(q, version >= 3),
    ]
    if degree > 0:
        rest = np.empty((n, sh.shape[1] - 1, 3), np.uint8)
        rest[:, :3] = _pack_sh(sh[:, 1:4, :], sh1_bits)
        rest[:, 3:] = _pack_sh(sh[:, 4:, :], sh_rest_bits)
        streams.append(rest.reshape(-1))
    blobs = [np.ascontiguousarray(s).tobytes() for s in streams]

    if version == 4:
        try:
            import zstandard
        except ImportError:
            raise UserError(f"{path}: writing SPZ version 4 needs the 'zstandard' package") from None
        blobs = [b for b in blobs if b]
        cctx = zstandard.ZstdCompressor(level=6)
        comp = [cctx.compress(b) for b in blobs]
        header = struct.pack("<IIIBBBBI12x", SPZ_MAGIC, 4, n, degree, frac, 0, len(blobs), 32)
        toc = b"".join(struct.pack("<QQ", len(c), len(b)) for c, b in zip(comp, blobs, strict=True))
        payload = header + toc + b"".join(comp)
    else:
        header = struct.pack("<IIIBBBB", SPZ_MAGIC, version, n, degree, frac, 0, 0)
        c = zlib.compressobj(6, zlib.DEFLATED, 16 + zlib.MAX_WBITS, 9)
        payload = c.compress(header + b"".join(blobs)) + c.flush()

    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(payload)

