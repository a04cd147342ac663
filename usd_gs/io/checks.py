"""Checks of a ``GaussianSet`` before it is written to a capture format (PLY, SPZ, .splat, SOG)."""

from __future__ import annotations

from usd_gs.errors import GaussianDataError, first_bad_index


def check_exportable(g) -> None:
    """``GaussianDataError`` naming the set (its prim path) and the first element whose opacity
    is outside [0, 1]: capture formats store a logit or a byte and would clamp it silently."""
    bad = ~((g.opacities >= 0) & (g.opacities <= 1))
    if bad.any():
        i = first_bad_index(bad)
        raise GaussianDataError(f"{g.label}: attribute 'opacities' element {i} is {float(g.opacities[i]):g}, outside "
                                f"[0, 1] ({int(bad.sum())} such elements); fix the stage (see usdgs validate)")


__all__ = ["check_exportable"]
