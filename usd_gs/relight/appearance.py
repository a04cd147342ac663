"""Relightable appearance a Gaussian prim may carry (read for the main job's relighting).

Attributes (all optional, per particle, prim-local like the other particle arrays; a prim with
none of them is relit from its captured colour, ``usd_gs.relight.avatar``):

| attribute | type | meaning |
| --- | --- | --- |
| ``primvars:usdgs:albedo`` | color3f[] (N) | linear diffuse albedo in [0, 1]: relit colour ``gamma albedo E / pi`` |
| ``primvars:usdgs:zh:albedo`` | color3f[] (N) | RGCA albedo rho (linear) |
| ``primvars:usdgs:zh:color`` | float3[] (N*12) | RGCA coloured ZH (elementSize 12): per particle 3 axes x 4 bands |
| ``primvars:usdgs:zh:mono`` | float[] (N*15) | RGCA monochrome ZH (elementSize 15): 3 axes x 5 bands (l = 4..8) |

Axes: tangent, bitangent, normal = the columns of the Gaussian's rotation; coloured bands
l = 0..3, RGB last.

ZH coefficients follow ``numba_kernels.zh_transfer`` (RGCA eq. 8, stored as is). The ZH path
needs ``zh:albedo`` and ``zh:color``; ``zh:color`` wins over ``albedo`` when both are present.
Values are read at the frame (time samples) or the default. Bad input (wrong length, non-finite,
negative albedo): ``UserError`` naming the prim and attribute.
"""

from __future__ import annotations

import numpy as np

from usd_gs.errors import GaussianDataError

ALBEDO = "primvars:usdgs:albedo"
ZH_ALBEDO = "primvars:usdgs:zh:albedo"
ZH_COLOR = "primvars:usdgs:zh:color"
ZH_MONO = "primvars:usdgs:zh:mono"


def _read(prim, name: str, time, n: int, per: int, comps: int) -> np.ndarray | None:
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        return None
    v = attr.Get(time)
    if v is None:
        return None
    a = np.asarray(v, np.float64).reshape(-1)
    if a.size != n * per * comps:
        raise GaussianDataError(f"{prim.GetPath()}: '{name}' has {a.size // max(comps, 1)} elements, expected "
                                f"{n * per} ({per} per particle for {n} particles)")
    bad = ~np.isfinite(a)
    if bad.any():
        raise GaussianDataError(f"{prim.GetPath()}: '{name}' element {int(np.flatnonzero(bad)[0]) // comps} is not "
                                "finite")
    return a


def read_appearance(prim, time, n: int) -> dict | None:
    """``{'albedo': (N, 3)}`` or ``{'zh_albedo': (N, 3), 'zh_color': (N, 3, 4, 3)[, 'zh_mono': (N, 3, 5)]}``
    (float32) from ``prim`` (a ``Usd.Prim``) at ``time`` (``Usd.TimeCode``) for its ``n`` particles,
    or None when it carries neither (module docstring)."""
    zc = _read(prim, ZH_COLOR, time, n, 12, 3)
    if zc is not None:
        za = _read(prim, ZH_ALBEDO, time, n, 1, 3)
        if za is None:
            raise GaussianDataError(f"{prim.GetPath()}: '{ZH_COLOR}' needs '{ZH_ALBEDO}' too")
        out = {"zh_albedo": za.reshape(n, 3).astype(np.float32),
               "zh_color": zc.reshape(n, 3, 4, 3).astype(np.float32)}
        zm = _read(prim, ZH_MONO, time, n, 15, 1)
        if zm is not None:
            out["zh_mono"] = zm.reshape(n, 3, 5).astype(np.float32)
        return out
    alb = _read(prim, ALBEDO, time, n, 1, 3)
    if alb is None:
        return None
    if (alb < 0).any():
        raise GaussianDataError(f"{prim.GetPath()}: '{ALBEDO}' element {int(np.flatnonzero(alb < 0)[0]) // 3} is "
                                "negative")
    return {"albedo": alb.reshape(n, 3).astype(np.float32)}
