"""Checks shared by the capture readers and writers: an input path that must be a readable file,
and a ``GaussianSet`` before it is written to a capture format (PLY, SPZ, .splat, SOG)."""

from __future__ import annotations

from pathlib import Path

from usd_gs.errors import GaussianDataError, InputFormatError, first_bad_index


def existing_file(path) -> Path:
    """``Path(path)``; ``InputFormatError`` naming it when it does not exist or is not a regular file."""
    p = Path(path)
    if not p.exists():
        raise InputFormatError(f"{path}: no such file")
    if not p.is_file():
        raise InputFormatError(f"{path}: not a regular file")
    return p


def check_exportable(g) -> None:
    """``GaussianDataError`` naming the set (its prim path) and the first element whose opacity
    is outside [0, 1]: capture formats store a logit or a byte and would clamp it silently."""
    bad = ~((g.opacities >= 0) & (g.opacities <= 1))
    if bad.any():
        i = first_bad_index(bad)
        raise GaussianDataError(f"{g.label}: attribute 'opacities' element {i} is {float(g.opacities[i]):g}, outside "
                                f"[0, 1] ({int(bad.sum())} such elements); fix the stage (see usdgs validate)")


__all__ = ["check_exportable", "existing_file"]
