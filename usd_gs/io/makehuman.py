"""MakeHuman rig inputs: the base mesh (.obj), its skeleton (.mhskel, JSON) and weights (.mhw, JSON).

Conventions: MakeHuman's base mesh is in decimetres, Y-up, facing +Z, the body's left side
(``.L`` bones) at +X, in an A-pose; :func:`load_makehuman` returns metres (``units`` = 0.1 m per
obj unit), the same axes. Only the skin is kept: faces of the obj group ``body`` (the helper
groups ``helper-*`` and ``joint-*`` are proxies and joint markers, not skin); the vertex array
is the whole obj (the .mhw and .mhskel index it). Quads are split into two triangles.

``.mhskel``: ``joints`` maps a joint name to obj vertex indices (its position is their mean);
``bones`` maps a bone name to ``head``/``tail`` joint names and ``parent``. ``.mhw``: ``weights``
maps a bone name to ``[[vertex, weight], ...]``; each vertex keeps its ``influences`` largest
weights, renormalised to sum to 1 (vertices without weights get the root bone).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from usd_gs.errors import InputFormatError

SKIN_GROUP = "body"


@dataclass
class MakeHumanRig:
    """A MakeHuman mesh with its skeleton and weights (module docstring).

    ``vertices`` (V, 3) float64 metres; ``faces`` (F, 3) int64 skin triangles; ``bones`` (J,)
    names parents first; ``parents`` (J,) int (-1 root); ``heads``/``tails`` (J, 3) metres;
    ``joint_indices`` (V, K) int32 into ``bones``; ``weights`` (V, K) float32, rows sum to 1.
    """

    path: str
    vertices: np.ndarray
    faces: np.ndarray
    bones: list[str]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    joint_indices: np.ndarray
    weights: np.ndarray


def read_obj(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(vertices (V, 3) float64 file units, triangles (F, 3) int64, group name of each triangle)."""
    path = Path(path)
    if not path.is_file():
        raise InputFormatError(f"{path}: no such .obj file")
    verts, faces, groups = [], [], []
    group = ""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                try:
                    idx = [int(t.split("/")[0]) for t in line.split()[1:]]
                except ValueError:
                    raise InputFormatError(f"{path}: line {lineno}: face indices are not integers") from None
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                for k in range(1, len(idx) - 1):
                    faces.append((idx[0], idx[k], idx[k + 1]))
                    groups.append(group)
            elif line.startswith("g "):
                group = line[2:].strip()
    try:
        v = np.array(verts, np.float64)
    except ValueError:
        raise InputFormatError(f"{path}: a vertex line holds a value that is not a number") from None
    f = np.array(faces, np.int64).reshape(-1, 3)
    if v.ndim != 2 or v.shape[1] != 3 or not len(v):
        raise InputFormatError(f"{path}: no vertices")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        bad = int(np.flatnonzero((f < 0).any(1) | (f >= len(v)).any(1))[0])
        raise InputFormatError(f"{path}: face {bad} refers to vertex {int(f[bad].max()) + 1}, the file has {len(v)}")
    return v, f, groups


def _json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise InputFormatError(f"{path}: no such {what} file")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{path}: not valid JSON ({exc})") from None


def load_makehuman(obj_path, skel_path, weights_path, influences: int = 4, units: float = 0.1) -> MakeHumanRig:
    """Read a MakeHuman base mesh, skeleton and weights (module docstring).

    Raises ``InputFormatError`` naming the file and the bone, joint or vertex at fault.
    """
    obj_path, skel_path, weights_path = Path(obj_path), Path(skel_path), Path(weights_path)
    verts, faces, groups = read_obj(obj_path)
    skin = np.array([g == SKIN_GROUP for g in groups], bool)
    if not skin.any():
        raise InputFormatError(f"{obj_path}: no faces in group '{SKIN_GROUP}' (the skin)")
    faces = faces[skin]
    verts = verts * units
    sk = _json(skel_path, ".mhskel")
    if "bones" not in sk or "joints" not in sk:
        raise InputFormatError(f"{skel_path}: needs 'bones' and 'joints'")
    joints = {}
    for name, ix in sk["joints"].items():
        ix = np.asarray(ix, np.int64)
        if ix.size == 0 or ix.min() < 0 or ix.max() >= len(verts):
            raise InputFormatError(f"{skel_path}: joint '{name}' refers to vertices outside the mesh's {len(verts)}")
        joints[name] = verts[ix].mean(axis=0)
    bones_in = sk["bones"]
    order: list[str] = []
    placed: set[str] = set()
    pending = list(bones_in)
    while pending:
        progress = False
        for b in list(pending):
            par = bones_in[b].get("parent")
            if par is None or par in placed:
                order.append(b)
                placed.add(b)
                pending.remove(b)
                progress = True
            elif par not in bones_in:
                raise InputFormatError(f"{skel_path}: bone '{b}' has parent '{par}', which is not a bone")
        if not progress:
            raise InputFormatError(f"{skel_path}: bone '{pending[0]}' is part of a parent cycle")
    index = {b: i for i, b in enumerate(order)}
    parents = np.array([index[bones_in[b]["parent"]] if bones_in[b].get("parent") else -1 for b in order], np.int64)
    heads, tails = np.zeros((len(order), 3)), np.zeros((len(order), 3))
    for i, b in enumerate(order):
        for arr, key in ((heads, "head"), (tails, "tail")):
            jn = bones_in[b].get(key)
            if jn not in joints:
                raise InputFormatError(f"{skel_path}: bone '{b}' {key} joint '{jn}' is not in 'joints'")
            arr[i] = joints[jn]

    wd = _json(weights_path, ".mhw").get("weights")
    if not isinstance(wd, dict):
        raise InputFormatError(f"{weights_path}: needs a 'weights' object")
    rows, cols, vals = [], [], []
    for b, pairs in wd.items():
        if b not in index:
            raise InputFormatError(f"{weights_path}: weights for bone '{b}', which {skel_path.name} does not have")
        a = np.asarray(pairs, np.float64).reshape(-1, 2)
        if a.size and (a[:, 0].min() < 0 or a[:, 0].max() >= len(verts)):
            raise InputFormatError(f"{weights_path}: bone '{b}' weights a vertex outside the mesh's {len(verts)}")
        rows.append(a[:, 0].astype(np.int64))
        cols.append(np.full(len(a), index[b], np.int64))
        vals.append(a[:, 1])
    dense = np.zeros((len(verts), len(order)), np.float64)
    np.add.at(dense, (np.concatenate(rows), np.concatenate(cols)), np.maximum(np.concatenate(vals), 0.0))
    k = int(influences)
    if dense.shape[1] < k:  # fewer bones than influences: pad with zero-weight columns
        dense = np.concatenate([dense, np.zeros((len(verts), k - dense.shape[1]))], axis=1)
    top = np.argsort(-dense, axis=1, kind="stable")[:, :k]
    w = np.take_along_axis(dense, top, axis=1)
    s = w.sum(axis=1, keepdims=True)
    empty = s[:, 0] <= 0
    w = np.where(empty[:, None], np.eye(1, k)[0], w / np.where(s > 0, s, 1.0))
    root = int(np.flatnonzero(parents < 0)[0])
    top = np.where(empty[:, None] | (top >= len(order)), root, top)
    return MakeHumanRig(str(obj_path), verts, faces, order, parents, heads, tails, top.astype(np.int32),
                        w.astype(np.float32))
