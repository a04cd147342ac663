"""A frame sequence of Gaussian sets as ONE time-sampled ``ParticleField3DGaussianSplat`` prim.

Each frame ``f`` becomes time samples at time code ``f`` of every per-particle attribute and
the extent (:func:`usd_gs.usd.gaussian_prim.write_gaussian_prim` with ``time=f``). Afterwards
every attribute whose samples are identical in every frame is authored once, as a default
value, with no samples. Counts may differ between frames (shared/DESIGN.md section 2: there is
no correspondence between frames, consumers evaluate whole frames). The SH degree must be the
same in every frame (it is a uniform attribute).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd

from usd_gs.errors import UserError
from usd_gs.gaussians import GaussianSet
from usd_gs.usd.gaussian_prim import write_gaussian_prim


@dataclass
class SequenceInfo:
    """What :func:`write_sequence_prim` wrote."""

    frames: list[int] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    sh_degree: int = 0
    static: list[str] = field(default_factory=list)     # attributes authored once (default value)
    animated: list[str] = field(default_factory=list)   # attributes with one sample per frame


def _same(a, b) -> bool:
    x, y = np.asarray(a), np.asarray(b)
    return x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8))


def hold_static_samples(stage: Usd.Stage, path) -> tuple[list[str], list[str]]:
    """Turn attributes of ``path`` (in the edit target layer) whose time samples are all
    bit-identical into a default value with no samples. Returns (static, animated) names."""
    layer = stage.GetEditTarget().GetLayer()
    spec_path = stage.GetEditTarget().MapToSpecPath(Sdf.Path(str(path)))
    prim_spec = layer.GetPrimAtPath(spec_path)
    static, animated = [], []
    if prim_spec is None:
        return static, animated
    for spec in list(prim_spec.attributes):
        times = layer.ListTimeSamplesForPath(spec.path)
        if not times:
            continue
        first = layer.QueryTimeSample(spec.path, times[0])
        ref = np.asarray(first)
        if all(_same(ref, layer.QueryTimeSample(spec.path, t)) for t in times[1:]):
            with Sdf.ChangeBlock():
                for t in times:
                    layer.EraseTimeSample(spec.path, t)
                spec.default = first
            static.append(spec.name)
        else:
            animated.append(spec.name)
    return static, animated


def write_sequence_prim(stage: Usd.Stage, path, frames: Iterable[tuple[int, GaussianSet]], keep_raw: bool = True,
                        precision: str = "float", fps: float | None = None) -> SequenceInfo:
    """Author ``frames`` (``(frame, GaussianSet)`` pairs, prim-local space) at ``path``.

    Sets the stage's start/end time codes to the first/last frame and, when ``fps`` is given,
    ``timeCodesPerSecond`` and ``framesPerSecond``. Raises :class:`UserError` for no frames
    or an SH degree that changes between frames (naming the frame's file).
    """
    info = SequenceInfo()
    for f, g in frames:
        if info.frames and g.sh_degree != info.sh_degree:
            raise UserError(f"{g.label}: frame {f} has SH degree {g.sh_degree} but frame {info.frames[0]} has "
                            f"{info.sh_degree}; the degree cannot change within a sequence")
        if not info.frames:
            info.sh_degree = g.sh_degree
        write_gaussian_prim(stage, path, g, time=float(f), keep_raw=keep_raw, precision=precision)
        info.frames.append(int(f))
        info.counts.append(g.count)
    if not info.frames:
        raise UserError(f"{path}: the sequence has no frames")
    info.static, info.animated = hold_static_samples(stage, path)
    stage.SetStartTimeCode(min(info.frames))
    stage.SetEndTimeCode(max(info.frames))
    if fps is not None:
        if not (fps > 0 and np.isfinite(fps)):
            raise UserError(f"--fps {fps}: must be a positive number")
        stage.SetTimeCodesPerSecond(float(fps))
        stage.SetFramesPerSecond(float(fps))
    return info
