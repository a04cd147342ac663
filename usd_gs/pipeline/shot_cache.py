"""A shot-level cache file that the chunks of one farm run share: what each chunk would otherwise
compute again from the shot's first (anchor) frame before its own first frame.

Every chunk of a farm run estimates the relit prims' normals, probe clusters and self-shadow
sample maps at the shot's anchor frame, and calibrates the estimated point lights once, exactly
as the whole-shot run does at its first frame (so the stitched output equals the single run).
Those values depend only on the input, the options, the shot-level lights and the anchor frame,
so the first chunk to compute them writes them here and later chunks read them back: the same
arrays, bit for bit, without the work (``usd_gs.pipeline.shot.ShotProcessor``).

File: one uncompressed NumPy ``.npz`` (no pickled objects), written atomically; its ``index``
member is JSON ``{"format": FORMAT, "key": ..., "entries": [[entry key, [member names]]]}`` and
every other member one array. ``key`` is the run's key (``usd_gs.farm.chunks.shot_cache_key``:
a hash of the options, lights, anchor frame, package version and the input's bytes); a file
with another key, another format or that cannot be read is ignored (computed again, then
replaced). Writers merge with what the file holds at the time, so chunks that run side by side
lose nothing but the race to write first.
"""

from __future__ import annotations

import json
import threading
import zipfile
from pathlib import Path

import numpy as np

from usd_gs.io.atomic import atomic_output

FORMAT = "usdgs-shot-cache/1"


def _entry_name(key: tuple) -> str:
    return json.dumps(list(key), separators=(",", ":"))


class ShotCache:
    """The cache file at ``path`` for the run ``key`` (module docstring). ``get`` and ``put`` are
    thread-safe; ``save`` writes the entries the file does not hold yet.

    Counters: ``loaded`` entries served from the file, ``computed`` entries this process added;
    ``problem`` names an unreadable file that was ignored (None when there was none)."""

    def __init__(self, path, key: str):
        self.path = Path(path)
        self.key = str(key)
        self._lock = threading.Lock()
        self._entries: dict[str, tuple[np.ndarray, ...]] = {}
        self._on_disk: set[str] = set()
        self.loaded = 0
        self.computed = 0
        self.problem: str | None = None
        self._entries.update(self._read())
        self._on_disk = set(self._entries)  # what the file holds (as far as this process knows)
        self._from_file = set(self._entries)  # what another process computed

    def _read(self) -> dict[str, tuple[np.ndarray, ...]]:
        """The file's entries ({} when it is missing, of another run or unreadable)."""
        if not self.path.is_file():
            return {}
        try:
            with np.load(self.path, allow_pickle=False) as z:
                index = json.loads(str(z["index"][()]))
                if index.get("format") != FORMAT or index.get("key") != self.key:
                    return {}
                return {name: tuple(np.array(z[m]) for m in members) for name, members in index["entries"]}
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
            self.problem = f"{self.path}: unreadable shot cache ({type(exc).__name__}: {exc}); computed again"
            return {}

    def get(self, *key) -> tuple[np.ndarray, ...] | None:
        """The arrays stored under ``key`` (a tuple of str, int and float), or None."""
        name = _entry_name(key)
        with self._lock:
            got = self._entries.get(name)
            if got is not None and name in self._from_file:
                self.loaded += 1
        return got

    def peek(self, *key) -> tuple[np.ndarray, ...] | None:
        """:meth:`get` without counting a load (to decide whether something must be computed)."""
        with self._lock:
            return self._entries.get(_entry_name(key))

    def put(self, key: tuple, arrays) -> None:
        """Store ``arrays`` (a sequence of arrays) under ``key``; the first value stored stays."""
        name = _entry_name(key)
        with self._lock:
            if name not in self._entries:
                self._entries[name] = tuple(np.asarray(a) for a in arrays)
                self.computed += 1

    def save(self) -> bool:
        """Write the file when this process holds entries it lacks (merged with the entries the
        file holds now, so another chunk's are kept); True if it wrote."""
        with self._lock:
            if set(self._entries) <= self._on_disk:
                return False
            entries = dict(self._entries)
        entries = {**self._read(), **entries}
        members: dict[str, np.ndarray] = {}
        index = []
        for i, (name, arrays) in enumerate(sorted(entries.items())):
            names = [f"e{i}_{j}" for j in range(len(arrays))]
            members.update(zip(names, arrays, strict=True))
            index.append([name, names])
        text = json.dumps({"format": FORMAT, "key": self.key, "entries": index})
        with atomic_output(self.path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, index=np.array(text), **members)
        with self._lock:
            self._on_disk |= set(entries)
            for name, arrays in entries.items():
                if name not in self._entries:
                    self._entries[name] = arrays
                    self._from_file.add(name)
        return True
