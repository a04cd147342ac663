"""Read PlayCanvas SOG files (version 2): bundled ``.sog``, ``meta.json`` folders, LOD sets.

Quantisation: positions 16 bits per axis of ``sign(x) ln(|x| + 1)`` between min and max;
log-scales and DC colour 8-bit indices into 256-entry codebooks; opacity 8 bits linear;
quaternions smallest-three 8 bits; SH bands 1..3 an (up to 64k)-entry palette of 8-bit
codebook indices.

Layout (all images lossless WebP, RGBA, one pixel per Gaussian in row-major order; only the
first ``count`` pixels are used):

- ``meta.json``: ``version`` 2, ``count``, ``means {mins, maxs, files: [lo, hi]}``,
  ``scales {codebook, files}``, ``quats {files}``, ``sh0 {codebook, files}`` and optionally
  ``shN {count, bands, codebook, files: [centroids, labels]}``.
- means: ``u = lo.rgb | hi.rgb << 8`` (16 bits), ``v = min + (max - min) * u / 65535`` (a zero
  range counts as 1), position ``sign(v) (exp|v| - 1)``.
- quats: r, g, b are the three smaller components ``(b/255*2 - 1) / sqrt(2)`` in (w, x, y, z)
  order with the largest left out; alpha ``252 + index`` of the largest, rebuilt positive.
- scales: r, g, b index ``scales.codebook`` (natural-log sigma).
- sh0: r, g, b index ``sh0.codebook`` (the raw ``f_dc``); alpha is the linear opacity * 255.
- shN: labels image ``label = r | g << 8``; centroids image is ``64 * (K-1)`` pixels wide,
  palette entry ``label`` at row ``label // 64``, columns ``(label % 64) * (K-1) + j`` hold
  coefficient ``j + 1`` as r, g, b indices into ``shN.codebook``.
- bundled ``.sog``: a zip holding ``meta.json`` and the images it names.
- LOD sets: ``lod-meta.json`` with ``lodLevels``, ``filenames`` (each a SOG ``meta.json``
  relative to it) and a ``tree`` whose nodes' ``lods`` map a level to ``{file, offset,
  count}``; level ``L`` is the concatenation, in file-index order, of the files it references.
  Level 0 is the finest.

Mapping to :class:`usd_gs.gaussians.GaussianSet`: ``log_scales`` are the codebook values
(``scales = exp``), ``opacities = alpha / 255``, quaternions normalised in float64, ``sh`` the
codebook values (DC raw, bands channel-major in the file, coefficient-major here); values
computed in float64 and rounded once to float32, as PlayCanvas splat-transform decodes them.
SOG stores PLY-convention coordinates (no axis change is applied).
"""

from __future__ import annotations

import io
import json
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from usd_gs.errors import InputFormatError, first_bad_index
from usd_gs.gaussians import GaussianSet, scales_from_log
from usd_gs.io.sog_files import (
    SogPrefetch,
    SogSource,
    archive_meta,
    decoded_shapes,
    libwebp,
    lod_files,
    open_zip,
    parse_meta,
    pick_level,
    webp_rgba,
    webp_size,
)

_SH_REST = {1: 3, 2: 8, 3: 15}
# |sign(x) ln(|x| + 1)| above this gives a position beyond the float32 range (and exp(log-scale) too)
_LOG_POS_MAX = _LOG_SCALE_MAX = float(np.log(np.finfo(np.float32).max))
# a quaternion byte b -> (b/255*2 - 1) / sqrt(2)
_QUAT_LUT = (np.arange(256, dtype=np.float64) / 255.0 * 2.0 - 1.0) / np.sqrt(2.0)


# ----------------------------------------------------------------------------------- meta
def _finite_numbers(v: list) -> bool:
    """A flat list of finite JSON numbers (no booleans, strings or nested lists)."""
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return a.ndim == 1 and bool(np.isfinite(a).all()) and not any(isinstance(x, bool) for x in v)


