"""Frame-range parsing for ``--frames``.

Accepted forms (inclusive ends, USD time codes):

- ``A-B``        every whole frame from A to B;
- ``A:B:STEP``   A, A+STEP, ... up to B (``A:B`` means step 1);
- ``N``          the single frame N;
- a comma-separated list of the above (``1-10,20,30:40:5``).

Negative frames are written with the colon form (``-5:5``; ``--frames -2:-1`` works without
``=``). Duplicates are removed and the result is sorted. ``None`` means the stage's start..end time codes.

:func:`as_time` is the one conversion of a time argument (a ``Usd.TimeCode``, a number or
None) to a ``Usd.TimeCode`` that every reader, renderer and writer uses.
"""

from __future__ import annotations

import math
import re

from usd_gs.errors import UserError

_RANGE = re.compile(r"^\s*(-?\d+(?:\.\d+)?)\s*-\s*(-?\d+(?:\.\d+)?)\s*$")
MAX_FRAMES = 1_000_000


def _num(text: str, spec: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise UserError(f"--frames '{spec}': '{text}' is not a number") from None
    if not math.isfinite(v):
        raise UserError(f"--frames '{spec}': '{text}' is not finite")
    return v


def _span(a: float, b: float, step: float, spec: str) -> list[float]:
    if step <= 0:
        raise UserError(f"--frames '{spec}': step must be > 0")
    if b < a:
        raise UserError(f"--frames '{spec}': end {b:g} is before start {a:g}")
    q = (b - a) / step
    if not math.isfinite(q) or q + 1 > MAX_FRAMES:
        many = f"{int(q) + 1:,}" if math.isfinite(q) else "too many"
        raise UserError(f"--frames '{spec}': {many} frames is more than {MAX_FRAMES:,}")
    n = int(math.floor(q + 1e-9)) + 1
    return [a + i * step for i in range(n)]


def parse_frames(spec: str | None, start: float, end: float) -> list[float]:
    """Frames (sorted float time codes) selected by ``spec``; ``None`` -> start..end step 1."""
    if spec is None or not spec.strip():
        return _span(float(start), float(end), 1.0, f"{start:g}-{end:g} (stage range)")
    frames: set[float] = set()
    for part in spec.split(","):
        part = part.strip()
        if not part:
            raise UserError(f"--frames '{spec}': empty item")
        m = _RANGE.match(part)
        if ":" in part:
            bits = part.split(":")
            if len(bits) not in (2, 3):
                raise UserError(f"--frames '{spec}': '{part}' must be A:B or A:B:STEP")
            a, b = _num(bits[0], spec), _num(bits[1], spec)
            step = _num(bits[2], spec) if len(bits) == 3 else 1.0
            frames.update(_span(a, b, step, spec))
        elif m:
            frames.update(_span(_num(m.group(1), spec), _num(m.group(2), spec), 1.0, spec))
        else:
            frames.add(_num(part, spec))
    return sorted(frames)


def outside_warning(frames: list[float], start: float, end: float, stage_path: str) -> str | None:
    """A warning naming the frames outside the stage's time range ``start..end`` (values are then
    held from the nearest sample), or None when every frame is inside."""
    out = [f for f in frames if f < start or f > end]
    if not out:
        return None
    shown = ", ".join(f"{f:g}" for f in out[:5]) + (f" ... ({len(out)} in all)" if len(out) > 5 else "")
    return (f"frame(s) {shown} outside {stage_path}'s time range {start:g}..{end:g}: values there are held from "
            "the nearest time sample")


def as_time(time, none=None):
    """``Usd.TimeCode`` from a ``Usd.TimeCode`` (returned as is), a number, or None; None gives
    ``none`` (a ``Usd.TimeCode``; default: ``Usd.TimeCode.Default()``, the unanimated value)."""
    from pxr import Usd

    if time is None:
        return Usd.TimeCode.Default() if none is None else none
    if isinstance(time, Usd.TimeCode):
        return time
    return Usd.TimeCode(float(time))
