"""Exception types. ``UserError`` and its subclasses are bad input: the CLI prints their
message on one line and exits with code 2. Anything else is an internal error (exit 1)."""

from __future__ import annotations


class UserError(Exception):
    """Bad input or options. The message must name the file/prim, attribute and element."""


class InputFormatError(UserError):
    """A file (PLY, SPZ, USD) that cannot be read as what it claims to be."""


class GaussianDataError(UserError):
    """Gaussian arrays that break the data contract (lengths, NaN/Inf, ranges, transforms)."""


def first_bad_index(mask) -> int:
    """Index of the first True in a flat boolean mask (``-1`` if none)."""
    import numpy as np

    idx = np.flatnonzero(np.asarray(mask).reshape(len(mask), -1).any(axis=1))
    return int(idx[0]) if idx.size else -1