def _field(label: str, meta, dotted: str, kind):
    cur = meta
    for part in dotted.split("."):
        if not isinstance(cur, dict) or part not in cur:
            raise InputFormatError(f"{label}: meta.json lacks field '{dotted}'")
        cur = cur[part]
    ok = {
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
        "vec3": lambda v: (isinstance(v, list) and len(v) == 3
                           and all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)
                                   for x in v)),
        "codebook": lambda v: isinstance(v, list) and 0 < len(v) <= 256 and _finite_numbers(v),
        "files": lambda v: isinstance(v, list) and len(v) >= 1 and all(isinstance(x, str) and x for x in v),
    }[kind]
    if not ok(cur):
        what = {"int": "a non-negative integer", "vec3": "a list of 3 finite numbers",
                "codebook": "a list of 1..256 finite numbers", "files": "a list of file names"}[kind]
        raise InputFormatError(f"{label}: meta.json field '{dotted}' is not {what}")
    return cur


# ---------------------------------------------------------------------------------- images
def _decode_webp(label: str, name: str, data: bytes, need: int, decoded=None) -> tuple[np.ndarray, int, int]:
    """((H*W, 4) uint8 RGBA pixels, W, H) of a WebP image holding at least ``need`` pixels.

    A still WebP goes to libwebp (:func:`usd_gs.io.sog_files.webp_rgba`; ``decoded``: its
    ``(pixels, W, H)`` from a :class:`~usd_gs.io.sog_files.SogPrefetch`, pixels None when it did
    not decode); anything libwebp does not decode that way (an animation, corrupt data, another
    format), and every image when libwebp is not found, through Pillow's ``Image.open``, whose
    messages name what it found.
    """
    px, size = (decoded[0], decoded[1:]) if decoded is not None and decoded[0] is not None else (None, webp_size(data))
    if size is not None:
        w, h = size
        if w * h < need:
            raise InputFormatError(f"{label}: image '{name}' is {w}x{h} = {w * h} pixels, fewer than "
                                   f"meta.json 'count' {need}")
        px = webp_rgba(data, size) if px is None else px
        if px is not None:
            return np.frombuffer(px, np.uint8).reshape(w * h, 4), w, h
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.format != "WEBP":
                raise InputFormatError(f"{label}: image '{name}' is {im.format or 'not an image'}, not WebP")
            w, h = im.size
            if w * h < need:
                raise InputFormatError(f"{label}: image '{name}' is {w}x{h} = {w * h} pixels, fewer than "
                                       f"meta.json 'count' {need}")
            im.load()
            px = np.asarray(im if im.mode == "RGBA" else im.convert("RGBA"))
    except InputFormatError:
        raise
    except Exception as exc:  # Pillow raises many types (OSError, SyntaxError, ValueError...) on corrupt data
        raise InputFormatError(f"{label}: image '{name}' does not decode as WebP ({type(exc).__name__}: "
                               f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})") from None
    return px.reshape(-1, 4), w, h


def _lookup(label: str, field: str, codebook: np.ndarray, px: np.ndarray) -> np.ndarray:
    """``codebook[px[..., :3]]``: the R, G, B bytes of the RGBA pixels ``px`` (..., 4) as indices
    into ``codebook`` (at most 256 entries); ``InputFormatError`` for an index past its end.
    Returns a (..., 3) float32 view (the gather runs over whole pixels, alpha included, through a
    256-entry table: contiguous, which is faster than gathering three strided bytes)."""
    _check_indices(label, field, codebook, px)
    return _take_rgb(_table256(codebook), px)


def _table256(values: np.ndarray) -> np.ndarray:
    """``values`` (float32, at most 256) padded with zeros to 256 entries."""
    table = np.zeros(256, np.float32)
    table[: len(values)] = values
    return table


