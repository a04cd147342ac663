"""Environment images: lat-long conventions, HDR/EXR reading, OpenEXR writing, cube <-> lat-long.

Lat-long convention (Y-up, matches three.js ``equirectUv``): an (H, W) image, row 0 at the
top. Pixel (i, j) centre has polar angle ``theta = pi (i + 0.5) / H`` measured from +Y and
azimuth ``phi = 2 pi (j + 0.5) / W - pi``, direction
``(sin theta cos phi, cos theta, sin theta sin phi)``: the top row looks up (+Y), the image
centre looks along +X, column 0 along -X, a quarter of the width along -Z.
Pixel values are linear radiance (RGB). Cube faces use ``numba_kernels.cubemap_dirs``
(OpenGL layout, pure numpy, no numba import).

This module does file I/O and must not import numba at import time; the SH helpers import
``numba_kernels.sh_real`` lazily (only when a degree > 3 RH basis is evaluated).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from numba_kernels.cubemap_dirs import cube_face_directions, sample_cube_faces
from usd_gs.errors import InputFormatError

# --------------------------------------------------------------------------- conventions


def latlong_directions(h: int, w: int) -> np.ndarray:
    """Unit directions of lat-long pixel centres, (h, w, 3) float64 (module convention)."""
    th = np.pi * (np.arange(h, dtype=np.float64) + 0.5) / h
    ph = 2.0 * np.pi * (np.arange(w, dtype=np.float64) + 0.5) / w - np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    st = np.sin(t)
    return np.stack([st * np.cos(p), np.cos(t), st * np.sin(p)], axis=-1)


def latlong_solid_angles(h: int, w: int) -> np.ndarray:
    """Exact solid angle of each lat-long pixel, (h, w) float64, summing to 4 pi.

    Row i spans ``theta in [pi i / h, pi (i+1) / h]``: ``(cos t0 - cos t1) * 2 pi / w``.
    """
    edges = np.pi * np.arange(h + 1, dtype=np.float64) / h
    rows = (np.cos(edges[:-1]) - np.cos(edges[1:])) * (2.0 * np.pi / w)
    return np.broadcast_to(rows[:, None], (h, w)).copy()


def directions_to_latlong_pixel(dirs: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel coordinates (row, col) of directions (..., 3); centre of (i, j) is (i, j)."""
    d = np.asarray(dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    phi = np.arctan2(d[..., 2], d[..., 0])
    row = theta / np.pi * h - 0.5
    col = (phi + np.pi) / (2.0 * np.pi) * w - 0.5
    return row, col


def latlong_lookup(img: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a lat-long image (h, w, C) at directions (..., 3): (..., C) float64.

    Wraps in azimuth, clamps in polar angle.
    """
    img = np.asarray(img)
    h, w = img.shape[:2]
    row, col = directions_to_latlong_pixel(dirs, h, w)
    row = np.clip(row, 0.0, h - 1.0)
    r0 = np.floor(row).astype(np.int64)
    r1 = np.minimum(r0 + 1, h - 1)
    fr = (row - r0)[..., None]
    c0f = np.floor(col)
    fc = (col - c0f)[..., None]
    c0 = c0f.astype(np.int64) % w
    c1 = (c0 + 1) % w
    im = img.astype(np.float64, copy=False)
    top = im[r0, c0] * (1.0 - fc) + im[r0, c1] * fc
    bot = im[r1, c0] * (1.0 - fc) + im[r1, c1] * fc
    return top * (1.0 - fr) + bot * fr


def latlong_to_cube_faces(img: np.ndarray, size: int, supersample: int = 1) -> np.ndarray:
    """Resample a lat-long image into cube faces (6, size, size, C) float32.

    Each texel is the mean of ``supersample^2`` bilinear lookups on a regular sub-grid
    (``supersample=1``: one lookup at the texel centre).
    """
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    dirs = cube_face_directions(size * ss)  # (6, S*ss, S*ss, 3): sub-texels of texel (i, j)
    vals = latlong_lookup(img, dirs)
    c = vals.shape[-1]
    return vals.reshape(6, size, ss, size, ss, c).mean(axis=(2, 4)).astype(np.float32)


def cube_faces_to_latlong(faces: np.ndarray, h: int = 256, w: int = 512) -> np.ndarray:
    """Lat-long image (h, w, C) float32 from cube faces (6, S, S, C) (bilinear within a face,
    clamped at face edges)."""
    faces = np.asarray(faces)
    if faces.ndim != 4 or faces.shape[0] != 6 or faces.shape[1] != faces.shape[2]:
        raise ValueError(f"cube faces must have shape (6, S, S, C), got {faces.shape}")
    return sample_cube_faces(faces, latlong_directions(h, w)).astype(np.float32)


def downsample_latlong(img: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter a lat-long image by an integer factor (solid-angle weighted per row)."""
    img = np.asarray(img, dtype=np.float64)
    h, w = img.shape[:2]
    if h % factor or w % factor:
        raise ValueError(f"image {h}x{w} is not divisible by {factor}")
    omega = latlong_solid_angles(h, w)[..., None]
    num = (img * omega).reshape(h // factor, factor, w // factor, factor, -1).sum(axis=(1, 3))
    den = omega.reshape(h // factor, factor, w // factor, factor, -1).sum(axis=(1, 3))
    return (num / den).astype(np.float32)


# ------------------------------------------------------------------------------ SH helpers


def _basis(dirs: np.ndarray, degree: int, basis: str) -> np.ndarray:
    if basis == "3dgs":
        from usd_gs.sh3dgs import eval_basis

        return eval_basis(dirs, degree)
    if basis == "rh":
        from numba_kernels.sh_real import eval_basis_rh_numpy

        return eval_basis_rh_numpy(dirs, degree)
    raise ValueError(f"SH basis must be '3dgs' or 'rh', got {basis!r}")


def sh_to_latlong(coeffs: np.ndarray, h: int = 128, w: int = 256, basis: str = "3dgs") -> np.ndarray:
    """Evaluate radiance SH coefficients (K, C) on a lat-long grid: (h, w, C) float32.

    basis: '3dgs' (``usd_gs.sh3dgs``, degree <= 3) or 'rh' (``numba_kernels.sh_real``, <= 8).
    Probe coefficients are radiance: no 0.5 offset is added.
    """
    c = np.asarray(coeffs, dtype=np.float64)
    k = c.shape[0]
    degree = int(round(np.sqrt(k))) - 1
    if (degree + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients is not (d+1)^2")
    return (_basis(latlong_directions(h, w), degree, basis) @ c).astype(np.float32)


def project_latlong_to_sh(img: np.ndarray, degree: int, basis: str = "rh") -> np.ndarray:
    """SH projection of a lat-long radiance image by exact per-pixel solid angles: (K, C) float64.

    ``a_k = sum_ij Omega_ij L_ij Y_k(d_ij)``, the quadrature the probe fit is compared with.
    """
    img = np.asarray(img, dtype=np.float64)
    h, w = img.shape[:2]
    y = _basis(latlong_directions(h, w), degree, basis)
    omega = latlong_solid_angles(h, w)
    return np.einsum("hwk,hw,hwc->kc", y, omega, img.reshape(h, w, -1))


# ------------------------------------------------------------------------------- reading


def _decode_rgbe(rgbe: np.ndarray) -> np.ndarray:
    e = rgbe[..., 3].astype(np.int32)
    f = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0).astype(np.float32)
    return rgbe[..., :3].astype(np.float32) * f[..., None]


def read_hdr(path) -> np.ndarray:
    """Read a Radiance RGBE ``.hdr`` (flat or new-style RLE, ``-Y H +X W``): (H, W, 3) float32.

    Values are linear radiance (``m * 2^(e - 136)``, the ``stb_image`` / ``rgbe.c`` decoding).
    """
    path = Path(path)
    data = path.read_bytes()
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise InputFormatError(f"{path}: not a Radiance .hdr file (missing '#?RADIANCE' magic)")
    end = data.find(b"\n\n")
    if end < 0:
        raise InputFormatError(f"{path}: truncated .hdr header")
    header = data[:end].decode("latin-1")
    fmt = re.search(r"^FORMAT=(\S+)", header, re.M)
    if fmt and fmt.group(1) != "32-bit_rle_rgbe":
        raise InputFormatError(f"{path}: unsupported .hdr FORMAT '{fmt.group(1)}' (need 32-bit_rle_rgbe)")
    nl = data.find(b"\n", end + 2)
    res = data[end + 2:nl].decode("latin-1").split()
    if len(res) != 4 or res[0] != "-Y" or res[2] != "+X":
        raise InputFormatError(f"{path}: unsupported .hdr resolution line {' '.join(res)!r} (need '-Y H +X W')")
    h, w = int(res[1]), int(res[3])
    buf = np.frombuffer(data, dtype=np.uint8, offset=nl + 1)
    out = np.empty((h, w, 4), dtype=np.uint8)
    pos = 0
    for y in range(h):
        if pos + 4 > buf.size:
            raise InputFormatError(f"{path}: truncated pixel data at scanline {y}")
        rle_w = (int(buf[pos + 2]) << 8) | int(buf[pos + 3])
        if 8 <= w < 32768 and buf[pos] == 2 and buf[pos + 1] == 2 and rle_w == w:
            pos += 4
            for ch in range(4):
                x = 0
                row = out[y, :, ch]
                while x < w:
                    if pos >= buf.size:
                        raise InputFormatError(f"{path}: truncated RLE data at scanline {y}")
                    c = int(buf[pos])
                    if c > 128:
                        c -= 128
                        if x + c > w:
                            raise InputFormatError(f"{path}: bad RLE run at scanline {y}, pixel {x}")
                        row[x:x + c] = buf[pos + 1]
                        pos += 2
                    else:
                        if c == 0 or x + c > w:
                            raise InputFormatError(f"{path}: bad RLE count at scanline {y}, pixel {x}")
                        row[x:x + c] = buf[pos + 1:pos + 1 + c]
                        pos += 1 + c
                    x += c
        else:  # flat scanline
            if pos + 4 * w > buf.size:
                raise InputFormatError(f"{path}: truncated flat pixel data at scanline {y}")
            out[y] = buf[pos:pos + 4 * w].reshape(w, 4)
            pos += 4 * w
    return _decode_rgbe(out)


def read_exr(path) -> np.ndarray:
    """Read the first part (level 0) of an OpenEXR image as (H, W, 3) float32 linear RGB."""
    import OpenEXR

    path = Path(path)
    try:
        with OpenEXR.File(str(path)) as f:
            ch = f.channels()
            if "RGB" in ch:
                img = ch["RGB"].pixels
            elif "RGBA" in ch:
                img = ch["RGBA"].pixels[..., :3]
            elif all(k in ch for k in ("R", "G", "B")):
                img = np.stack([ch[k].pixels for k in ("R", "G", "B")], axis=-1)
            else:
                raise InputFormatError(f"{path}: OpenEXR file has no R, G, B channels (has {sorted(ch)})")
            return np.ascontiguousarray(img, dtype=np.float32)
    except InputFormatError:
        raise
    except Exception as exc:  # OpenEXR raises plain RuntimeError/Exception on bad files
        raise InputFormatError(f"{path}: cannot read OpenEXR image: {exc}") from None


def read_envmap(path) -> np.ndarray:
    """Read a lat-long environment (.hdr or .exr) as (H, W, 3) float32; checks finiteness."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".hdr":
        img = read_hdr(path)
    elif suffix == ".exr":
        img = read_exr(path)
    else:
        raise InputFormatError(f"{path}: unsupported environment image type '{suffix}' (need .hdr or .exr)")
    bad = ~np.isfinite(img)
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=-1).reshape(-1))[0])
        raise InputFormatError(f"{path}: pixel {i} (row {i // img.shape[1]}, column {i % img.shape[1]}) is not finite")
    return img


# ------------------------------------------------------------------------------- writing


def write_exr(path, img: np.ndarray, half: bool = False, latlong: bool = True) -> Path:
    """Write an (H, W, 3) linear RGB image as OpenEXR (ZIP, float32 or half), atomically.

    With ``latlong`` the header carries ``envmap = LATLONG``. Returns the path.
    """
    import OpenEXR

    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), got {img.shape}")
    arr = np.ascontiguousarray(img, dtype=np.float16 if half else np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if latlong:
        header["envmap"] = OpenEXR.ENVMAP_LATLONG
    from usd_gs.io.atomic import atomic_output

    path = Path(path)
    with atomic_output(path) as tmp, OpenEXR.File(header, {"RGB": arr}) as f:
        f.write(str(tmp))
    return path


def write_cube_faces_latlong(path, faces: np.ndarray, h: int = 256, w: int = 512) -> Path:
    """Lat-long OpenEXR of raw cube faces (6, S, S, 3)."""
    return write_exr(path, cube_faces_to_latlong(faces, h, w))
