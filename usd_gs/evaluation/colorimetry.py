"""Colorimetry for the evaluation metrics: CIE Y and CIE-Lab of linear Rec.709 / sRGB colours.

Input colours are **linear** RGB with Rec.709 (= sRGB) primaries and D65 white, the colour
space of the Gaussians' ``0.5 + SH`` colours in this project (the generated scenes and
avatars store linear colours). Conversions follow IEC 61966-2-1 and CIE 15:

- ``XYZ = M @ rgb`` with the sRGB matrix :data:`RGB_TO_XYZ` (white (1, 1, 1) -> D65 white
  :data:`D65_WHITE`, Y = 1);
- CIE Y (relative luminance) is the middle row: ``0.2126729 R + 0.7151522 G + 0.0721750 B``;
- CIE-Lab (CIE 1976 L*a*b*) relative to D65: ``L* = 116 f(Y/Yn) - 16``,
  ``a* = 500 (f(X/Xn) - f(Y/Yn))``, ``b* = 200 (f(Y/Yn) - f(Z/Zn))`` with
  ``f(t) = t^(1/3)`` for ``t > (6/29)^3`` else ``t / (3 (6/29)^2) + 4/29``.

Values above 1 (relit, HDR colours) are allowed (L* > 100); negative components are
clamped to 0 first (a Gaussian cannot emit negative light; the 3DGS renderer clamps too).
"""

from __future__ import annotations

import numpy as np

RGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                       [0.2126729, 0.7151522, 0.0721750],
                       [0.0193339, 0.1191920, 0.9503041]])
"""Linear sRGB / Rec.709 (D65) to CIE XYZ, IEC 61966-2-1."""

D65_WHITE = RGB_TO_XYZ.sum(axis=1)
"""XYZ of linear RGB (1, 1, 1): (0.95047, 1.0, 1.08883)."""

_DELTA = 6.0 / 29.0


def _rgb(rgb) -> np.ndarray:
    a = np.asarray(rgb, dtype=np.float64)
    if a.shape[-1] != 3:
        raise ValueError(f"colours must have shape (..., 3), got {a.shape}")
    return np.maximum(a, 0.0)


def luminance(rgb) -> np.ndarray:
    """CIE Y (..., ) float64 of linear Rec.709 RGB (..., 3); white = 1."""
    return _rgb(rgb) @ RGB_TO_XYZ[1]


def rgb_to_xyz(rgb) -> np.ndarray:
    """CIE XYZ (..., 3) float64 of linear Rec.709 RGB (..., 3)."""
    return _rgb(rgb) @ RGB_TO_XYZ.T


def _f(t: np.ndarray) -> np.ndarray:
    return np.where(t > _DELTA ** 3, np.cbrt(t), t / (3.0 * _DELTA * _DELTA) + 4.0 / 29.0)


def rgb_to_lab(rgb) -> np.ndarray:
    """CIE-Lab (..., 3) float64 (L* in [0, 100] for colours in [0, 1]) of linear Rec.709 RGB, D65 white."""
    fx, fy, fz = np.moveaxis(_f(rgb_to_xyz(rgb) / D65_WHITE), -1, 0)
    return np.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)