def _take_rgb(table: np.ndarray, px: np.ndarray) -> np.ndarray:
    """``table[px[..., :3]]`` for a 256-entry ``table`` and uint8 RGBA ``px`` (..., 4)."""
    if px.flags.c_contiguous:
        return np.take(table, px)[..., :3]
    return np.take(table, px[..., :3])


# ---------------------------------------------------------------------------------- decode
class _Plan:
    """A parsed meta.json: what to decode (images, codebooks) for one SOG unit."""

    def __init__(self, src: SogSource):
        label = self.label = src.label
        self.src = src
        meta = parse_meta(label, src.read("meta.json", image=False))
        self.count = n = _field(label, meta, "count", "int")
        self.mins = np.asarray(_field(label, meta, "means.mins", "vec3"), np.float64)
        self.maxs = np.asarray(_field(label, meta, "means.maxs", "vec3"), np.float64)
        mfiles = _field(label, meta, "means.files", "files")
        if len(mfiles) < 2:
            raise InputFormatError(f"{label}: meta.json field 'means.files' needs 2 files (low and high bytes)")
        self.scb = np.asarray(_field(label, meta, "scales.codebook", "codebook"), np.float32)
        if self.scb.max() > _LOG_SCALE_MAX:
            raise InputFormatError(f"{label}: meta.json 'scales.codebook' value {float(self.scb.max())!r} "
                                   "overflows float32 after exp()")
        self.qfile = _field(label, meta, "quats.files", "files")[0]
        self.ccb = np.asarray(_field(label, meta, "sh0.codebook", "codebook"), np.float32)
        self.jobs = {"means_l": (mfiles[0], n), "means_u": (mfiles[1], n), "quats": (self.qfile, n),
                     "scales": (_field(label, meta, "scales.files", "files")[0], n),
                     "sh0": (_field(label, meta, "sh0.files", "files")[0], n)}
        shn = meta.get("shN")
        self.bands = 0
        if shn is not None:
            self.bands = _field(label, meta, "shN.bands", "int")
            if self.bands not in (0, 1, 2, 3):
                raise InputFormatError(f"{label}: meta.json field 'shN.bands' is {self.bands}; expected 1, 2 or 3")
        if self.bands:
            self.palette = _field(label, meta, "shN.count", "int")
            self.hcb = np.asarray(_field(label, meta, "shN.codebook", "codebook"), np.float32)
            self.hfiles = _field(label, meta, "shN.files", "files")
            if len(self.hfiles) < 2:
                raise InputFormatError(f"{label}: meta.json field 'shN.files' needs 2 files (centroids and labels)")
            self.jobs["centroids"] = (self.hfiles[0], 0)
            self.jobs["labels"] = (self.hfiles[1], n)

    def load(self) -> dict:
        """The raw bytes of every image (read in the calling thread: zip files are not thread-safe)."""
        return {key: self.src.read(name) for key, (name, _) in self.jobs.items()}


def _alloc(n: int, degree: int, empty=None) -> dict:
    """The decoded fields' float32 arrays: ``empty(shape)`` (values 0) for positions, scales,
    log-scales, opacities and SH when given (see :func:`read_sog`), else numpy's."""
    new = empty or (lambda shape: np.zeros(shape, np.float32))
    positions, log_scales, scales, opacities, sh = (new(shape) for shape in decoded_shapes(n, degree))
    return {"positions": positions, "orientations": np.empty((n, 4), np.float32), "log_scales": log_scales,
            "scales": scales, "opacities": opacities, "sh": sh}


def _to_set(out: dict, label: str) -> GaussianSet:
    return GaussianSet(out["positions"], out["orientations"], out["scales"], out["opacities"],
                       out["sh"], log_scales=out["log_scales"], label=label)


