"""Biovision Hierarchy (.bvh) motion reader (numpy only).

Conventions: the file's own units and axes (no conversion here); matrices 4x4 float64 in the
column-vector convention. Each joint's local transform at frame f is
``T(offset + position channels) @ R`` with ``R`` the product of its rotation channels in the
order listed (``CHANNELS 3 Zrotation Xrotation Yrotation`` -> ``Rz @ Rx @ Ry``, angles in
degrees), the standard BVH reading; the global transform is the parent's global times the
local one. ``End Site`` offsets are kept as each joint's ``end_offsets`` (the direction of a
leaf bone). The rest pose is every channel at zero (offsets only).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from usd_gs.errors import InputFormatError

_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass
class BvhMotion:
    """A parsed BVH file. ``names`` (J,) joint names in file order (parents first);
    ``parents`` (J,) int (-1 root); ``offsets`` (J, 3); ``end_offsets`` list of (3,) arrays or None
    (the End Site of a leaf joint); ``channels`` list of channel-name lists per joint;
    ``frames`` (F, C) float64 channel values; ``frame_time`` seconds per frame."""

    path: str
    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_offsets: list
    channels: list[list[str]]
    frames: np.ndarray
    frame_time: float

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def rest_global(self) -> np.ndarray:
        """(J, 4, 4) global matrices of the rest pose (all channels zero)."""
        g = np.zeros((len(self.names), 4, 4))
        for j, p in enumerate(self.parents):
            loc = np.eye(4)
            loc[:3, 3] = self.offsets[j]
            g[j] = loc if p < 0 else g[p] @ loc
        return g

    def global_transforms(self, frame_indices=None) -> np.ndarray:
        """(F, J, 4, 4) global matrices at the given frames (all frames when None)."""
        fr = self.frames if frame_indices is None else self.frames[np.asarray(frame_indices, np.int64)]
        f, nj = fr.shape[0], len(self.names)
        glob = np.zeros((f, nj, 4, 4))
        col = 0
        for j, p in enumerate(self.parents):
            loc = np.zeros((f, 4, 4))
            loc[:, :3, :3] = np.eye(3)
            loc[:, 3, 3] = 1.0
            loc[:, :3, 3] = self.offsets[j]
            rot = np.broadcast_to(np.eye(3), (f, 3, 3)).copy()
            for ch in self.channels[j]:
                v = fr[:, col]
                col += 1
                kind, axis = ch[1:], _AXES[ch[0].upper()]
                if kind.lower() == "position":
                    loc[:, axis, 3] += v
                else:
                    rot = rot @ _axis_rotation(axis, np.radians(v))
            loc[:, :3, :3] = rot
            glob[:, j] = loc if p < 0 else glob[:, p] @ loc
        return glob


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.zeros(angle.shape + (3, 3))
    i, k = (axis + 1) % 3, (axis + 2) % 3
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., k, k] = c
    r[..., i, k] = -s
    r[..., k, i] = s
    return r


def read_bvh(path) -> BvhMotion:
    """Parse a .bvh file. Raises ``InputFormatError`` naming the file and line for malformed input."""
    path = Path(path)
    if not path.is_file():
        raise InputFormatError(f"{path}: no such BVH file")
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputFormatError(f"{path}: cannot read ({exc})") from None
    names, parents, offsets, ends, channels = [], [], [], [], []
    stack: list[int] = []
    in_end = False
    i = 0
    n_lines = len(lines)

    def err(msg):  # i has moved past the current line: i is its 1-based number
        return InputFormatError(f"{path}: line {i}: {msg}")

    while i < n_lines:
        tok = lines[i].split()
        i += 1
        if not tok:
            continue
        key = tok[0].upper()
        if key == "HIERARCHY":
            continue
        if key in ("ROOT", "JOINT"):
            if len(tok) < 2:
                raise err(f"{tok[0]} without a name")
            names.append(" ".join(tok[1:]))
            parents.append(stack[-1] if stack else -1)
            offsets.append(np.zeros(3))
            ends.append(None)
            channels.append([])
            stack.append(len(names) - 1)
            continue
        if key == "END":
            in_end = True
            continue
        if key == "{":
            continue
        if key == "}":
            if in_end:
                in_end = False
            elif stack:
                stack.pop()
            else:
                raise err("unbalanced '}'")
            continue
        if key == "OFFSET":
            try:
                off = np.array([float(x) for x in tok[1:4]])
            except ValueError:
                raise err(f"OFFSET values {tok[1:4]} are not numbers") from None
            if off.shape != (3,) or not np.isfinite(off).all():
                raise err("OFFSET needs three finite numbers")
            if in_end:
                ends[stack[-1]] = off
            elif stack:
                offsets[stack[-1]] = off
            continue
        if key == "CHANNELS":
            try:
                n = int(tok[1])
            except (IndexError, ValueError):
                raise err("CHANNELS without a count") from None
            chans = tok[2:2 + n]
            for c in chans:
                if len(c) < 2 or c[0].upper() not in _AXES or c[1:].lower() not in ("position", "rotation"):
                    raise err(f"unknown channel '{c}'")
            channels[stack[-1]] = chans
            continue
        if key == "MOTION":
            break
        raise err(f"unexpected '{tok[0]}'")
    if not names:
        raise InputFormatError(f"{path}: no ROOT joint (not a BVH file?)")
    n_frames, frame_time = None, None
    while i < n_lines and (n_frames is None or frame_time is None):
        line = lines[i].strip()
        i += 1
        if line.lower().startswith("frames:"):
            n_frames = int(line.split(":")[1])
        elif line.lower().startswith("frame time:"):
            frame_time = float(line.split(":")[1])
    if n_frames is None or frame_time is None or not frame_time > 0:
        raise InputFormatError(f"{path}: MOTION section lacks 'Frames:' or a positive 'Frame Time:'")
    n_ch = sum(len(c) for c in channels)
    rows = [ln for ln in lines[i:] if ln.strip()]
    if len(rows) < n_frames:
        raise InputFormatError(f"{path}: 'Frames: {n_frames}' but only {len(rows)} frame lines")
    try:
        data = np.array([[float(x) for x in r.split()] for r in rows[:n_frames]], np.float64)
    except ValueError:
        raise InputFormatError(f"{path}: a frame line holds a value that is not a number") from None
    if data.ndim != 2 or data.shape[1] != n_ch:
        bad = next(k for k, r in enumerate(rows[:n_frames]) if len(r.split()) != n_ch)
        raise InputFormatError(f"{path}: frame {bad} has {len(rows[bad].split())} values, the hierarchy has "
                               f"{n_ch} channels")
    if not np.isfinite(data).all():
        raise InputFormatError(f"{path}: frame {int(np.flatnonzero(~np.isfinite(data).all(1))[0])} is not finite")
    return BvhMotion(str(path), names, np.array(parents, np.int64), np.array(offsets), ends, channels, data,
                     float(frame_time))
