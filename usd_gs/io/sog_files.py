"""SOG containers, manifests and WebP images, with the standard library only (no numpy, no pxr).

What :mod:`usd_gs.io.sog` needs before any numpy work: the files of a SOG unit in a folder or a
zip archive (:class:`SogSource`), ``meta.json`` and ``lod-meta.json`` parsing
(:func:`parse_meta`, :func:`lod_files`), libwebp through ctypes (:func:`webp_rgba`), and
:class:`SogPrefetch`, which reads and decodes a capture's images in a background thread from
the very start of ``usdgs import``, while the main thread imports numpy and pxr (ctypes and
file reads release the GIL). Every module and library the threads use is loaded before they
start: loading one in a thread while another imports pxr can deadlock. Layout and field
meanings: the :mod:`usd_gs.io.sog` docstring.
"""

from __future__ import annotations

import ctypes
import importlib.util
import json
import mmap
import os
import threading
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from usd_gs.errors import InputFormatError


# ------------------------------------------------------------------------------ containers
class SogSource:
    """Files of one SOG unit (``meta.json`` and its images) in a folder or a zip archive.
    ``prefetch``: a :class:`SogPrefetch` whose bytes and pixels are used where it has them."""

    def __init__(self, label: str, folder: Path | None = None, archive: zipfile.ZipFile | None = None,
                 prefix: str = "", prefetch: SogPrefetch | None = None):
        self.label = label
        self.folder = folder
        self.archive = archive
        self.prefix = prefix
        self.prefetch = prefetch
        self.archive_path = os.path.abspath(archive.filename) if archive is not None and archive.filename else None

    def _member(self, name: str) -> str:
        return str(PurePosixPath(self.prefix) / name) if self.prefix else name

    def key(self, name: str) -> tuple:
        """The :class:`SogPrefetch` key of file ``name`` of this unit."""
        if self.archive is not None:
            return (self.archive_path, self._member(name))
        return (os.path.abspath(self.folder / name), "")

    def prefetched(self, name: str):
        """``(bytes, pixels, width, height)`` of image ``name`` from the prefetch, or None."""
        return None if self.prefetch is None else self.prefetch.get(self.key(name))

    def read(self, name: str, image: bool = True) -> bytes:
        """The bytes of file ``name`` of this unit (an image from the prefetch when it has it;
        ``image`` False: read here, never waiting for the prefetch); ``InputFormatError`` naming
        the file or member when it is missing or unreadable."""
        hit = self.prefetched(name) if image else None
        if hit is not None:
            return hit[0]
        if self.archive is not None:
            member = self._member(name)
            try:
                return self.archive.read(member)
            except KeyError:
                raise InputFormatError(f"{self.label}: archive has no member '{member}'") from None
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError) as exc:
                raise InputFormatError(f"{self.label}: archive member '{member}' is corrupt ({exc})") from None
        p = self.folder / name
        try:
            return p.read_bytes()
        except FileNotFoundError:
            raise InputFormatError(f"{self.label}: missing file {p}") from None
        except OSError as exc:
            raise InputFormatError(f"{self.label}: cannot read {p} ({exc})") from None


def open_zip(label: str, path: Path) -> zipfile.ZipFile:
    """``path`` as a zip archive; ``InputFormatError`` naming ``label`` when it is not one."""
    try:
        return zipfile.ZipFile(path)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        raise InputFormatError(f"{label}: not a readable .sog zip archive ({exc})") from None


def archive_meta(label: str, zf: zipfile.ZipFile) -> str:
    """The folder prefix ('' for the top) of the shallowest ``meta.json`` in a bundled ``.sog``."""
    try:
        names = zf.namelist()
    except (zipfile.BadZipFile, ValueError) as exc:
        raise InputFormatError(f"{label}: corrupt zip directory ({exc})") from None
    metas = [nm for nm in names if PurePosixPath(nm).name == "meta.json"]
    if not metas:
        raise InputFormatError(f"{label}: archive has no meta.json")
    prefix = str(PurePosixPath(min(metas, key=len)).parent)
    return "" if prefix == "." else prefix