def _images(plan: _Plan, raw: dict) -> dict:
    """The decoded WebP images of one SOG unit: key -> (pixels, width, height) (those its
    source's prefetch decoded are taken from there)."""
    jobs, src = plan.jobs, plan.src
    out = {}
    for key, (name, need) in jobs.items():
        hit = src.prefetched(name)
        out[key] = _decode_webp(plan.label, name, raw[key], need, None if hit is None else hit[1:])
    return out


#: rows decoded per pass: the temporaries stay a few hundred KB (reused and in cache) instead of
#: fresh (N,)-sized arrays, whose first-touch page faults cost more than the arithmetic
_BLOCK = 16384


def _decode(plan: _Plan, imgs: dict, out: dict, start: int = 0) -> None:
    """Decode one SOG unit's images (:func:`_images`) into rows ``start:start+count`` of ``out``
    (the checks first, naming the field and element; then :data:`_BLOCK` rows at a time)."""
    label = plan.label
    n = plan.count
    mins, maxs, qfile, bands = plan.mins, plan.maxs, plan.qfile, plan.bands
    rng = maxs - mins
    rng[rng == 0] = 1.0
    if max(np.abs(mins).max(), np.abs(mins + rng).max()) > _LOG_POS_MAX:
        raise InputFormatError(f"{label}: meta.json 'means.mins'/'means.maxs' {mins.tolist()}/{maxs.tolist()} "
                               "decode to positions outside the float32 range")
    lut = None
    if n > 30000:  # a 65536-entry table per axis (same float64 values), then one gather per axis
        v = (np.arange(65536) / 65535.0)[:, None] * rng + mins
        lut = np.copysign(np.expm1(np.abs(v)), v).astype(np.float32)
    qpx = imgs["quats"][0][:n]
    if n and qpx[:, 3].min() < 252:
        i = int(np.flatnonzero(qpx[:, 3] < 252)[0])
        raise InputFormatError(f"{label}: image '{qfile}' pixel {i} has alpha {int(qpx[i, 3])}; "
                               "a quaternion tag must be 252..255")
    spx, c0 = imgs["scales"][0][:n], imgs["sh0"][0][:n]
    _check_indices(label, "scales", plan.scb, spx)
    _check_indices(label, "sh0", plan.ccb, c0)
    log_table, dc_table = _table256(plan.scb), _table256(plan.ccb)
    scale_table = scales_from_log(log_table)
    rows = lab = None
    if bands:
        hfiles, palette, hcb = plan.hfiles, plan.palette, plan.hcb
        rest = _SH_REST[bands]
        cen, cw, ch = imgs["centroids"]
        if cw != 64 * rest:
            raise InputFormatError(f"{label}: image '{hfiles[0]}' is {cw} pixels wide; {bands} SH bands need "
                                   f"{64 * rest}")
        if palette > ch * 64:
            raise InputFormatError(f"{label}: meta.json 'shN.count' {palette} is more than the {ch * 64} palette "
                                   f"entries image '{hfiles[0]}' ({cw}x{ch}) holds")
        pal = _lookup(label, "shN", hcb, cen.reshape(ch * 64, rest, 4)[:palette])  # (P, K-1, 3)
        # whole rows (coefficient 0 and any band past this unit's left 0), gathered into the output
        k = out["sh"].shape[1]
        rows = np.zeros((palette, k * 3), np.float32)
        rows.reshape(palette, k, 3)[:, 1:rest + 1] = pal
        lab = imgs["labels"][0][:n]
    for r0 in range(0, n, _BLOCK):
        r1 = min(n, r0 + _BLOCK)
        sl = slice(start + r0, start + r1)
        u = imgs["means_l"][0][r0:r1, :3].astype(np.uint16)
        u |= imgs["means_u"][0][r0:r1, :3].astype(np.uint16) << 8
        positions = out["positions"][sl]
        if lut is not None:
            for j in range(3):
                np.take(lut[:, j], u[:, j], out=positions[:, j])
        else:
            v = u / 65535.0  # the reference's order of operations: min + range * (u / 65535)
            v *= rng
            v += mins
            positions[...] = np.copysign(np.expm1(np.abs(v)), v)
        _quaternions(qpx[r0:r1], out["orientations"][sl])
        out["log_scales"][sl] = _take_rgb(log_table, spx[r0:r1])
        out["scales"][sl] = _take_rgb(scale_table, spx[r0:r1])  # elementwise: as of log_scales
        out["opacities"][sl] = c0[r0:r1, 3].astype(np.float32) / np.float32(255.0)
        sh = out["sh"][sl]
        if rows is not None:
            labels = lab[r0:r1, 0].astype(np.intp) | (lab[r0:r1, 1].astype(np.intp) << 8)
            if len(labels) and labels.max() >= len(rows):
                i = int(np.flatnonzero(labels >= len(rows))[0])
                raise InputFormatError(f"{label}: image '{plan.hfiles[1]}' pixel {r0 + i} has label "
                                       f"{int(labels[i])}, past meta.json 'shN.count' {len(rows)}")
            np.take(rows, labels, axis=0, out=sh.reshape(r1 - r0, -1), mode="clip")
        sh[:, 0, :] = _take_rgb(dc_table, c0[r0:r1])


