"""The demo's optional monkey: the shared SOG flipbook ``sequences/monkey/monkey_0001..0050.sog``
as one time-sampled avatar prim (``usdgs demo make --monkey``).

``stages/demo_data/monkey.usdc``: ``/World/Monkey``, role avatar, SH degree 0. Demo frame f
shows sequence frame ``(f - 1) % 50 + 1``; every frame is placed by the same canonical matrix
(baked into the points): turned upright from the PLY convention (180 degrees about Z: the
flipbook is stored Y-down), lowest point on y = 0, centred on :data:`MONKEY_POSITION` and
scaled to :data:`MONKEY_HEIGHT` metres tall (all from frame 1). Written with
:func:`usd_gs.usd.sequence_prim.write_sequence_prim`: attributes identical in every frame
are authored once.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from usd_gs.io.formats import read_capture
from usd_gs.io.sequence import frame_path, sequence_paths
from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic
from usd_gs.usd.schema import apply_role
from usd_gs.usd.sequence_prim import write_sequence_prim

MONKEY_PATTERN = "sequences/monkey/monkey_####.sog"
MONKEY_FRAMES = 50
MONKEY_HEIGHT = 0.45
MONKEY_POSITION = (1.2, 0.0, 1.1)
MONKEY_ROTATION = np.diag([-1.0, -1.0, 1.0])
PRIM_PATH = "/World/Monkey"


def monkey_frame(f: int) -> int:
    """Sequence frame (1..50) shown at demo frame ``f`` (1-based; the flipbook loops)."""
    return (int(f) - 1) % MONKEY_FRAMES + 1


def placement_matrix(positions: np.ndarray) -> np.ndarray:
    """USD (row-vector) 4x4 matrix: rotate by :data:`MONKEY_ROTATION`, lowest point to y = 0,
    x/z box centre to :data:`MONKEY_POSITION`, uniform scale to :data:`MONKEY_HEIGHT` tall
    (the placement ``usd_gs.demo.stage.canonical_matrix`` gives the demo's captures)."""
    rot = MONKEY_ROTATION
    p = np.asarray(positions, np.float64) @ rot.T
    lo, hi = p.min(axis=0), p.max(axis=0)
    s = MONKEY_HEIGHT / (hi[1] - lo[1])
    base = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    m = np.eye(4)
    m[:3, :3] = (s * rot).T
    m[3, :3] = np.asarray(MONKEY_POSITION) - s * base
    return m


def write_monkey_layer(frames: int, data_dir, path, fps: float = 24.0) -> int:
    """Write the monkey layer (module docstring) for demo frames 1..``frames`` to ``path``.

    Returns the Gaussian count of frame 1. Raises ``UserError`` naming a missing frame file.
    """

    pattern = str(Path(data_dir) / MONKEY_PATTERN)
    sequence_paths(pattern, (1, min(frames, MONKEY_FRAMES)))  # every file present before any work
    first = read_capture(frame_path(pattern, 1))
    m = placement_matrix(first.positions)
    cache: dict[int, object] = {}

    def placed(f: int):
        src = monkey_frame(f)
        if src not in cache:
            g = read_capture(frame_path(pattern, src)).transformed(m, label=PRIM_PATH)
            cache[src] = replace(g, log_scales=None, logit_opacities=None, extras={})
        g = cache[src]
        if frames <= MONKEY_FRAMES:
            cache.pop(src)
        return f, g

    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    write_sequence_prim(stage, PRIM_PATH, (placed(f) for f in range(1, frames + 1)), keep_raw=False, fps=fps)
    apply_role(stage.GetPrimAtPath(PRIM_PATH), "avatar")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    save_stage_atomic(stage, path)
    return first.count
