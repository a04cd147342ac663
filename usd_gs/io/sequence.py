"""Frame sequences: one capture file per frame, named by a pattern.

A pattern holds exactly one frame token: a run of ``#`` (``monkey_####.sog``: the frame number
zero-padded to the run's length) or a printf integer (``%d``, ``%04d``). Frames are integers
and become USD time codes as they are.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet

_TOKEN = re.compile(r"#+|%0?(\d*)d")


def _token(pattern: str) -> re.Match | None:
    """The frame token in the file-name part of ``pattern`` (None if there is none)."""
    head, name = os.path.split(pattern)
    hits = list(_TOKEN.finditer(name))
    if len(hits) > 1:
        raise UserError(f"{pattern}: more than one frame token ('#...' or '%0Nd') in the file name")
    if not hits:
        return None
    m = hits[0]
    return _TOKEN.match(pattern, len(pattern) - len(name) + m.start())


def is_pattern(path: str) -> bool:
    """True when ``path``'s file name holds a frame token (``####`` or ``%04d``)."""
    return _token(str(path)) is not None


def frame_path(pattern: str, frame: int) -> str:
    """``pattern`` with its frame token replaced by ``frame`` (zero-padded to the token width)."""
    m = _token(pattern)
    if m is None:
        return pattern
    tok = m.group(0)
    width = len(tok) if tok.startswith("#") else int(m.group(1) or 0)
    sign = "-" if frame < 0 else ""
    return pattern[:m.start()] + sign + str(abs(frame)).zfill(width) + pattern[m.end():]


def parse_frames(text: str) -> tuple[int, int]:
    """``'A-B'`` (or ``'A'``, or ``'A:B'``) as an inclusive ``(A, B)`` with ``A <= B``."""
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:[-:]\s*(-?\d+)\s*)?", str(text))
    if not m:
        raise UserError(f"--frames {text!r}: expected A-B (e.g. 1-50) or a single frame")
    a = int(m.group(1))
    b = int(m.group(2)) if m.group(2) is not None else a
    if b < a:
        raise UserError(f"--frames {text!r}: the last frame {b} is before the first {a}")
    return a, b


def discover_frames(pattern: str) -> tuple[int, int]:
    """The first and last frame of files on disk matching ``pattern`` (``UserError`` if none)."""
    m = _token(pattern)
    if m is None:
        raise UserError(f"{pattern}: not a frame pattern (needs '####' or '%04d' in the file name)")
    folder = os.path.dirname(pattern) or "."
    name = os.path.basename(pattern)
    nm = _TOKEN.search(name)
    rx = re.compile(re.escape(name[:nm.start()]) + r"(-?\d+)" + re.escape(name[nm.end():]) + r"\Z")
    try:
        entries = os.listdir(folder)
    except OSError as exc:
        raise UserError(f"{pattern}: cannot list folder {folder} ({exc.strerror})") from None
    frames = sorted(int(h.group(1)) for h in (rx.match(e) for e in entries) if h)
    if not frames:
        raise UserError(f"{pattern}: no file in {folder} matches the pattern")
    return frames[0], frames[-1]


def sequence_paths(pattern: str, frames: tuple[int, int] | None = None) -> list[tuple[int, str]]:
    """``[(frame, path)]`` for frames ``A..B`` (default: the range found on disk).

    Raises :class:`UserError` naming the first missing file.
    """
    a, b = frames if frames is not None else discover_frames(pattern)
    out = [(f, frame_path(pattern, f)) for f in range(a, b + 1)]
    for f, p in out:
        if not os.path.exists(p):
            raise UserError(f"{p}: missing frame {f} of the sequence {pattern} (frames {a}-{b})")
    return out


def read_sequence(pattern: str, frames: tuple[int, int] | None = None, lod: int | None = None,
                  prefetch: int = 2) -> Iterator[tuple[int, GaussianSet]]:
    """Yield ``(frame, GaussianSet)`` for every frame of the sequence, in frame order.

    Every path is checked before the first file is read (missing frames fail fast). Up to
    ``prefetch`` frames ahead are decoded in a background thread while the caller works on
    the current one (0: read each frame when asked).
    """
    from concurrent.futures import ThreadPoolExecutor

    from usd_gs.io.formats import read_capture

    paths = sequence_paths(pattern, frames)
    if prefetch <= 0:
        for f, p in paths:
            yield f, read_capture(Path(p), lod=lod)
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="usdgs-seq") as pool:
        pending = [pool.submit(read_capture, Path(p), lod) for _, p in paths[:prefetch]]
        try:
            for i, (f, _) in enumerate(paths):
                g = pending.pop(0).result()
                if i + prefetch < len(paths):
                    pending.append(pool.submit(read_capture, Path(paths[i + prefetch][1]), lod))
                yield f, g
        finally:
            for fut in pending:
                fut.cancel()