def _check_indices(label: str, field: str, codebook: np.ndarray, px: np.ndarray) -> None:
    """``InputFormatError`` naming the Gaussian when an R, G or B byte of ``px`` (N, 4) is past
    the end of ``codebook`` (at most 256 entries)."""
    idx = px[..., :3]
    if len(codebook) < 256 and idx.size and int(idx.max()) >= len(codebook):
        i = first_bad_index(idx >= len(codebook))
        raise InputFormatError(f"{label}: '{field}' index {int(idx.reshape(len(idx), -1)[i].max())} at Gaussian {i} "
                               f"is past the {len(codebook)}-entry codebook")


def _quaternions(qpx: np.ndarray, quats: np.ndarray) -> None:
    """Unit (w, x, y, z) quaternions into ``quats`` (M, 4) float32 from smallest-three pixels
    ``qpx`` (M, 4) uint8 whose alpha tags are checked (252..255); normalised in float64."""
    n = len(qpx)
    tag = qpx[:, 3] - np.uint8(252)  # index (w, x, y, z) of the largest component
    abc = np.take(_QUAT_LUT, qpx[:, :3])  # the other three, in (w, x, y, z) order
    abc2 = np.einsum("ij,ij->i", abc, abc)
    big = np.sqrt(np.maximum(0.0, 1.0 - abc2))
    inv_norm = 1.0 / np.sqrt(abc2 + big * big)  # never zero: the largest is 1 when a = b = c = 0
    col = np.empty(n, np.float64)
    for j in range(4):  # component j: the largest where tag == j, else a, b or c (j or j-1 by tag > j)
        below, above = abc[:, max(j - 1, 0)], abc[:, min(j, 2)]
        np.copyto(col, above if j == 0 else below)
        if 0 < j < 3:
            np.copyto(col, above, where=tag > j)
        np.copyto(col, big, where=tag == j)
        col *= inv_norm
        quats[:, j] = col