# ----------------------------------------------------------------------------------- meta
def parse_meta(label: str, data: bytes) -> dict:
    """A SOG ``meta.json`` (version 2) as a dict; ``InputFormatError`` naming ``label`` otherwise."""
    try:
        meta = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputFormatError(f"{label}: meta.json is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise InputFormatError(f"{label}: meta.json is not a JSON object")
    if "version" not in meta:
        raise InputFormatError(f"{label}: meta.json lacks field 'version' (SOG version 1 files are not supported; "
                               "convert them with splat-transform)")
    if meta["version"] != 2:
        raise InputFormatError(f"{label}: meta.json field 'version' is {meta['version']!r}; only 2 is supported")
    return meta


def lod_files(label: str, meta) -> tuple[int, dict[int, dict[int, int]], list[str]]:
    """(lodLevels, {level: {file index: Gaussian count}}, filenames) of a lod-meta.json."""
    if not isinstance(meta, dict):
        raise InputFormatError(f"{label}: lod-meta.json is not a JSON object")
    levels = meta.get("lodLevels")
    if not isinstance(levels, int) or isinstance(levels, bool) or levels <= 0:
        raise InputFormatError(f"{label}: lod-meta.json field 'lodLevels' is missing or not a positive integer")
    names = meta.get("filenames")
    if not isinstance(names, list) or not all(isinstance(x, str) and x for x in names):
        raise InputFormatError(f"{label}: lod-meta.json field 'filenames' is missing or not a list of names")
    if not isinstance(meta.get("tree"), dict):
        raise InputFormatError(f"{label}: lod-meta.json field 'tree' is missing or not an object")
    out: dict[int, dict[int, int]] = {}
    stack = [meta["tree"]]
    while stack:
        node = stack.pop()
        if not isinstance(node, dict):
            raise InputFormatError(f"{label}: lod-meta.json 'tree' has a node that is not an object")
        lods = node.get("lods", {})
        children = node.get("children", [])
        if not isinstance(lods, dict) or not isinstance(children, list):
            raise InputFormatError(f"{label}: lod-meta.json 'tree' node has bad 'lods' or 'children'")
        for key, ref in lods.items():
            ok = (isinstance(ref, dict) and key.isdigit() and int(key) < levels
                  and all(isinstance(ref.get(f), int) and not isinstance(ref.get(f), bool) and ref.get(f) >= 0
                          for f in ("file", "offset", "count")) and ref["file"] < len(names))
            if not ok:
                raise InputFormatError(f"{label}: lod-meta.json 'tree' has a bad LOD reference {key!r}: {ref!r}")
            files = out.setdefault(int(key), {})
            files[ref["file"]] = files.get(ref["file"], 0) + ref["count"]
        stack.extend(children)
    return levels, out, names


def missing_chunks(folder: Path, names: list[str], files: dict[int, int]) -> list[str]:
    """The chunk ``meta.json`` paths of one LOD level (``files``: :func:`lod_files`) that do not exist."""
    return [str(folder / names[f]) for f in sorted(files) if not (folder / names[f]).is_file()]


def pick_level(label: str, folder: Path, by_level: dict, names: list[str], lod: int | None) -> int:
    """The LOD level to read: ``lod``, or for None the finest level whose chunks are all present.
    ``InputFormatError`` for a level that is absent or incomplete (naming the missing files)."""
    present = sorted(by_level)
    if not present:
        raise InputFormatError(f"{label}: lod-meta.json 'tree' references no LOD level")
    if lod is None:
        complete = [lv for lv in present if not missing_chunks(folder, names, by_level[lv])]
        if not complete:
            raise InputFormatError(f"{label}: no LOD level is complete; level {present[0]} lacks "
                                   f"{', '.join(missing_chunks(folder, names, by_level[present[0]]))}")
        return complete[0]
    if lod not in by_level:
        raise InputFormatError(f"{label}: LOD level {lod} is not in the set (levels: {', '.join(map(str, present))})")
    gone = missing_chunks(folder, names, by_level[lod])
    if gone:
        raise InputFormatError(f"{label}: LOD level {lod} is incomplete: missing {', '.join(gone)}")
    return lod


def image_names(meta: dict) -> list[str]:
    """The image file names a parsed ``meta.json`` refers to, in decoding order (no checks: a
    malformed field gives fewer names; :mod:`usd_gs.io.sog` checks the manifest)."""
    out: list[str] = []
    for field, count in (("means", 2), ("quats", 1), ("scales", 1), ("sh0", 1), ("shN", 2)):
        files = meta.get(field, {}).get("files") if isinstance(meta.get(field), dict) else None
        if isinstance(files, list):
            out.extend(f for f in files[:count] if isinstance(f, str) and f)
    return out


# ---------------------------------------------------------------------------------- images
_LIBWEBP: list = []  # [the libwebp decode functions, or None], filled on first use


def libwebp():
    """``(WebPGetInfo, WebPDecodeRGBAInto)`` of libwebp through ctypes, or None.

    The library is the one Pillow ships beside itself (``pillow.libs``/``.dylibs``), else the
    system's. ctypes releases the GIL during the call, so images decode in parallel with other
    threads (Pillow's WebP decoder holds it), straight into the caller's buffer.
    """
    if _LIBWEBP:
        return _LIBWEBP[0]
    spec = importlib.util.find_spec("PIL")  # (its folder, without importing Pillow)
    here = Path(spec.origin).resolve().parent if spec is not None and spec.origin else None
    names = [] if here is None else sorted(
        str(f) for d in (here.parent / "pillow.libs", here / ".dylibs")
        if d.is_dir() for f in d.iterdir() if f.name.startswith(("libwebp-", "libwebp.")))
    found = None
    for name in [*names, "system"]:
        try:
            if name == "system":
                import ctypes.util as ctypes_util  # (runs ldconfig: only when Pillow ships no libwebp)

                name = ctypes_util.find_library("webp")
            lib = ctypes.CDLL(name)
            info, decode = lib.WebPGetInfo, lib.WebPDecodeRGBAInto
        except (OSError, AttributeError, TypeError):
            continue
        pint = ctypes.POINTER(ctypes.c_int)
        info.argtypes, info.restype = [ctypes.c_char_p, ctypes.c_size_t, pint, pint], ctypes.c_int
        decode.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
        decode.restype = ctypes.c_void_p
        found = (info, decode)
        break
    _LIBWEBP.append(found)
    return found


def webp_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a still WebP image as libwebp reads its header, or None (not a WebP
    libwebp takes as a still image, or no libwebp)."""
    lib = libwebp() if data[:4] == b"RIFF" and data[8:12] == b"WEBP" else None
    if lib is None:
        return None
    w, h = ctypes.c_int(0), ctypes.c_int(0)
    if lib[0](data, len(data), ctypes.byref(w), ctypes.byref(h)) and w.value > 0 and h.value > 0:
        return w.value, h.value
    return None


def webp_rgba(data: bytes, size: tuple[int, int]):
    """The RGBA pixels (row-major, 4 bytes each) of a still WebP image of ``size`` (:func:`webp_size`)
    decoded by libwebp into a writable buffer (an anonymous ``mmap``: its pages are first touched
    by the decoder, not zero-filled before), or None when libwebp does not decode it."""
    w, h = size
    px = mmap.mmap(-1, w * h * 4)
    buf = (ctypes.c_char * len(px)).from_buffer(px)
    ok = libwebp()[1](data, len(data), ctypes.addressof(buf), len(px), 4 * w)
    del buf  # (a live ctypes view would keep the mapping from closing)
    return px if ok else None


# -------------------------------------------------------------------------------- prefetch
def looks_like_sog(path: str) -> bool:
    """Whether ``path`` names a SOG input by its name (``.sog``, ``meta.json``, ``lod-meta.json``, or a
    folder holding one); nothing is read."""
    name = os.path.basename(os.path.normpath(path)).lower()
    if name.endswith(".sog") or name in ("meta.json", "lod-meta.json"):
        return os.path.isfile(path)
    return os.path.isdir(path) and any(os.path.isfile(os.path.join(path, m)) for m in ("lod-meta.json", "meta.json"))


def decoded_shapes(n: int, degree: int) -> list[tuple]:
    """Shapes of the float32 arrays a SOG of ``n`` Gaussians and SH ``degree`` decodes into, in the
    order ``usd_gs.io.sog`` allocates them: positions, log-scales, scales (N, 3), opacities (N,),
    SH (N, K, 3) (orientations apart)."""
    return [(n, 3), (n, 3), (n, 3), (n,), (n, (degree + 1) ** 2, 3)]


def _units(path: str, lod: int | None):
    """``(source, meta dict)`` of every SOG unit of ``path`` (a LOD set's level ``lod`` as
    :func:`pick_level` picks it, a ``meta.json`` or a bundled ``.sog``), read without checks (the
    reader checks). A bundled unit's source is only valid while the generator is not exhausted."""
    p = Path(path)
    if p.is_dir():
        p = p / "lod-meta.json" if (p / "lod-meta.json").is_file() else p / "meta.json"
    if p.name == "lod-meta.json":
        _, by_level, names = lod_files(str(p), json.loads(p.read_text(encoding="utf-8")))
        for f in sorted(by_level[pick_level(str(p), p.parent, by_level, names, lod)]):
            meta_path = p.parent / names[f]
            yield SogSource(str(meta_path), folder=meta_path.parent), json.loads(meta_path.read_bytes())
    elif p.suffix.lower() == ".json":
        yield SogSource(str(p), folder=p.parent), json.loads(p.read_bytes())
    else:
        with zipfile.ZipFile(p) as zf:
            src = SogSource(str(p), archive=zf, prefix=archive_meta(str(p), zf))
            yield src, json.loads(zf.read(src._member("meta.json")))


def manifest_size(path: str, lod: int | None = None) -> tuple[int, int] | None:
    """``(Gaussian count, SH degree)`` of a SOG input from its manifests alone (``lod``: as for
    :func:`pick_level`), or None when they do not parse; checks nothing else (the reader does)."""
    try:
        metas = [meta for _, meta in _units(path, lod)]
        count = sum(int(m["count"]) for m in metas)
        degree = max(int(m["shN"]["bands"]) if isinstance(m.get("shN"), dict) else 0 for m in metas)
        return (count, degree) if count >= 0 and 0 <= degree <= 3 else None
    except Exception:  # noqa: BLE001 - the reader reports what is wrong with the manifests
        return None


class SogPrefetch:
    """The image files of a SOG input read and decoded by libwebp in a daemon thread.

    Validates nothing and raises nothing: what it cannot find, read or decode it leaves out,
    and :mod:`usd_gs.io.sog` reads and decodes that itself, raising its usual messages (so the
    results and the errors are those without a prefetch). :meth:`get` waits until the image
    is done or the thread has finished. Keys: :meth:`SogSource.key`.
    """

    def __init__(self, path: str, lod: int | None = None):
        self._path, self._lod = path, lod
        self._images: dict[tuple, tuple] = {}
        self._cond = threading.Condition()
        self._finished = False
        libwebp()  # loaded here: a thread must not load libraries while another imports pxr
        self._thread = threading.Thread(target=self._run, name="usdgs-sog-prefetch", daemon=True)
        self._thread.start()

    def get(self, key: tuple):
        """``(bytes, pixels buffer or None, width, height)`` of the image ``key``, or None when the
        prefetch does not have it."""
        with self._cond:
            while key not in self._images and not self._finished:
                self._cond.wait()
            return self._images.get(key)

    def _put(self, key: tuple, data: bytes) -> None:
        size = webp_size(data)
        px = webp_rgba(data, size) if size is not None else None
        with self._cond:
            self._images[key] = (data, px, *(size or (0, 0)))
            self._cond.notify_all()

    def _run(self) -> None:
        try:
            self._read()
        except Exception:  # noqa: BLE001 - anything left out is read by the reader, with its messages
            pass
        finally:
            with self._cond:
                self._finished = True
                self._cond.notify_all()

    def _read(self) -> None:
        for src, meta in _units(self._path, self._lod):
            for name in image_names(meta):
                self._put(src.key(name), src.read(name, image=False))
