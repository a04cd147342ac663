"""USD's float array storage for a numpy shape, with pxr alone (no numpy): ``usdgs import``
allocates the arrays a SOG decodes into before numpy is loaded (``usd_gs.usd.bulk`` wraps them
in numpy views)."""

from __future__ import annotations


def vt_class_name(shape: tuple) -> str | None:
    """The ``Vt`` float32 array class whose numpy view has ``shape``: ``FloatArray`` for (N,),
    ``Vec3fArray`` for (N, ..., 3) (N * ... vectors); None for any other shape."""
    shape = tuple(int(d) for d in shape)
    if len(shape) == 1:
        return "FloatArray"
    if len(shape) >= 2 and shape[-1] == 3:
        return "Vec3fArray"
    return None


def new_vt_array(shape: tuple):
    """A fresh zero-filled ``Vt`` array of :func:`vt_class_name` ``(shape)`` holding ``prod(shape)``
    floats, or None when no class fits."""
    name = vt_class_name(shape)
    if name is None:
        return None
    from pxr import Vt

    count = 1
    for d in shape[:-1] if name == "Vec3fArray" else shape:
        count *= int(d)
    return getattr(Vt, name)(count)
