"""Frame chunks of a farm run and their manifest entries (what makes a run resumable).

A chunk is a run of consecutive processed frames. Its results are one USD layer
``<dir>/chunk_<first>_<last>.usdc`` (plus ``chunk_<first>_<last>_probes/``) and a JSON
sidecar ``<dir>/chunk_<first>_<last>.json``, the chunk's manifest entry::

    {"format": "usdgs-chunk/1", "layer": "chunk_0001_0002.usdc", "frames": [1.0, 2.0],
     "options_hash": "...", "input_hash": "...", "layer_sha256": "...", "probe_files": 6,
     "input": "/abs/shot.usda", "seconds": 1.9}

The sidecar is written atomically *after* the layer and the probes are in place, so a chunk
counts as finished only when everything it wrote is complete; a run killed at any point
leaves finished chunks usable and unfinished ones without a sidecar (they are recomputed).
``options_hash`` covers every processing option except the frame selection, plus the
shot-level lights; ``input_hash`` covers the bytes of every layer of the input stage. A
chunk whose frames, hashes or layer bytes differ from what the run expects is stale.

The folder also holds the run's shot cache, ``<dir>/shot_cache_<key>.npz``
(:func:`shot_cache_path`, ``usd_gs.pipeline.shot_cache``): what every chunk computes from the
shot's first frame, written by the first chunk that computes it and read by the others.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from pxr import Usd

from usd_gs import __version__
from usd_gs.errors import UserError
from usd_gs.io.atomic import atomic_output
from usd_gs.pipeline.options import canonical
from usd_gs.usd.stage import open_stage

FORMAT = "usdgs-chunk/1"
PREFIX = "chunk_"
SHOT_CACHE_PREFIX = "shot_cache_"  # the run's shared anchor-frame values (usd_gs.pipeline.shot_cache)


def _frame_label(f: float) -> str:
    """``1.0 -> '0001'``, ``-3.0 -> 'm0003'``, ``2.5 -> '0002p5'`` (file-name safe, sortable for f >= 0)."""
    sign = "m" if f < 0 else ""
    a = abs(f)
    whole = int(math.floor(a))
    frac = repr(a - whole)[2:] if a != whole else ""
    return f"{sign}{whole:04d}" + (f"p{frac}" if frac else "")


@dataclass(frozen=True)
class Chunk:
    """One chunk: its index in the plan and its frames (sorted time codes)."""

    index: int
    frames: tuple[float, ...]

    @property
    def name(self) -> str:
        return f"{PREFIX}{_frame_label(self.frames[0])}_{_frame_label(self.frames[-1])}"

    @property
    def label(self) -> str:
        """``frames 1-2`` for progress and error messages."""
        a, b = self.frames[0], self.frames[-1]
        return f"frames {a:g}" if a == b else f"frames {a:g}-{b:g}"

    def layer_path(self, folder: Path) -> Path:
        return Path(folder) / f"{self.name}.usdc"

    def sidecar_path(self, folder: Path) -> Path:
        return Path(folder) / f"{self.name}.json"

    def probes_path(self, folder: Path) -> Path:
        return Path(folder) / f"{self.name}_probes"

    def frames_spec(self) -> str:
        """A ``--frames`` value selecting exactly these frames."""
        return ",".join(repr(float(f)) for f in self.frames)


def plan_chunks(frames: list[float], chunk_size: int) -> list[Chunk]:
    """Split the processed frames (sorted) into chunks of at most ``chunk_size`` frames."""
    if chunk_size < 1:
        raise UserError(f"--chunk-size must be >= 1, got {chunk_size}")
    return [Chunk(i, tuple(float(f) for f in frames[k:k + chunk_size]))
            for i, k in enumerate(range(0, len(frames), chunk_size))]


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def input_hash(stage_path: str) -> str:
    """SHA-256 over the bytes of every file layer the input stage uses (sorted by path), so any
    edit to the shot, a sublayer or a referenced asset layer changes it."""

    stage = open_stage(stage_path) if not isinstance(stage_path, Usd.Stage) else stage_path
    files = sorted({layer.realPath for layer in stage.GetUsedLayers() if layer.realPath})
    h = hashlib.sha256()
    for f in files:
        h.update(os.path.basename(f).encode())
        h.update(sha256_file(f).encode())
    return h.hexdigest()


def options_hash(options, lights, anchor: float | None = None) -> str:
    """SHA-256 of every processing option except ``frames``,
    the shot-level ``lights`` (None: per frame from the stage), the normals ``anchor`` frame
    and the package version."""

    opts = canonical(options)
    opts.pop("frames", None)
    opts.pop("allow_missing", None)  # how the input is opened, not what is computed
    text = json.dumps({"options": opts, "lights": canonical(lights), "anchor": canonical(anchor),
                       "version": __version__}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def shot_cache_key(opts_hash: str, in_hash: str) -> str:
    """The key of a run's shot cache: SHA-256 of its options hash and input hash."""
    return hashlib.sha256(f"{opts_hash}:{in_hash}".encode()).hexdigest()


