"""Minimal glTF 2.0 binary (.glb) reader for one skinned, animated mesh, and its skinning.

numpy plus Pillow for the texture image. Reads:

- the GLB container (12-byte header, JSON chunk, BIN chunk);
- accessors (componentType, type, byteOffset, byteStride, normalized, sparse) and bufferViews;
- the triangle primitives of the first skinned mesh node: POSITION, NORMAL, TEXCOORD_0,
  JOINTS_0, WEIGHTS_0 and indices (several primitives are concatenated);
- the material's base colour texture (embedded PNG or JPEG, decoded with Pillow; an image
  that cannot be decoded leaves ``SkinnedMesh.texture`` None with a note, and the
  ``baseColorFactor`` is used);
- the node hierarchy (TRS or matrix), the skin (joints, inverseBindMatrices, skeleton) and
  the animations (translation / rotation / scale channels; LINEAR, STEP, CUBICSPLINE).

Conventions
-----------
- glTF is right-handed, **Y-up, metres, +Z forward** (the front of an asset faces +Z).
  Everything :func:`pose` returns is in the glTF scene's world space, i.e. already Y-up,
  metres: the transforms of the joints' ancestor nodes (CesiumMan has a ``Z_UP`` root node
  turning its Z-up modelling space into Y-up) are part of every joint's global matrix.
- CesiumMan after :func:`pose`: feet on y ~ 0, head top at 1.44..1.46 m while walking
  (1.51 m in the rest pose), facing +Z, walking in place (no root motion), left side at +X.
- ``SkinnedMesh.rest_vertices`` are the raw POSITION values in the mesh's own space (for
  CesiumMan that space is Z-up: x in [-0.13, 0.18], z in [0, 1.51]).
- Matrices are 4x4 float64 acting on column vectors (``p' = M @ [p, 1]``). glTF stores them
  column-major; this module transposes them on load. (USD's ``Gf.Matrix4d`` is the
  transpose of these, row-vector convention.)
- Quaternions: glTF stores (x, y, z, w); this module converts them on load to the project
  order **(w, x, y, z)** (``usd_gs.gaussians``), normalised.
- Skinning (glTF spec, "Skins"): the skinned mesh node's own transform is ignored; a vertex
  ``v`` becomes ``sum_k w_k * (G[j_k] @ IBM[j_k]) @ v`` with ``G`` the global joint matrices
  and ``IBM`` the inverse bind matrices.
- Animation time is in seconds; sampling before the first / after the last key clamps.
- Colours: ``texture`` and ``base_color`` are LINEAR RGB in [0, 1] (the sRGB transfer
  function of glTF's base colour texture is undone on load).
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from usd_gs.errors import InputFormatError
from usd_gs.gaussians import matrix_to_quaternion, quaternion_to_matrix

_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
    5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4"),
}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942


# --------------------------------------------------------------------------- data types
@dataclass
class AnimationChannel:
    """One animated node property.

    ``path`` is ``"translation"``, ``"rotation"`` or ``"scale"``; ``times`` (K,) float64
    seconds, increasing; ``values`` (K, c) float64 for LINEAR/STEP or (3K, c) ordered
    (in-tangent, value, out-tangent) per key for CUBICSPLINE; rotations are (w, x, y, z).
    """

    node: int
    path: str
    interpolation: str
    times: np.ndarray
    values: np.ndarray


@dataclass
class SkinnedMesh:
    """A skinned triangle mesh with its skeleton and animation (see module docstring).

    Shapes: V vertices, F triangles, J joints, M nodes.

    - ``rest_vertices`` (V, 3) float64, mesh space (the glTF POSITION values).
    - ``faces`` (F, 3) int64 vertex indices, counter-clockwise = front (glTF).
    - ``normals`` (V, 3) float64 unit, mesh space (computed from faces if absent).
    - ``uvs`` (V, 2) float64 glTF UV (origin top-left of the image, v down) or None.
    - ``joints`` (V, 4) int64 indices into the skin's joint list; ``weights`` (V, 4) float64,
      rows sum to 1.
    - ``texture`` (H, W, 3) float32 linear RGB or None; ``base_color`` (3,) linear RGB factor
      (already multiplied into ``texture``).
    - ``joint_nodes`` (J,) node index of each joint; ``inverse_bind_matrices`` (J, 4, 4).
    - ``node_parents`` (M,) parent node index or -1; ``node_translations`` (M, 3),
      ``node_rotations`` (M, 4) (w, x, y, z), ``node_scales`` (M, 3): the rest TRS;
      ``node_matrices`` (M, 4, 4) rest local matrices (== TRS unless the node has a matrix
      with shear); ``node_names`` (M,) list.
    - ``mesh_node`` node carrying the mesh; ``channels`` the animation of the first
      animation (or the one chosen on load); ``duration`` its last key time in seconds
      (0 without animation).
    """

    path: str
    rest_vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray | None
    joints: np.ndarray
    weights: np.ndarray
    texture: np.ndarray | None
    base_color: np.ndarray
    joint_nodes: np.ndarray
    inverse_bind_matrices: np.ndarray
    node_parents: np.ndarray
    node_translations: np.ndarray
    node_rotations: np.ndarray
    node_scales: np.ndarray
    node_matrices: np.ndarray
    node_names: list[str]
    mesh_node: int
    channels: list[AnimationChannel] = field(default_factory=list)
    duration: float = 0.0
    start_time: float = 0.0
    texture_note: str = ""

    @property
    def num_joints(self) -> int:
        return int(self.joint_nodes.shape[0])

    @property
    def joint_names(self) -> list[str]:
        return [self.node_names[i] for i in self.joint_nodes]


# --------------------------------------------------------------------------- GLB container
def _read_glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    if len(data) < 20:
        raise InputFormatError(f"{path}: not a GLB file (only {len(data)} bytes)")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC:
        raise InputFormatError(f"{path}: header magic is {data[:4]!r}, expected b'glTF' (not a .glb file)")
    if version != 2:
        raise InputFormatError(f"{path}: glTF container version {version}, only version 2 is supported")
    if length > len(data):
        raise InputFormatError(f"{path}: header length {length} exceeds the file size {len(data)} (truncated file)")
    doc, binary, off = None, b"", 12
    while off + 8 <= length:
        clen, ctype = struct.unpack_from("<II", data, off)
        if off + 8 + clen > length:
            raise InputFormatError(f"{path}: chunk at byte {off} of length {clen} runs past the end of the file")
        chunk = data[off + 8: off + 8 + clen]
        if ctype == _CHUNK_JSON and doc is None:
            try:
                doc = json.loads(chunk.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise InputFormatError(f"{path}: JSON chunk is not valid JSON ({exc})") from None
        elif ctype == _CHUNK_BIN and not binary:
            binary = chunk
        off += 8 + clen + (-clen % 4)
    if doc is None:
        raise InputFormatError(f"{path}: no JSON chunk")
    return doc, binary


class _Doc:
    """JSON + buffers, with accessor decoding."""

    def __init__(self, path: Path, doc: dict, binary: bytes):
        self.path, self.doc = path, doc
        self.buffers = []
        for i, buf in enumerate(doc.get("buffers", [])):
            uri = buf.get("uri")
            if uri is None:
                self.buffers.append(binary)
            elif uri.startswith("data:"):
                self.buffers.append(base64.b64decode(uri.split(",", 1)[1]))
            else:
                ext = path.parent / uri
                if not ext.is_file():
                    raise InputFormatError(f"{path}: buffers[{i}].uri '{uri}' not found next to the file")
                self.buffers.append(ext.read_bytes())

    def err(self, msg: str) -> InputFormatError:
        return InputFormatError(f"{self.path}: {msg}")

    def view_bytes(self, index: int) -> tuple[np.ndarray, int | None]:
        views = self.doc.get("bufferViews", [])
        if not 0 <= index < len(views):
            raise self.err(f"bufferView index {index} out of range (file has {len(views)})")
        v = views[index]
        buf = self.buffers[v.get("buffer", 0)]
        start, n = v.get("byteOffset", 0), v["byteLength"]
        if start + n > len(buf):
            raise self.err(f"bufferViews[{index}] (offset {start}, length {n}) runs past its buffer ({len(buf)} bytes)")
        return np.frombuffer(buf, np.uint8, n, start), v.get("byteStride")

    def _raw(self, view: int, offset: int, count: int, dtype: np.dtype, ncomp: int, what: str) -> np.ndarray:
        raw, stride = self.view_bytes(view)
        elem = dtype.itemsize * ncomp
        stride = stride or elem
        if count == 0:
            return np.zeros((0, ncomp), dtype)
        need = offset + stride * (count - 1) + elem
        if need > raw.size:
            raise self.err(f"{what}: needs {need} bytes but bufferViews[{view}] has {raw.size}")
        rows = np.lib.stride_tricks.as_strided(raw[offset:], shape=(count, elem), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, ncomp)

    def accessor(self, index: int, what: str = "") -> np.ndarray:
        """Accessor ``index`` as a (count, ncomp) array (float64 if normalised or float)."""
        accs = self.doc.get("accessors", [])
        if not 0 <= index < len(accs):
            raise self.err(f"{what}: accessor index {index} out of range (file has {len(accs)})")
        a = accs[index]
        what = f"accessors[{index}] ({what})" if what else f"accessors[{index}]"
        dtype = _COMPONENT_DTYPES.get(a.get("componentType"))
        ncomp = _TYPE_SIZES.get(a.get("type"))
        if dtype is None or ncomp is None:
            raise self.err(f"{what}: unsupported componentType {a.get('componentType')} / type {a.get('type')}")
        if a["type"] in ("MAT2", "MAT3") and dtype.itemsize < 4:
            raise self.err(f"{what}: {a['type']} with {dtype.itemsize}-byte components (column padding) unsupported")
        count = int(a["count"])
        if "bufferView" in a:
            out = self._raw(a["bufferView"], a.get("byteOffset", 0), count, dtype, ncomp, what).copy()
        else:
            out = np.zeros((count, ncomp), dtype)
        sp = a.get("sparse")
        if sp:
            n = int(sp["count"])
            idt = _COMPONENT_DTYPES[sp["indices"]["componentType"]]
            idx = self._raw(sp["indices"]["bufferView"], sp["indices"].get("byteOffset", 0), n, idt, 1,
                            what + " sparse.indices")[:, 0].astype(np.int64)
            val = self._raw(sp["values"]["bufferView"], sp["values"].get("byteOffset", 0), n, dtype, ncomp,
                            what + " sparse.values")
            if n and (idx.min() < 0 or idx.max() >= count):
                raise self.err(f"{what}: sparse index {int(idx.max())} out of range (count {count})")
            out[idx] = val
        if dtype.kind == "f":
            out = out.astype(np.float64)
            bad = ~np.isfinite(out).all(axis=1)
            if bad.any():
                raise self.err(f"{what}: element {int(np.flatnonzero(bad)[0])} is not finite")
        elif a.get("normalized", False):
            info = np.iinfo(dtype)
            out = np.maximum(out.astype(np.float64) / info.max, -1.0)
        return out


# --------------------------------------------------------------------------- PNG (numpy)
def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1] (float64 in, float64 out)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _decode_image(blob: bytes, mime: str, name: str) -> tuple[np.ndarray | None, str]:
    """(H, W, 3) float64 sRGB-encoded values in [0, 1] decoded with Pillow, or (None, reason)."""
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(blob)) as im:
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                img = np.asarray(im, dtype=np.float64) / 65535.0
                img = np.repeat(img[..., None], 3, axis=2)
            else:
                img = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        return None, f"{name}: {mime or 'image'} could not be decoded ({exc})"
    return img, ""


# --------------------------------------------------------------------------- quaternions
def quat_slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation of (w, x, y, z) quaternions, (..., 4) float64.

    ``u`` broadcasts against the leading shape. Falls back to normalised lerp when the
    quaternions are within ~2.6 degrees (stable near identity).
    """
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    u = np.asarray(u, np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    near = dot > 0.9995
    safe = np.where(near, 1.0, sin_t)
    w0 = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(near, u, np.sin(u * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def trs_matrices(t: np.ndarray, q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(N, 4, 4) float64 ``T @ R @ S`` from (N, 3) translations, (N, 4) (w,x,y,z), (N, 3) scales."""
    t, q, s = (np.asarray(a, np.float64) for a in (t, q, s))
    m = np.zeros((t.shape[0], 4, 4))
    m[:, :3, :3] = quaternion_to_matrix(q) * s[:, None, :]
    m[:, :3, 3] = t
    m[:, 3, 3] = 1.0
    return m


def _decompose(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One 4x4 column-vector matrix -> (t (3,), q (4,) w,x,y,z, s (3,)); shear is dropped."""
    t = m[:3, 3].copy()
    lin = m[:3, :3]
    s = np.linalg.norm(lin, axis=0)
    s = np.where(s > 0, s, 1.0)
    if np.linalg.det(lin) < 0:
        s[0] = -s[0]
    r = lin / s
    u, _, vt = np.linalg.svd(r)
    return t, matrix_to_quaternion((u @ vt)[None])[0], s


# --------------------------------------------------------------------------- loading
def load_skinned_mesh(path, animation: int = 0) -> SkinnedMesh:
    """Read the first skinned mesh node of a .glb file with its skin and ``animation``.

    Raises ``InputFormatError`` (a ``UserError``) naming the file and the offending field
    for a malformed file, a file without a skinned mesh, or non-triangle primitives.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError(f"{path}: file not found")
    try:
        return _load(path, animation)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputFormatError(f"{path}: malformed glTF ({type(exc).__name__}: {exc})") from None


def _load(path: Path, animation: int) -> SkinnedMesh:
    doc = _Doc(path, *_read_glb(path))
    j = doc.doc
    nodes = j.get("nodes", [])
    n_nodes = len(nodes)
    mesh_node = next((i for i, n in enumerate(nodes) if "mesh" in n and "skin" in n), None)
    if mesh_node is None:
        raise doc.err("no node has both 'mesh' and 'skin' (not a skinned mesh)")

    # ---- node hierarchy
    parents = np.full(n_nodes, -1, np.int64)
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            if not 0 <= c < n_nodes or parents[c] != -1:
                raise doc.err(f"nodes[{i}].children: child {c} is out of range or has two parents")
            parents[c] = i
    trans = np.zeros((n_nodes, 3))
    rots = np.tile([1.0, 0.0, 0.0, 0.0], (n_nodes, 1))
    scales = np.ones((n_nodes, 3))
    mats = np.zeros((n_nodes, 4, 4))
    for i, n in enumerate(nodes):
        if "matrix" in n:
            m = np.asarray(n["matrix"], np.float64).reshape(4, 4).T
            if not np.all(np.isfinite(m)):
                raise doc.err(f"nodes[{i}].matrix is not finite")
            mats[i] = m
            trans[i], rots[i], scales[i] = _decompose(m)
        else:
            trans[i] = n.get("translation", [0.0, 0.0, 0.0])
            x, y, z, w = n.get("rotation", [0.0, 0.0, 0.0, 1.0])
            q = np.array([w, x, y, z], np.float64)
            nq = np.linalg.norm(q)
            if not nq > 0:
                raise doc.err(f"nodes[{i}].rotation is a zero quaternion")
            rots[i] = q / nq
            scales[i] = n.get("scale", [1.0, 1.0, 1.0])
            mats[i] = trs_matrices(trans[i:i + 1], rots[i:i + 1], scales[i:i + 1])[0]
    _topological_order(parents, doc)

    # ---- mesh primitives
    mesh = j["meshes"][nodes[mesh_node]["mesh"]]
    pos_l, nrm_l, uv_l, jnt_l, wgt_l, face_l, material = [], [], [], [], [], [], None
    base = 0
    for pi, prim in enumerate(mesh.get("primitives", [])):
        where = f"meshes[{nodes[mesh_node]['mesh']}].primitives[{pi}]"
        if prim.get("mode", 4) != 4:
            raise doc.err(f"{where}.mode is {prim.get('mode')}, only triangles (4) are supported")
        attrs = prim.get("attributes", {})
        for key in ("POSITION", "JOINTS_0", "WEIGHTS_0"):
            if key not in attrs:
                raise doc.err(f"{where}.attributes has no {key}")
        p = doc.accessor(attrs["POSITION"], f"{where} POSITION")
        nv = p.shape[0]
        pos_l.append(p)
        nrm_l.append(doc.accessor(attrs["NORMAL"], f"{where} NORMAL") if "NORMAL" in attrs else None)
        uv_l.append(doc.accessor(attrs["TEXCOORD_0"], f"{where} TEXCOORD_0") if "TEXCOORD_0" in attrs else None)
        jnt_l.append(doc.accessor(attrs["JOINTS_0"], f"{where} JOINTS_0").astype(np.int64))
        wgt_l.append(doc.accessor(attrs["WEIGHTS_0"], f"{where} WEIGHTS_0"))
        if "indices" in prim:
            idx = doc.accessor(prim["indices"], f"{where} indices").astype(np.int64).reshape(-1)
        else:
            idx = np.arange(nv, dtype=np.int64)
        if idx.size % 3:
            raise doc.err(f"{where}.indices: {idx.size} indices is not a multiple of 3")
        if idx.size and (idx.min() < 0 or idx.max() >= nv):
            bad = int(np.flatnonzero((idx < 0) | (idx >= nv))[0])
            raise doc.err(f"{where}.indices element {bad} = {int(idx[bad])} out of range (0..{nv - 1})")
        face_l.append(idx.reshape(-1, 3) + base)
        base += nv
        if material is None and "material" in prim:
            material = prim["material"]
    if not pos_l:
        raise doc.err(f"meshes[{nodes[mesh_node]['mesh']}] has no primitives")
    verts = np.concatenate(pos_l)
    faces = np.concatenate(face_l)
    if any(n is None for n in nrm_l):
        normals = vertex_normals(verts, faces)
    else:
        normals = np.concatenate(nrm_l)
        ln = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = normals / np.where(ln > 0, ln, 1.0)
    uvs = None if any(u is None for u in uv_l) else np.concatenate(uv_l)
    joints = np.concatenate(jnt_l)
    weights = np.concatenate(wgt_l)
    wsum = weights.sum(axis=1, keepdims=True)
    if np.any(weights < 0) or np.any(wsum <= 0):
        bad = int(np.flatnonzero((weights < 0).any(axis=1) | (wsum[:, 0] <= 0))[0])
        raise doc.err(f"WEIGHTS_0 element {bad} = {weights[bad].tolist()} (negative or all zero)")
    weights = weights / wsum

    # ---- skin
    skin_i = nodes[mesh_node]["skin"]
    skin = j["skins"][skin_i]
    joint_nodes = np.asarray(skin["joints"], np.int64)
    nj = joint_nodes.size
    if nj == 0 or joint_nodes.min() < 0 or joint_nodes.max() >= n_nodes:
        raise doc.err(f"skins[{skin_i}].joints must be non-empty node indices < {n_nodes}")
    if joints.max(initial=0) >= nj:
        bad = int(np.flatnonzero((joints >= nj).any(axis=1))[0])
        raise doc.err(f"JOINTS_0 element {bad} = {joints[bad].tolist()} refers past the {nj} joints of the skin")
    if "inverseBindMatrices" in skin:
        ibm = doc.accessor(skin["inverseBindMatrices"], f"skins[{skin_i}].inverseBindMatrices")
        if ibm.shape != (nj, 16):
            raise doc.err(f"skins[{skin_i}].inverseBindMatrices has shape {ibm.shape}, expected ({nj}, 16)")
        ibm = ibm.reshape(nj, 4, 4).transpose(0, 2, 1).copy()
    else:
        ibm = np.tile(np.eye(4), (nj, 1, 1))

    # ---- material / texture
    base_color = np.ones(3)
    texture, note = None, "no base colour texture"
    if material is not None:
        pbr = j["materials"][material].get("pbrMetallicRoughness", {})
        base_color = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3], np.float64)
        tex_ref = pbr.get("baseColorTexture")
        if tex_ref is not None:
            src = j["textures"][tex_ref["index"]].get("source")
            img = j["images"][src] if src is not None else None
            if img is not None:
                name = f"{path}: images[{src}]"
                if "bufferView" in img:
                    raw, _ = doc.view_bytes(img["bufferView"])
                    blob = raw.tobytes()
                elif img.get("uri", "").startswith("data:"):
                    blob = base64.b64decode(img["uri"].split(",", 1)[1])
                else:
                    f = path.parent / img.get("uri", "")
                    blob = f.read_bytes() if f.is_file() else b""
                enc, note = _decode_image(blob, img.get("mimeType", ""), name) if blob else (None, f"{name}: missing")
                if enc is not None:
                    texture = (srgb_to_linear(enc) * base_color).astype(np.float32)
                    note = ""

    # ---- animation
    channels, duration, start = [], 0.0, 0.0
    anims = j.get("animations", [])
    if anims:
        if not 0 <= animation < len(anims):
            raise doc.err(f"animation index {animation} out of range (file has {len(anims)})")
        anim = anims[animation]
        for ci, ch in enumerate(anim.get("channels", [])):
            tgt = ch.get("target", {})
            pth = tgt.get("path")
            if pth not in ("translation", "rotation", "scale") or "node" not in tgt:
                continue  # morph-target weights / pointer extensions are not needed here
            smp = anim["samplers"][ch["sampler"]]
            interp = smp.get("interpolation", "LINEAR")
            if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise doc.err(f"animations[{animation}].samplers[{ch['sampler']}].interpolation '{interp}' unknown")
            times = doc.accessor(smp["input"], f"animation channel {ci} input")[:, 0]
            vals = doc.accessor(smp["output"], f"animation channel {ci} output")
            if times.size == 0 or np.any(np.diff(times) <= 0):
                raise doc.err(f"animations[{animation}].channels[{ci}]: key times are empty or not increasing")
            per_key = 3 if interp == "CUBICSPLINE" else 1
            if vals.shape[0] != per_key * times.size:
                raise doc.err(f"animations[{animation}].channels[{ci}]: {vals.shape[0]} output values for "
                              f"{times.size} keys ({interp})")
            if pth == "rotation":
                vals = vals[:, [3, 0, 1, 2]]
                zero = np.linalg.norm(vals, axis=1) == 0
                if interp != "CUBICSPLINE" and zero.any():
                    raise doc.err(f"animations[{animation}].channels[{ci}]: rotation key {int(np.argmax(zero))} "
                                  "is a zero quaternion")
            channels.append(AnimationChannel(int(tgt["node"]), pth, interp, times, vals))
        if channels:
            duration = float(max(c.times[-1] for c in channels))
            start = float(min(c.times[0] for c in channels))
    return SkinnedMesh(
        path=str(path), rest_vertices=verts, faces=faces, normals=normals, uvs=uvs, joints=joints,
        weights=weights, texture=texture, base_color=base_color, joint_nodes=joint_nodes,
        inverse_bind_matrices=ibm, node_parents=parents, node_translations=trans, node_rotations=rots,
        node_scales=scales, node_matrices=mats, node_names=[n.get("name", f"node{i}") for i, n in enumerate(nodes)],
        mesh_node=int(mesh_node), channels=channels, duration=duration, start_time=start, texture_note=note)


def _topological_order(parents: np.ndarray, doc: _Doc | None = None) -> np.ndarray:
    """Node indices ordered so every parent precedes its children; raises on a cycle."""
    n = parents.size
    depth = np.full(n, -1, np.int64)
    for i in range(n):
        chain, k = [], i
        while k != -1 and depth[k] < 0:
            if k in chain or len(chain) > n:
                msg = f"node hierarchy has a cycle through node {k}"
                raise doc.err(msg) if doc is not None else InputFormatError(msg)
            chain.append(k)
            k = parents[k]
        d = -1 if k == -1 else depth[k]
        for c in reversed(chain):
            d += 1
            depth[c] = d
    return np.argsort(depth, kind="stable")


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float64 unit area-weighted vertex normals (counter-clockwise faces = front)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), np.array([0.0, 1.0, 0.0]))


# --------------------------------------------------------------------------- animation
def loop_period(mesh: SkinnedMesh) -> float:
    """Seconds after which a looped animation repeats: the key range plus one key interval.

    glTF has no loop flag; a walk cycle exported from a DCC tool (CesiumMan: 48 keys at
    1/24 s from t = 1/24 to t = 2) ends one key interval before it starts again, so the
    looped clip goes last key -> first key over one (median) key interval.
    """
    if not mesh.channels:
        return 0.0
    steps = np.concatenate([np.diff(c.times) for c in mesh.channels])
    gap = float(np.median(steps)) if steps.size else 0.0
    return mesh.duration - mesh.start_time + gap


def sample_channel(ch: AnimationChannel, t: float, period: float | None = None) -> np.ndarray:
    """Value of ``ch`` at time ``t`` seconds; (c,) float64.

    Without ``period`` the time is clamped to the key range. With ``period`` (seconds, see
    :func:`loop_period`) the channel repeats with that period from its first key, and
    between its last key and the first key of the next cycle it interpolates linearly
    (rotations: slerp) from the last to the first key value.
    """
    times, vals = ch.times, ch.values
    k = times.size
    cubic = ch.interpolation == "CUBICSPLINE"

    def key(i):
        return vals[3 * i + 1] if cubic else vals[i]

    if period is not None and period > 0:
        t = times[0] + float(np.mod(t - times[0], period))
        end = times[0] + period
        if t > times[-1] and end > times[-1]:
            u = (t - times[-1]) / (end - times[-1])
            if ch.interpolation == "STEP":
                return np.asarray(key(k - 1), np.float64)
            if ch.path == "rotation":
                return quat_slerp(key(k - 1), key(0), u)
            return (1.0 - u) * key(k - 1) + u * key(0)
    if k == 1 or t <= times[0]:
        out = key(0)
    elif t >= times[-1]:
        out = key(k - 1)
    else:
        i = int(np.searchsorted(times, t, side="right")) - 1
        i = min(max(i, 0), k - 2)
        dt = times[i + 1] - times[i]
        u = (t - times[i]) / dt
        if ch.interpolation == "STEP":
            out = key(i)
        elif cubic:
            p0, m0 = vals[3 * i + 1], vals[3 * i + 2] * dt
            p1, m1 = vals[3 * (i + 1) + 1], vals[3 * (i + 1)] * dt
            u2, u3 = u * u, u * u * u
            out = ((2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * m0
                   + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * m1)
        elif ch.path == "rotation":
            out = quat_slerp(key(i), key(i + 1), u)
        else:
            out = (1.0 - u) * key(i) + u * key(i + 1)
    if ch.path == "rotation":
        out = out / np.linalg.norm(out)
    return np.asarray(out, np.float64)


def node_global_matrices(mesh: SkinnedMesh, t: float | None, loop: bool = False) -> np.ndarray:
    """(M, 4, 4) world matrices of all nodes at time ``t`` seconds (None: the rest TRS).

    ``loop``: repeat the animation with :func:`loop_period` instead of clamping.
    """
    local = mesh.node_matrices.copy()
    period = loop_period(mesh) if loop else None
    if t is not None and mesh.channels:
        trs = {}
        for ch in mesh.channels:
            n = ch.node
            if n not in trs:
                trs[n] = [mesh.node_translations[n].copy(), mesh.node_rotations[n].copy(), mesh.node_scales[n].copy()]
            slot = {"translation": 0, "rotation": 1, "scale": 2}[ch.path]
            trs[n][slot] = sample_channel(ch, float(t), period)
        if trs:
            ids = np.fromiter(trs, np.int64)
            local[ids] = trs_matrices(np.array([trs[i][0] for i in ids]), np.array([trs[i][1] for i in ids]),
                                      np.array([trs[i][2] for i in ids]))
    glob = np.empty_like(local)
    for n in _topological_order(mesh.node_parents):
        p = mesh.node_parents[n]
        glob[n] = local[n] if p < 0 else glob[p] @ local[n]
    return glob


def skin_matrices(mesh: SkinnedMesh, t: float | None, loop: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(joint world matrices (J, 4, 4), skinning matrices ``G @ IBM`` (J, 4, 4)) at ``t``."""
    g = node_global_matrices(mesh, t, loop)[mesh.joint_nodes]
    return g, g @ mesh.inverse_bind_matrices


def pose(mesh: SkinnedMesh, t_seconds: float | None, loop: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear-blend-skinned vertices at time ``t_seconds`` (None: the skeleton's rest TRS).

    ``loop=False`` clamps ``t`` to the key range; ``loop=True`` repeats the clip with
    period :func:`loop_period` (seamless for a cyclic clip such as CesiumMan's walk).

    Returns ``(vertices (V, 3), normals (V, 3) unit, joint world matrices (J, 4, 4))``,
    float64, glTF world space (Y-up, metres). Each vertex uses the weight-blended matrix
    ``B = sum_k w_k * G[j_k] @ IBM[j_k]``; normals use ``inverse(B[:3, :3]).T``.
    """
    joint_world, skin = skin_matrices(mesh, t_seconds, loop)
    return (*skin_vertices(skin, mesh.joints, mesh.weights, mesh.rest_vertices, mesh.normals), joint_world)


def skin_vertices(skin: np.ndarray, joints: np.ndarray, weights: np.ndarray, vertices: np.ndarray,
                  normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """LBS of (V, 3) ``vertices`` (and optional normals) by (J, 4, 4) ``skin`` matrices."""
    blend = np.einsum("vk,vkij->vij", weights, skin[joints])
    out = np.einsum("vij,vj->vi", blend[:, :3, :3], vertices) + blend[:, :3, 3]
    if normals is None:
        return out, None
    lin = blend[:, :3, :3]
    cof = _cofactor(lin)  # det * inverse-transpose; multiplying by sign(det) keeps the orientation
    det = np.einsum("vi,vi->v", lin[:, :, 0], cof[:, :, 0])
    n = np.einsum("vij,vj->vi", cof, normals) * np.where(det < 0, -1.0, 1.0)[:, None]
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    return out, n / np.where(ln > 0, ln, 1.0)


def _cofactor(a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cofactor matrices ``det(A) * inv(A).T`` (defined for singular A too)."""
    c0, c1, c2 = a[:, :, 0], a[:, :, 1], a[:, :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=2)