# ------------------------------------------------------------------------------------ LOD
class OpenedSog:
    """A SOG capture whose ``meta.json`` files are read and checked (:func:`open_sog`);
    :meth:`decode` reads and decodes the images. ``count`` Gaussians of SH degree ``sh_degree``."""

    def __init__(self, label: str, plans: list, raws: list | None = None):
        self.label = label
        self._plans = plans
        self._raws = raws  # the images' bytes, already read (a zip archive is closed by now)
        self.count = int(sum(pl.count for pl in plans))
        self.sh_degree = max(pl.bands for pl in plans)

    def decode(self, threads: int | None = None, empty=None, on_rows=None) -> GaussianSet:
        """The :class:`GaussianSet` (``threads``, ``empty``: see :func:`read_sog`). Uses numpy,
        ctypes and, for images libwebp does not take, Pillow; nothing else is imported here.
        ``on_rows(rows)``: called in the decoding thread with each unit's rows (a
        :class:`GaussianSet` of views into the result) as soon as they are decoded; what it
        raises is raised here."""
        import threading

        plans, raws = self._plans, self._raws
        starts = np.concatenate([[0], np.cumsum([pl.count for pl in plans])]).astype(int)
        workers = threads or min(len(plans), os.cpu_count() or 1)
        out: list[dict] = []  # allocated once, when the first unit's images are decoded
        lock = threading.Lock()

        def run(i):
            imgs = _images(plans[i], raws[i] if raws is not None else plans[i].load())
            with lock:
                if not out:
                    out.append(_alloc(self.count, self.sh_degree, empty))
            _decode(plans[i], imgs, out[0], int(starts[i]))
            if on_rows is not None:
                rows = slice(int(starts[i]), int(starts[i + 1]))
                on_rows(_to_set({key: arr[rows] for key, arr in out[0].items()}, plans[i].label))

        if workers > 1 and len(plans) > 1:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                list(pool.map(run, range(len(plans))))
        else:
            for i in range(len(plans)):
                run(i)
        if not out:  # no unit
            out.append(_alloc(self.count, self.sh_degree, empty))
        return _to_set(out[0], self.label)


def read_lod_set(path, lod: int | None = None, threads: int | None = None, empty=None) -> GaussianSet:
    """Read one level of a SOG LOD set (``lod-meta.json``; module docstring; :func:`open_lod_set`)."""
    return open_lod_set(path, lod).decode(threads, empty)