def shot_cache_path(folder: Path, opts_hash: str, in_hash: str) -> Path:
    """``<folder>/shot_cache_<first 16 hex digits of the key>.npz``: the file the chunks of one run
    share (``usd_gs.pipeline.shot_cache``)."""
    return Path(folder) / f"{SHOT_CACHE_PREFIX}{shot_cache_key(opts_hash, in_hash)[:16]}.npz"


def write_json_atomic(path: Path, data: dict) -> None:
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def read_sidecar(path: Path) -> dict | None:
    """A chunk's manifest entry, or None if it is missing, unreadable or not ours."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("format") == FORMAT else None


def chunk_is_done(chunk: Chunk, folder: Path, opts_hash: str, in_hash: str) -> bool:
    """True if the chunk's sidecar matches the frames and hashes and its files are intact."""
    entry = read_sidecar(chunk.sidecar_path(folder))
    if entry is None or entry.get("frames") != list(chunk.frames):
        return False
    if entry.get("options_hash") != opts_hash or entry.get("input_hash") != in_hash:
        return False
    return entry_files_ok(entry, folder)


def entry_files_ok(entry: dict, folder: Path) -> bool:
    """The entry's layer exists with the recorded bytes and its probe folder holds the files."""
    layer = Path(folder) / entry.get("layer", "")
    if not layer.is_file() or sha256_file(layer) != entry.get("layer_sha256"):
        return False
    n = int(entry.get("probe_files", 0))
    if n:
        probes = layer.with_name(layer.stem + "_probes")
        if not probes.is_dir() or len(list(probes.iterdir())) != n:
            return False
    return True


def remove_chunk(folder: Path, name: str) -> None:
    """Delete a chunk's sidecar first (it stops counting as finished), then its files."""
    folder = Path(folder)
    for p in (folder / f"{name}.json", folder / f"{name}.usdc"):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
    shutil.rmtree(folder / f"{name}_probes", ignore_errors=True)


def clean_folder(folder: Path, plan: list[Chunk], keep: set[str], opts_hash: str, in_hash: str) -> list[str]:
    """Remove what would otherwise mix with this run's chunks in ``folder``; returns the names
    of the chunks removed. Removed: temp files of a killed write of a planned chunk, planned
    chunks that are not finished (``keep`` holds the finished ones), chunks of other options
    or another input (stale), and chunks of the same run whose frames overlap the plan but
    that are not planned (another chunk size), and shot caches of other options or another input.
    Chunks of the same run with other frames (other farm tasks writing the same folder) are left
    alone. Only files this module names are touched."""
    folder = Path(folder)
    mine = shot_cache_path(folder, opts_hash, in_hash).name
    for p in folder.glob(f"{SHOT_CACHE_PREFIX}*.npz"):
        if p.name != mine:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
    planned = {c.name for c in plan}
    frames = {f for c in plan for f in c.frames}
    for name in planned - keep:
        for p in folder.glob(f".{name}[._]*"):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
    removed = []
    names = {p.stem for p in folder.glob(f"{PREFIX}*.json")} | {p.stem for p in folder.glob(f"{PREFIX}*.usdc")}
    for name in sorted(names - keep):
        entry = read_sidecar(folder / f"{name}.json")
        if entry is None and name not in planned:
            continue  # no entry: another task may be finishing it; assemble ignores it
        stale = entry is not None and (entry.get("options_hash") != opts_hash or entry.get("input_hash") != in_hash)
        if name in planned or stale or frames.intersection(entry.get("frames", ())):
            remove_chunk(folder, name)
            removed.append(name)
    return removed
