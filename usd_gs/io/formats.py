"""One entry point for every capture format: :func:`read_capture` and :func:`write_capture`.

Readable: INRIA ``.ply``, PlayCanvas ``.compressed.ply`` (recognised by its header, whatever
the name), antimatter15 ``.splat``, Niantic ``.spz``, SOG (bundled ``.sog``, ``meta.json``,
LOD sets ``lod-meta.json``, or a folder holding one of those). Writable: ``.ply``, ``.splat``,
``.spz`` and bundled ``.sog`` (SH degree 0 only). No axis conversion is applied by any of them
(SPZ is read and written in its native frame, as PlayCanvas splat-transform does).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from usd_gs.errors import InputFormatError, UserError
from usd_gs.gaussians import GaussianSet

READ_KINDS = ("ply", "compressed-ply", "splat", "spz", "sog")
WRITE_EXTS = (".ply", ".splat", ".spz", ".sog")
READ_HELP = ".ply, .compressed.ply, .splat, .spz, .sog, meta.json, lod-meta.json or a SOG folder"


#: name endings of the capture files a frame sequence may be made of (:func:`folder_pattern`)
CAPTURE_ENDINGS = (".compressed.ply", ".ply", ".splat", ".spz", ".sog")
_NUMBERED = re.compile(r"(.*?)(\d+)(" + "|".join(re.escape(e) for e in CAPTURE_ENDINGS) + r")\Z", re.IGNORECASE)


def folder_pattern(folder) -> tuple[str, int] | None:
    """``(pattern, file count)`` of the frame sequence a folder holds: its capture files named
    ``<prefix><frame number><ending>`` with one prefix, ending and digit count (the most common
    when several), as a ``####`` pattern inside ``folder`` (``usd_gs.io.sequence``); None when
    fewer than two such files."""
    try:
        names = os.listdir(folder)
    except OSError:
        return None
    groups: dict[tuple[str, int, str], int] = {}
    for name in names:
        m = _NUMBERED.match(name)
        if m:
            key = (m.group(1), len(m.group(2)), m.group(3))
            groups[key] = groups.get(key, 0) + 1
    if not groups:
        return None
    (prefix, width, ending), count = max(groups.items(), key=lambda kv: (kv[1], kv[0]))
    if count < 2:
        return None
    return os.path.join(str(folder), prefix + "#" * width + ending), count


def capture_kind(path) -> str:
    """The reader for ``path``: one of :data:`READ_KINDS`; ``UserError`` for anything else."""
    p = Path(path)
    name = p.name.lower()
    if p.is_dir():
        if (p / "lod-meta.json").is_file() or (p / "meta.json").is_file():
            return "sog"
        seq = folder_pattern(p)
        hint = (f"; it holds a frame sequence of {seq[1]} files: import it with its frame pattern, "
                f"'{seq[0]}'" if seq else "")
        raise UserError(f"{path}: folder holds neither lod-meta.json nor meta.json (not a SOG folder){hint}")
    if name.endswith(".compressed.ply"):
        return "compressed-ply"
    if name.endswith(".ply"):
        from usd_gs.io.compressed_ply import is_compressed_ply

        return "compressed-ply" if p.is_file() and is_compressed_ply(p) else "ply"
    if name.endswith(".splat"):
        return "splat"
    if name.endswith(".spz"):
        return "spz"
    if name.endswith(".sog") or name.endswith(".json"):
        return "sog"
    raise UserError(f"{path}: unsupported input type '{p.suffix or 'no extension'}' (expected {READ_HELP})")


def read_capture(path, lod: int | None = None, empty=None) -> GaussianSet:
    """Read any supported capture (module docstring) into a :class:`GaussianSet`.

    ``lod`` selects a level of a SOG LOD set (None: the finest complete level); given for
    another format other than 0 it is an error. ``empty`` allocates the decoded float32
    arrays of a SOG (``usd_gs.io.sog.read_sog``; the other readers do not use it). Bad input
    raises :class:`UserError` (:class:`InputFormatError`) naming the file and the field.
    """
    kind = capture_kind(path)
    if lod not in (None, 0) and kind != "sog":
        raise UserError(f"{path}: --lod {lod} only applies to SOG LOD sets (lod-meta.json)")
    if not Path(path).exists():
        raise InputFormatError(f"{path}: no such file")
    if kind == "ply":
        from usd_gs.io.ply import read_ply

        return read_ply(path)
    if kind == "compressed-ply":
        from usd_gs.io.compressed_ply import read_compressed_ply

        return read_compressed_ply(path)
    if kind == "splat":
        from usd_gs.io.splat import read_splat

        return read_splat(path)
    if kind == "spz":
        from usd_gs.io.spz import read_spz

        return read_spz(path)
    from usd_gs.io.sog import read_sog

    return read_sog(path, lod=lod, empty=empty)


def write_capture(path, gaussians: GaussianSet) -> None:
    """Write ``gaussians`` as ``.ply`` (INRIA), ``.splat``, ``.spz`` (v3) or ``.sog`` (bundled SOG v2,
    SH degree 0) by extension, atomically."""
    ext = Path(path).suffix.lower()
    if ext == ".ply":
        from usd_gs.io.ply import write_ply

        write_ply(path, gaussians)
    elif ext == ".splat":
        from usd_gs.io.splat import write_splat

        write_splat(path, gaussians)
    elif ext == ".spz":
        from usd_gs.io.spz import write_spz

        write_spz(path, gaussians)
    elif ext == ".sog":
        from usd_gs.io.sog import write_sog

        write_sog(path, gaussians)
    else:
        raise UserError(f"{path}: output must end in {', '.join(WRITE_EXTS)}")
