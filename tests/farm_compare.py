"""Attribute-by-attribute comparison of two composed stages (used by the farm tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Sdf, Usd


def _same(a, b) -> bool:
    if isinstance(a, Sdf.AssetPath) and isinstance(b, Sdf.AssetPath):
        # clip values are anchored at their chunk layer: compare the files they name
        return Path(a.resolvedPath).read_bytes() == Path(b.resolvedPath).read_bytes()
    if a is None or b is None:
        return a is None and b is None
    if hasattr(a, "__len__") and not isinstance(a, str):
        x, y = np.asarray(a), np.asarray(b)
        return x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x, y)
    return a == b


def stage_differences(path_a, path_b, frames) -> list[str]:
    """Every (prim, attribute, frame) whose composed value differs, plus prims, types,
    attributes and metadata (interpolation, elementSize) present on one side only."""
    sa, sb = Usd.Stage.Open(str(path_a)), Usd.Stage.Open(str(path_b))
    out = []
    prims_a = {str(p.GetPath()): p for p in sa.Traverse()}
    prims_b = {str(p.GetPath()): p for p in sb.Traverse()}
    for p in sorted(set(prims_a) ^ set(prims_b)):
        out.append(f"{p}: prim on one side only")
    for path in sorted(set(prims_a) & set(prims_b)):
        pa, pb = prims_a[path], prims_b[path]
        if pa.GetTypeName() != pb.GetTypeName():
            out.append(f"{path}: type {pa.GetTypeName()} != {pb.GetTypeName()}")
        names_a = {a.GetName() for a in pa.GetAttributes() if a.HasAuthoredValue()}
        names_b = {a.GetName() for a in pb.GetAttributes() if a.HasAuthoredValue()}
        for n in sorted(names_a ^ names_b):
            out.append(f"{path}.{n}: authored on one side only")
        for n in sorted(names_a & names_b):
            aa, ab = pa.GetAttribute(n), pb.GetAttribute(n)
            for key in ("interpolation", "elementSize"):
                if aa.GetMetadata(key) != ab.GetMetadata(key):
                    out.append(f"{path}.{n}: {key} {aa.GetMetadata(key)} != {ab.GetMetadata(key)}")
            for f in frames:
                if not _same(aa.Get(f), ab.Get(f)):
                    out.append(f"{path}.{n} @ {f}: differs")
    return out