def open_lod_set(path, lod: int | None = None, prefetch: SogPrefetch | None = None) -> OpenedSog:
    """One level of a SOG LOD set (``lod-meta.json``), its manifests read, ready to decode.

    ``lod`` None picks the finest level (lowest number) whose chunk files are all present.
    Raises :class:`InputFormatError` for a bad manifest, a level that does not exist, a level
    whose chunk files are missing (the message lists them) and a chunk whose ``count``
    differs from the counts the tree references. ``prefetch``: see :func:`open_sog`.
    """
    p = Path(path)
    label = str(path)
    try:
        meta = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFormatError(f"{label}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputFormatError(f"{label}: lod-meta.json is not valid JSON ({exc})") from None
    _, by_level, names = lod_files(label, meta)
    lod = pick_level(label, p.parent, by_level, names, lod)
    plans = []
    for f, count in sorted(by_level[lod].items()):
        meta_path = p.parent / names[f]
        plan = _Plan(SogSource(str(meta_path), folder=meta_path.parent, prefetch=prefetch))
        if plan.count != count:
            raise InputFormatError(f"{meta_path}: meta.json 'count' is {plan.count} but {label} references "
                                   f"{count} Gaussians in it for LOD {lod}")
        plans.append(plan)
    return OpenedSog(label, plans)


# ---------------------------------------------------------------------------------- public
def read_sog(path, lod: int | None = None, threads: int | None = None, empty=None) -> GaussianSet:
    """Read a SOG v2 capture into a :class:`GaussianSet` (module docstring).

    ``path`` is a bundled ``.sog`` zip, a ``meta.json``, a ``lod-meta.json`` or a folder
    holding one of them. ``lod`` selects the level of a LOD set (None: the finest complete
    level); it is an error for a single SOG unless 0 or None. Raises
    :class:`InputFormatError` naming the file and the field on bad input (corrupt zip,
    missing member, WebP that does not decode or is smaller than ``count``, missing or
    malformed meta.json fields, codebook indices out of range, bad quaternion tags).

    ``threads``: decoding threads for the chunks of a LOD set (default: one per core, at most
    one per chunk). ``empty``: a function ``shape -> zero-filled C-order float32 array`` that
    allocates the decoded positions, scales, log-scales, opacities and SH (``usdgs import``
    passes one whose arrays are USD's own storage; default numpy's).
    """
    return open_sog(path, lod).decode(threads, empty)


def open_sog(path, lod: int | None = None, prefetch: SogPrefetch | None = None) -> OpenedSog:
    """The first half of :func:`read_sog`: the manifests read and checked (and a bundled
    ``.sog``'s members read), so ``count`` and ``sh_degree`` are known before the images are
    decoded by :meth:`OpenedSog.decode`. Raises what :func:`read_sog` raises for the manifests.
    ``prefetch``: a :class:`~usd_gs.io.sog_files.SogPrefetch` of ``path`` started earlier, whose
    image bytes and pixels are used (the same values; it only saves time)."""
    p = Path(path)
    label = str(path)
    if p.is_dir():
        if (p / "lod-meta.json").is_file():
            p = p / "lod-meta.json"
        elif (p / "meta.json").is_file():
            p = p / "meta.json"
        else:
            raise InputFormatError(f"{label}: folder holds neither lod-meta.json nor meta.json")
    if not p.exists():
        raise InputFormatError(f"{label}: no such file")
    if p.name == "lod-meta.json":
        return open_lod_set(p, lod, prefetch)
    if lod not in (None, 0):
        raise InputFormatError(f"{label}: --lod {lod} given but this SOG has a single level (no lod-meta.json)")
    if p.suffix.lower() == ".json":
        return OpenedSog(label, [_Plan(SogSource(str(p), folder=p.parent, prefetch=prefetch))])
    with open_zip(label, p) as zf:
        plan = _Plan(SogSource(label, archive=zf, prefix=archive_meta(label, zf), prefetch=prefetch))
        raw = plan.load()
    return OpenedSog(label, [plan], [raw])


def load_webp_codec() -> bool:
    """Find and load libwebp now (:func:`usd_gs.io.sog_files.libwebp`; otherwise done on the first
    image); True when found. ``usdgs import`` calls it before it decodes in a thread, so that
    thread loads nothing."""
    return libwebp() is not None


# ---------------------------------------------------------------------------------- writing
def _codebook(values: np.ndarray, k: int = 256, iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """1-D k-means of ``values`` (any shape) into at most ``k`` sorted float32 centroids.

    Returns (codebook, uint8 labels shaped like ``values``). Exact (the distinct values) when
    there are at most ``k`` of them; else quantile start and Lloyd iterations in float64.
    """
    v = np.asarray(values, np.float64).ravel()
    uniq = np.unique(v)
    if len(uniq) <= k:
        cb = uniq.astype(np.float32)
        return cb, np.searchsorted(cb, v.astype(np.float32)).astype(np.uint8).reshape(np.shape(values))
    sample = v if v.size <= 2_000_000 else v[:: v.size // 2_000_000 + 1]
    c = np.quantile(sample, (np.arange(k) + 0.5) / k)
    for _ in range(iterations):
        lab = np.searchsorted((c[1:] + c[:-1]) / 2.0, sample)
        cnt = np.bincount(lab, minlength=k)
        tot = np.bincount(lab, weights=sample, minlength=k)
        c = np.sort(np.where(cnt > 0, tot / np.maximum(cnt, 1), c))
    cb = c.astype(np.float32)
    mid = (cb[1:].astype(np.float64) + cb[:-1]) / 2.0
    return cb, np.searchsorted(mid, v).astype(np.uint8).reshape(np.shape(values))


def _encode_webp(rgba: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, "WEBP", lossless=True, exact=True, quality=50, method=0)
    return buf.getvalue()


def encode_sog(gaussians: GaussianSet) -> dict[str, bytes]:
    """The files of a SOG v2 (``meta.json`` and its WebP images) for ``gaussians``, in the
    layout :func:`read_sog` reads, by name. SH degree 0 only (higher bands need a palette
    k-means that is not cheap on a CPU: :class:`UserError`); Gaussians keep their order.

    Quantisation: 16-bit ``sign(x) ln(|x| + 1)`` positions between the per-axis min and max,
    256-entry 1-D k-means codebooks for log-scales and for the DC term (each shared by the
    three channels), opacity ``round(255 a)``, smallest-three quaternions rounded to 8 bits.
    """
    from usd_gs.errors import UserError

    g = gaussians
    if g.sh_degree > 0:
        raise UserError(f"{g.label}: SOG writing supports SH degree 0 only (this set has degree {g.sh_degree}); "
                        "write .ply or .spz, or convert with PlayCanvas splat-transform")
    n = g.count
    if n == 0:
        raise UserError(f"{g.label}: cannot write an empty SOG")
    width = int(np.ceil(np.sqrt(n) / 4.0) * 4)
    height = int(np.ceil(n / width / 4.0) * 4)
    if width > 16383 or height > 16383:
        raise UserError(f"{g.label}: {n} Gaussians exceed the 16383x16383 SOG image limit")

    def image(channels: list[np.ndarray], alpha=None) -> bytes:
        img = np.zeros((height * width, 4), np.uint8)
        for j, c in enumerate(channels):
            img[:n, j] = c
        img[:, 3] = 255
        if alpha is not None:
            img[:n, 3] = alpha
        return _encode_webp(img.reshape(height, width, 4))

    lt = np.sign(g.positions.astype(np.float64)) * np.log1p(np.abs(g.positions.astype(np.float64)))
    mins, maxs = lt.min(axis=0), lt.max(axis=0)
    span = np.where(maxs > mins, maxs - mins, 1.0)
    u = np.clip(np.rint((lt - mins) / span * 65535.0), 0, 65535).astype(np.uint16)
    files = {"means_l.webp": image([u[:, j] & 0xFF for j in range(3)]),
             "means_u.webp": image([u[:, j] >> 8 for j in range(3)])}

    q = g.unit_quaternions()
    big = np.argmax(np.abs(q), axis=1)
    q *= np.where(q[np.arange(n), big] < 0, -1.0, 1.0)[:, None]
    others = np.asarray(((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)))[big]
    abc = np.take_along_axis(q, others, axis=1) * np.sqrt(2.0)
    qb = np.clip(np.rint((abc * 0.5 + 0.5) * 255.0), 0, 255).astype(np.uint8)
    files["quats.webp"] = image([qb[:, j] for j in range(3)], alpha=(252 + big).astype(np.uint8))

    log_s = g.log_scales if g.log_scales is not None else np.log(g.scales.astype(np.float64))
    scb, slab = _codebook(log_s)
    files["scales.webp"] = image([slab[:, j] for j in range(3)])
    ccb, clab = _codebook(g.sh[:, 0, :])
    alpha = np.clip(np.rint(g.opacities.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    files["sh0.webp"] = image([clab[:, j] for j in range(3)], alpha=alpha)
    meta = {"version": 2, "asset": {"generator": "usd-gs"}, "count": int(n),
            "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"codebook": scb.tolist(), "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"codebook": ccb.tolist(), "files": ["sh0.webp"]}}
    files["meta.json"] = json.dumps(meta).encode()
    return files


def write_sog(path, gaussians: GaussianSet) -> None:
    """Write ``gaussians`` (see :func:`encode_sog`) as a bundled ``.sog`` zip, or, for a path
    named ``meta.json``, as a SOG folder (the images beside it). Written atomically."""
    from usd_gs.io.atomic import atomic_output

    files = encode_sog(gaussians)
    p = Path(path)
    if p.name.lower() == "meta.json":
        for name, data in files.items():
            with atomic_output(p.parent / name) as tmp:
                tmp.write_bytes(data)
        return
    import zipfile

    with atomic_output(p) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
        for name in ("meta.json", *sorted(k for k in files if k != "meta.json")):
            zf.writestr(name, files[name])
