"""sRGB transfer function of the colour maths (shared/DESIGN.md section 4): relighting and shadows.

3DGS colours (``0.5 + SH(dir)``) are display-referred, sRGB-encoded values; light is summed and
divided on linear values. :func:`srgb_decode` / :func:`srgb_encode` are the IEC 61966-2-1
piecewise curve (linear segment below 0.04045 encoded / 0.0031308 linear, exponent 2.4 above),
extended above 1 by the same power law (HDR values such as a lamp's radiance stay monotonic and
invertible) and clamped at 0 below (no negative light). Both are float64 in, float64 out, any
shape.

``COLOR_SPACES``: 'srgb' (the default, the DESIGN rule) or 'linear' (colours that are linear
already, e.g. generated scenes baked in linear units): :func:`to_linear` / :func:`from_linear`
pick the conversion.
"""

from __future__ import annotations

import numpy as np

COLOR_SPACES = ("srgb", "linear")
#: Rec. 709 / sRGB luminance weights of linear RGB
LUMA = np.array([0.2126, 0.7152, 0.0722])


def srgb_decode(c) -> np.ndarray:
    """Linear values of sRGB-encoded ``c`` (module docstring)."""
    c = np.maximum(np.asarray(c, np.float64), 0.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def srgb_encode(x) -> np.ndarray:
    """sRGB-encoded values of linear ``x`` (module docstring)."""
    x = np.maximum(np.asarray(x, np.float64), 0.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055)


def to_linear(c, space: str) -> np.ndarray:
    """``c`` in linear units: decoded for 'srgb', as is (clamped at 0) for 'linear'."""
    if space == "srgb":
        return srgb_decode(c)
    return np.maximum(np.asarray(c, np.float64), 0.0)


def from_linear(x, space: str) -> np.ndarray:
    """Linear ``x`` in the colour space ``space`` (inverse of :func:`to_linear`)."""
    if space == "srgb":
        return srgb_encode(x)
    return np.maximum(np.asarray(x, np.float64), 0.0)


def display_factor(c, k, space: str, floor: float = 1e-4, linear=None) -> np.ndarray:
    """Per-channel factor ``f`` with ``f * c = from_linear(to_linear(c) * k)``: what scaling a
    displayed colour ``c`` (..., 3) by the linear light ratio ``k`` (same shape) means in
    ``space``. Where ``c < floor`` the factor is the one of the limit ``c -> 0`` (``k``: the
    sRGB curve is linear there). ``linear``: ``to_linear(c, space)`` where the caller has it."""
    c = np.asarray(c, np.float64)
    k = np.maximum(np.asarray(k, np.float64), 0.0)
    if space != "srgb":
        return k
    out = from_linear((to_linear(c, space) if linear is None else linear) * k, space)
    small = c < floor
    return np.where(small, k, out / np.where(small, 1.0, c))
