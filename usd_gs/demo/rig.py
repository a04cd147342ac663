"""Bind a captured Gaussian avatar to a skeleton (``usdgs rig``): alignment, weight transfer,
Skeleton / SkelAnimation / bound Gaussian prim (``usd_gs.usd.skel``).

Rig space (everything this module returns and writes): metres, Y-up, the body facing +Z, its
left side at +X, feet at y = 0, centred on the Y axis. Matrices are 4x4 float64 in the
COLUMN-vector convention (``p' = M @ [p, 1]``); the USD files get their transposes.

Skin sources (:class:`RigSource`):

- MakeHuman (``.obj`` + ``.mhskel`` + ``.mhw``, ``usd_gs.io.makehuman``): the A-posed base mesh is
  first posed into a T-pose (each arm's upper and lower segment turned horizontal by linear
  blend skinning with the mesh's own weights), which becomes the bind pose; every joint's bind
  frame is a pure translation to its bone head (joint orientations carry no meaning here).
- glTF (``.glb``, ``usd_gs.io.gltf``): bound at the skeleton's rest pose (bind matrices = the
  joints' rest world matrices, bind mesh = the rest-posed mesh), joints reordered parents first.

Alignment (:func:`align_to_mesh`): the Gaussians' up axis is turned to +Y, their facing to +Z
(auto: the toes point forward, detected from the lowest 4 % of the centres), uniform scale from
the robust height (0.2 / 99.8 percentiles), feet and horizontal centre matched, then a few
similarity ICP iterations against the closest surface points (outliers beyond 3 median distances
ignored), and a last vertical shift that puts the robust bottom (0.2 percentile) of the centres
on the skin's lowest point (the fit pairs shoes and clothes with the bare skin and tends to lift
the capture). An explicit matrix replaces all of it.

Weight transfer (:func:`transfer_weights`): closest point on the skin (candidates: the 12 nearest
triangle centroids and the faces of the nearest vertex, exact point-triangle distances from
``trimesh.triangles.closest_point``), barycentric blend of the triangle's vertex weights, kept
to the ``influences`` largest and renormalised; centres farther than ``max_distance`` take the
nearest skin vertex's weights (vertices that no skin face uses are ignored) and are counted.

Motion: a BVH (``usd_gs.io.bvh``) retargeted by joint names (:func:`retarget_bvh`) or the glTF's
own animation. trimesh and scipy are imported inside the functions that use them.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel

from usd_gs.demo.mesh_avatar import (
    AVATAR_INSET,
    AVATAR_SIGMA_FACTOR,
    face_areas,
    gaussians_on_mesh,
    sample_colors,
    sample_surface,
)
from usd_gs.errors import GaussianDataError, UserError
from usd_gs.gaussians import GaussianSet, matrix_to_quaternion
from usd_gs.io.bvh import read_bvh
from usd_gs.io.gltf import load_skinned_mesh, loop_period, node_global_matrices, pose
from usd_gs.io.makehuman import load_makehuman
from usd_gs.io.ply import read_ply
from usd_gs.usd import skel as uskel
from usd_gs.usd.gaussian_prim import (
    find_gaussian_prims,
    new_stage,
    read_gaussian_prim,
    save_stage_atomic,
    write_gaussian_prim,
)
from usd_gs.usd.schema import apply_role

FPS = 24.0

#: BVH joint -> MakeHuman default skeleton bone, for MakeHuman's own BVH walks (``Root``, ``Spine1``, ...)
MAP_MAKEHUMAN_BVH = {
    "Root": "root", "Spine1": "spine04", "Spine2": "spine02", "Spine3": "spine01", "Neck": "neck01",
    "Head": "head",
    **{f"{a}_{s}": f"{b}.{s}" for s in "LR" for a, b in (
        ("Clavicle", "clavicle"), ("UpArm", "upperarm01"), ("LoArm", "lowerarm01"), ("Hand", "wrist"),
        ("UpLeg", "upperleg01"), ("LoLeg", "lowerleg01"), ("Foot", "foot"))},
}
#: BVH joint -> MakeHuman default skeleton bone, for CMU-style BVH (``Hips``, ``LeftHip``, ...)
MAP_CMU_BVH = {
    "Hips": "root", "lowerback": "spine04", "Chest": "spine02", "Chest2": "spine01", "lowerneck": "neck01",
    "Neck": "neck03", "Head": "head",
    **{f"{side}{a}": f"{b}.{s}" for side, s in (("Left", "L"), ("Right", "R")) for a, b in (
        ("Collar", "clavicle"), ("Shoulder", "upperarm01"), ("Elbow", "lowerarm01"), ("Wrist", "wrist"),
        ("Hip", "upperleg01"), ("Knee", "lowerleg01"), ("Ankle", "foot"))},
}
BUILTIN_MAPS = {"makehuman": MAP_MAKEHUMAN_BVH, "cmu": MAP_CMU_BVH}


@dataclass
class RigSource:
    """A skinned mesh in rig space, bound (module docstring).

    ``vertices`` (V, 3) bind-pose skin; ``faces`` (F, 3); ``joint_indices``/``weights`` (V, K);
    ``names`` (J,) source joint names; ``parents`` (J,) parents first; ``bind`` (J, 4, 4) bind
    world matrices; ``rest_local`` (J, 4, 4) parent-relative rest; ``heads``/``tails`` (J, 3) bone
    ends in the bind pose (tails give the bone directions retargeting aligns).
    ``local_frames`` optional (T, J, 4, 4) parent-relative animation with ``times`` (T,) seconds.
    """

    path: str
    vertices: np.ndarray
    faces: np.ndarray
    joint_indices: np.ndarray
    weights: np.ndarray
    names: list[str]
    parents: np.ndarray
    bind: np.ndarray
    rest_local: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    local_frames: np.ndarray | None = None
    times: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def joint_paths(self) -> list[str]:
        """UsdSkel joint paths (``root/spine05/...``) of sanitised names."""
        clean = [re.sub(r"[^A-Za-z0-9_]", "_", n) or "joint" for n in self.names]
        clean = [("_" + c) if c[0].isdigit() else c for c in clean]
        seen: dict[str, int] = {}
        uniq = []
        for c in clean:
            k = seen.get(c, 0)
            seen[c] = k + 1
            uniq.append(c if k == 0 else f"{c}_{k}")
        paths: list[str] = []
        for j, p in enumerate(self.parents):
            paths.append(uniq[j] if p < 0 else f"{paths[p]}/{uniq[j]}")
        return paths


# ----------------------------------------------------------------------------- small math
def _translate(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def rotation_between(a, b) -> np.ndarray:
    """3x3 minimal rotation taking direction ``a`` to direction ``b``."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-12:
        axis = np.eye(3)[np.argmin(np.abs(a))]
        axis = np.cross(a, axis)
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _forward_kinematics(parents, rest_local, local_rot=None) -> np.ndarray:
    """(J, 4, 4) globals from parent-relative rest matrices, optionally right-multiplied by a
    local rotation (J, 3, 3) per joint."""
    g = np.zeros_like(rest_local)
    for j, p in enumerate(parents):
        loc = rest_local[j].copy()
        if local_rot is not None:
            loc[:3, :3] = loc[:3, :3] @ local_rot[j]
        g[j] = loc if p < 0 else g[p] @ loc
    return g


def lbs(vertices, joint_indices, weights, skin) -> np.ndarray:
    """(V, 3) linear blend skinning by (J, 4, 4) column-vector skinning matrices."""
    blend = np.einsum("vk,vkij->vij", weights.astype(np.float64), skin[joint_indices])
    return np.einsum("vij,vj->vi", blend[:, :3, :3], vertices) + blend[:, :3, 3]


# ----------------------------------------------------------------------------- sources
def makehuman_source(obj, mhskel, mhw, tpose: bool = True, influences: int = 4) -> RigSource:
    """A :class:`RigSource` from MakeHuman files (module docstring); ``tpose`` poses the arms horizontal."""

    mh = load_makehuman(obj, mhskel, mhw, influences=influences)
    used = np.unique(mh.faces)
    lo, hi = mh.vertices[used].min(axis=0), mh.vertices[used].max(axis=0)
    shift = -np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    verts, heads, tails = mh.vertices + shift, mh.heads + shift, mh.tails + shift
    parents = mh.parents
    nj = len(mh.bones)
    bind = np.stack([_translate(h) for h in heads])
    rest_local = np.stack([bind[j] if p < 0 else _translate(heads[j] - heads[p]) for j, p in enumerate(parents)])
    notes = []
    if tpose:
        index = {b: i for i, b in enumerate(mh.bones)}
        local_rot = np.broadcast_to(np.eye(3), (nj, 3, 3)).copy()
        for side, sign in (("L", 1.0), ("R", -1.0)):
            names = [f"upperarm01.{side}", f"lowerarm01.{side}", f"wrist.{side}"]
            if not all(n in index for n in names):
                continue
            ua, la, wr = (index[n] for n in names)
            target = np.array([sign, 0.0, 0.0])
            local_rot[ua] = rotation_between(heads[la] - heads[ua], target)
            g = _forward_kinematics(parents, rest_local, local_rot)
            fore = g[la][:3, :3] @ (heads[wr] - heads[la])  # forearm direction after the upper-arm turn
            par = g[parents[la]][:3, :3]
            local_rot[la] = par.T @ rotation_between(fore, target) @ par
        glob = _forward_kinematics(parents, rest_local, local_rot)
        skin = glob @ np.linalg.inv(bind)
        verts = lbs(verts, mh.joint_indices, mh.weights, skin)
        new_heads = glob[:, :3, 3].copy()
        tails = np.einsum("jab,jb->ja", glob[:, :3, :3], tails - heads) + new_heads
        heads = new_heads
        bind = np.stack([_translate(h) for h in heads])
        rest_local = np.stack([bind[j] if p < 0 else _translate(heads[j] - heads[p])
                               for j, p in enumerate(parents)])
        # feet back on the floor after posing (the arms do not touch it; no-op in practice)
        notes.append("MakeHuman mesh posed into a T-pose (arms horizontal) as the bind pose")
    return RigSource(str(obj), verts, mh.faces, mh.joint_indices, mh.weights, list(mh.bones), parents, bind,
                     rest_local, heads, tails, notes=notes)


def _gltf_joint_order(mesh) -> tuple[list[int], np.ndarray, np.ndarray]:
    """(order: skin joint indices, parents first; new_index (J,): the position of each skin joint in
    that order; parents (J,) int64 in that order, -1 for a root)
    of a ``usd_gs.io.gltf.SkinnedMesh``: the parent of a joint is its nearest ancestor node that is
    a joint."""
    nodes = mesh.joint_nodes
    node_to_joint = {int(n): j for j, n in enumerate(nodes)}
    jparent = []
    for n in nodes:
        p = int(mesh.node_parents[n])
        while p >= 0 and p not in node_to_joint:
            p = int(mesh.node_parents[p])
        jparent.append(node_to_joint.get(p, -1))
    order: list[int] = []
    placed: set[int] = set()
    while len(order) < len(nodes):
        for j in range(len(nodes)):
            if j not in placed and (jparent[j] < 0 or jparent[j] in placed):
                order.append(j)
                placed.add(j)
    new_index = np.empty(len(nodes), np.int64)
    new_index[order] = np.arange(len(order))
    return order, new_index, np.array([new_index[jparent[j]] if jparent[j] >= 0 else -1 for j in order], np.int64)


def gltf_source(path, fps: float = FPS) -> RigSource:
    """A :class:`RigSource` from a skinned .glb, bound at its rest pose, with its animation sampled
    at ``fps`` over one loop (``usd_gs.io.gltf``)."""

    mesh = load_skinned_mesh(path)
    nodes = mesh.joint_nodes
    order, new_index, parents = _gltf_joint_order(mesh)
    names = [mesh.node_names[nodes[j]] or f"joint{j}" for j in order]

    def globals_at(t):
        return node_global_matrices(mesh, t, loop=True)[nodes[order]]

    rest_g = globals_at(None)
    rest_local = _locals(rest_g, parents)
    verts = pose(mesh, None)[0]
    heads = rest_g[:, :3, 3].copy()
    tails = heads.copy()
    for j in range(len(order)):
        kids = np.flatnonzero(parents == j)
        if kids.size:
            tails[j] = heads[kids].mean(axis=0)
        elif parents[j] >= 0:
            tails[j] = heads[j] + 0.3 * (heads[j] - heads[parents[j]])
    src = RigSource(str(path), verts, mesh.faces, new_index[mesh.joints].astype(np.int32),
                    mesh.weights.astype(np.float32), names, parents, rest_g, rest_local, heads, tails)
    if mesh.channels:
        period = loop_period(mesh)
        n = max(1, int(round(period * fps))) if period > 0 else 1
        times = np.arange(n) / fps
        src.local_frames = np.stack([_locals(globals_at(float(t)), parents) for t in times])
        src.times = times
    return src


def _locals(glob: np.ndarray, parents: np.ndarray) -> np.ndarray:
    out = glob.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            out[j] = np.linalg.inv(glob[p]) @ glob[j]
    return out


def load_source(skin, skeleton=None, weights=None, tpose: bool = True) -> RigSource:
    """:func:`gltf_source` for a .glb, :func:`makehuman_source` for an .obj (with ``skeleton``
    .mhskel and ``weights`` .mhw; defaults: ``<stem>.mhskel`` / ``<stem>_weights.mhw`` beside it)."""
    skin = Path(skin)
    ext = skin.suffix.lower()
    if ext in (".glb", ".gltf"):
        return gltf_source(skin)
    if ext == ".obj":
        if skeleton is None or weights is None:
            raise UserError(f"{skin}: a MakeHuman .obj needs --skeleton FILE.mhskel and --weights FILE.mhw")
        return makehuman_source(skin, skeleton, weights, tpose=tpose)
    raise UserError(f"{skin}: --skin must be a skinned .glb or a MakeHuman .obj, not '{ext}'")


# ----------------------------------------------------------------------------- alignment
_UP = {"+y": (1, 1.0), "-y": (1, -1.0), "+z": (2, 1.0), "-z": (2, -1.0), "+x": (0, 1.0), "-x": (0, -1.0)}


def _up_rotation(up: str) -> np.ndarray:
    if up.lower() not in _UP:
        raise UserError(f"--up must be one of {', '.join(_UP)}, not '{up}'")
    axis, sign = _UP[up.lower()]
    return rotation_between(sign * np.eye(3)[axis], [0.0, 1.0, 0.0])


def facing_direction(points: np.ndarray) -> np.ndarray:
    """Unit horizontal direction (+-X or +-Z) a standing Y-up body faces: the horizontal axis of
    the smaller robust extent (the arm span of a T-pose is the larger one), its sign from where the
    feet (lowest 4 % of the height) stick out relative to the ankles (4-10 %); +Z when undecided."""
    y = points[:, 1]
    lo, hi = _robust_box(points)
    h = hi[1] - lo[1]
    axis = 0 if (hi[0] - lo[0]) < (hi[2] - lo[2]) else 2
    feet = points[y < lo[1] + 0.04 * h]
    ankles = points[(y >= lo[1] + 0.04 * h) & (y < lo[1] + 0.10 * h)]
    out = np.zeros(3)
    out[axis] = 1.0
    if len(feet) >= 10 and len(ankles) >= 10:
        d = np.median(feet[:, axis]) - np.median(ankles[:, axis])
        if d < 0:
            out[axis] = -1.0
    return out


def _robust_box(p: np.ndarray):
    return np.percentile(p, 0.2, axis=0), np.percentile(p, 99.8, axis=0)


def _umeyama(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """4x4 similarity minimising |s R src + t - dst|^2 (Umeyama 1991)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    cov = b.T @ a / len(src)
    u, d, vt = np.linalg.svd(cov)
    sgn = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2, 2] = -1
    r = u @ sgn @ vt
    var = np.mean(np.sum(a * a, axis=1))
    s = float(np.trace(np.diag(d) @ sgn) / var)
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = md - s * r @ ms
    return m


def align_to_mesh(gs: GaussianSet, vertices: np.ndarray, up: str = "+y", facing: str = "auto",
                  icp_iterations: int = 10, seed: int = 0, faces: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """4x4 similarity (column-vector) taking the Gaussian centres onto the skin (rig space), and a
    report dict (scale, facing, median distance in metres). ICP pairs each centre with its closest
    point on the triangles ``faces`` of ``vertices`` (with the nearest vertex when ``faces`` is
    None). See module docstring."""
    p = gs.positions.astype(np.float64)
    keep = gs.opacities > 0.3
    if keep.sum() >= 100:
        p = p[keep]
    r_up = _up_rotation(up)
    q = p @ r_up.T
    if facing == "auto":
        f = facing_direction(q)
    else:
        if facing.lower() not in _UP or _UP[facing.lower()][0] == 1:
            raise UserError(f"--facing must be auto, +z, -z, +x or -x, not '{facing}'")
        axis, sign = _UP[facing.lower()]
        f = sign * np.eye(3)[axis]
    r_face = rotation_between(f, [0.0, 0.0, 1.0]) if abs(f[2] + 1) > 1e-9 else np.diag([-1.0, 1.0, -1.0])
    rot = r_face @ r_up
    q = p @ rot.T
    qlo, qhi = _robust_box(q)
    vlo, vhi = vertices.min(axis=0), vertices.max(axis=0)
    s = (vhi[1] - vlo[1]) / max(qhi[1] - qlo[1], 1e-12)
    m = np.eye(4)
    m[:3, :3] = s * rot
    qc = np.array([(qlo[0] + qhi[0]) / 2, qlo[1], (qlo[2] + qhi[2]) / 2]) * s
    vc = np.array([(vlo[0] + vhi[0]) / 2, vlo[1], (vlo[2] + vhi[2]) / 2])
    m[:3, 3] = vc - qc
    rng = np.random.default_rng(seed)
    sample = p[rng.choice(len(p), size=min(len(p), 3000), replace=False)]

    if faces is None:
        from scipy.spatial import cKDTree

        vtree = cKDTree(vertices)
    else:
        surface = SurfaceQuery(vertices, faces)

    def closest(x):
        if faces is None:
            dist, idx = vtree.query(x)
            return vertices[idx], dist
        face, bary, dist = surface.query(x)
        return np.einsum("nk,nkd->nd", bary, vertices[faces[face]]), dist

    for _ in range(max(0, icp_iterations)):
        x = sample @ m[:3, :3].T + m[:3, 3]
        target, dist = closest(x)
        ok = dist < 3 * np.median(dist) + 1e-9
        step = _umeyama(x[ok], target[ok])
        m = step @ m
        if np.abs(step - np.eye(4)).max() < 1e-6:  # converged (sub-micrometre update)
            break
    # feet on the floor: the fit pairs shoes and clothes with the bare skin and may lift the capture
    y = (p @ m[:3, :3].T + m[:3, 3])[:, 1]
    m[1, 3] -= np.percentile(y, 0.2) - vertices[:, 1].min() if faces is None else \
        np.percentile(y, 0.2) - vertices[np.unique(faces), 1].min()
    resid = float(np.median(closest(sample @ m[:3, :3].T + m[:3, 3])[1]))
    scale = float(abs(np.linalg.det(m[:3, :3])) ** (1 / 3))
    return m, {"scale": scale, "facing": f.tolist(), "median_distance_m": resid}


def parse_matrix(text: str) -> np.ndarray:
    """A 4x4 column-vector matrix from 16 comma/space-separated numbers (row-major) or a
    ``.json`` file holding a 4x4 list."""
    t = text.strip()
    if t.endswith(".json") and Path(t).is_file():
        vals = np.asarray(json.loads(Path(t).read_text()), np.float64).reshape(-1)
    else:
        try:
            vals = np.array([float(v) for v in re.split(r"[,\s]+", t) if v], np.float64)
        except ValueError:
            raise UserError(f"--align-matrix '{text}': not 16 numbers") from None
    if vals.size != 16 or not np.isfinite(vals).all():
        raise UserError(f"--align-matrix '{text}': needs 16 finite numbers (row-major 4x4), got {vals.size}")
    return vals.reshape(4, 4)


# ----------------------------------------------------------------------------- weights
class SurfaceQuery:
    """Closest points on a triangle mesh (module docstring): KD-trees of the triangle centroids and
    of the skin vertices, built once; exact point-triangle distances by ``trimesh``."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from scipy.spatial import cKDTree

        self.vertices, self.faces = vertices, faces
        self.tri = vertices[faces]
        self.centroids = cKDTree(self.tri.mean(axis=1))
        self.used = np.unique(faces)  # vertices no face uses (helper geometry) are ignored
        self.vtree = cKDTree(vertices[self.used])
        self.vertex_faces = _vertex_faces(len(vertices), faces)

    def query(self, points: np.ndarray):
        """(face index (N,), barycentrics (N, 3), distance (N,)) of each point's closest surface point."""
        import trimesh

        tri, faces = self.tri, self.faces
        k = min(12, len(faces))
        _, cand = self.centroids.query(points, k=k)
        cand = cand.reshape(len(points), -1)
        _, nv = self.vtree.query(points)
        cand = np.concatenate([cand, self.vertex_faces[self.used[nv]]], axis=1)
        n, c = cand.shape
        flat = cand.reshape(-1)
        rep = np.repeat(points, c, axis=0)
        out = np.empty((n, 3))
        best = np.empty(n, np.int64)
        dist = np.empty(n)
        step = max(1, 400000 // c)
        for a in range(0, n, step):
            sl = slice(a * c, min(n, a + step) * c)
            cp = trimesh.triangles.closest_point(tri[flat[sl]], rep[sl])
            d = np.linalg.norm(cp - rep[sl], axis=1).reshape(-1, c)
            arg = np.argmin(d, axis=1)
            rows = np.arange(d.shape[0])
            best[a:a + d.shape[0]] = cand[a:a + d.shape[0]][rows, arg]
            dist[a:a + d.shape[0]] = d[rows, arg]
            out[a:a + d.shape[0]] = cp.reshape(-1, c, 3)[rows, arg]
        bary = trimesh.triangles.points_to_barycentric(tri[best], out)
        bary = np.clip(np.nan_to_num(bary, nan=1 / 3), 0.0, 1.0)
        bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)
        return best, bary, dist


def closest_surface_points(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray):
    """(face index (N,), barycentrics (N, 3), distance (N,)) of each point's closest point on the
    triangle mesh (:class:`SurfaceQuery`)."""
    return SurfaceQuery(vertices, faces).query(points)


def _vertex_faces(nv: int, faces: np.ndarray, width: int = 8) -> np.ndarray:
    """(V, width) faces around each vertex, padded with its first face (0 when it has none)."""
    order = np.argsort(faces.reshape(-1), kind="stable")
    vid = faces.reshape(-1)[order]
    fid = order // 3
    start = np.searchsorted(vid, np.arange(nv))
    end = np.searchsorted(vid, np.arange(nv), side="right")
    out = np.zeros((nv, width), np.int64)
    for k in range(width):
        pos = np.minimum(start + k, np.maximum(end - 1, start))
        has = end > start
        out[:, k] = np.where(has, fid[np.minimum(pos, len(fid) - 1)], 0)
    return out


def transfer_weights(src: RigSource, points: np.ndarray, influences: int = 4, max_distance: float = 0.05):
    """(joint indices (N, K) int32, weights (N, K) float32 summing to 1, far count, distances (N,))."""
    from scipy.spatial import cKDTree

    face, bary, dist = closest_surface_points(src.vertices, src.faces, points)
    corners = src.faces[face]  # (N, 3)
    kv = src.joint_indices.shape[1]
    idx = src.joint_indices[corners].reshape(len(points), 3 * kv)
    w = (src.weights[corners].astype(np.float64) * bary[:, :, None]).reshape(len(points), 3 * kv)
    far = dist > max_distance
    if far.any():
        used = np.unique(src.faces)  # skin vertices only (a MakeHuman obj also holds helper geometry)
        _, nv = cKDTree(src.vertices[used]).query(points[far])
        nv = used[nv]
        idx[far] = np.tile(src.joint_indices[nv], (1, 3))
        w[far] = np.concatenate([src.weights[nv].astype(np.float64), np.zeros((len(nv), 2 * kv))], axis=1)
    # merge duplicate joints of a row (a dense row per Gaussian, in chunks), keep the largest K
    nj = len(src.names)
    k = int(influences)
    ik = np.empty((len(points), k), np.int64)
    wk = np.empty((len(points), k))
    step = max(1, 2_000_000 // max(nj, 1))
    for a in range(0, len(points), step):
        sl = slice(a, min(len(points), a + step))
        dense = np.zeros((sl.stop - sl.start, max(nj, k)))  # padded: fewer joints than influences
        rows = np.repeat(np.arange(sl.stop - sl.start), idx.shape[1])
        np.add.at(dense, (rows, idx[sl].reshape(-1)), w[sl].reshape(-1))
        top = np.argsort(-dense, axis=1, kind="stable")[:, :k]
        ik[sl] = top
        wk[sl] = np.take_along_axis(dense, top, axis=1)
    s = wk.sum(axis=1, keepdims=True)
    wk = wk / np.where(s > 0, s, 1.0)
    ik = np.where(wk > 0, ik, ik[:, :1])  # zero-weight slots (and padding) name the main joint
    return ik.astype(np.int32), wk.astype(np.float32), int(far.sum()), dist


# ----------------------------------------------------------------------------- motion
def parse_joint_map(text: str | None) -> dict[str, str] | None:
    """A BVH -> skeleton joint name map from a JSON file (``{"bvh": "skeleton", ...}``) or
    ``bvh:skeleton,bvh2:skeleton2``; None for None."""
    if not text:
        return None
    p = Path(text)
    if p.suffix.lower() == ".json":
        if not p.is_file():
            raise UserError(f"{p}: no such joint-map file")
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise UserError(f"{p}: not valid JSON ({exc})") from None
        if not isinstance(d, dict):
            raise UserError(f"{p}: the joint map must be a JSON object {{bvh: skeleton}}")
        return {str(k): str(v) for k, v in d.items()}
    out = {}
    for pair in text.split(","):
        if ":" not in pair:
            raise UserError(f"--joint-map entry '{pair}' is not 'bvh:skeleton'")
        a, b = pair.split(":", 1)
        out[a.strip()] = b.strip()
    return out


def choose_joint_map(bvh_names: list[str], skeleton_names: list[str], explicit: dict | None, where: str):
    """The BVH -> skeleton map to use: ``explicit``, else the built-in map matching most BVH joints.
    Raises ``UserError`` naming the joint when nothing maps or a mapped joint is missing."""
    bvh_set, skel_set = set(bvh_names), set(skeleton_names)
    if explicit is None:
        # identity map when the names are the skeleton's own
        ident = {n: n for n in bvh_names if n in skel_set}
        cands = [(sum(1 for k, v in m.items() if k in bvh_set and v in skel_set), name, m)
                 for name, m in BUILTIN_MAPS.items()]
        cands.append((len(ident), "names", ident))
        count, _, mapping = max(cands, key=lambda c: c[0])
        if count < 3:
            raise UserError(f"{where}: BVH joint '{bvh_names[0]}' (and the others) do not map to the skeleton's "
                            "joints; give --joint-map")
        mapping = {k: v for k, v in mapping.items() if k in bvh_set and v in skel_set}
    else:
        mapping = explicit
        for k, v in mapping.items():
            if k not in bvh_set:
                raise UserError(f"{where}: joint-map BVH joint '{k}' is not in the BVH")
            if v not in skel_set:
                raise UserError(f"{where}: joint-map skeleton joint '{v}' (for BVH joint '{k}') is not in the skeleton")
    root = bvh_names[0]
    if root not in mapping:
        raise UserError(f"{where}: BVH root joint '{root}' does not map to a skeleton joint; give --joint-map")
    return mapping


def retarget_bvh(src: RigSource, bvh, joint_map: dict | None = None, fps: float = FPS, up: str = "auto",
                 in_place: bool = False):
    """(times (T,) seconds, local (T, J, 4, 4) parent-relative skeleton transforms) from a BVH.

    For each mapped skeleton joint: its world rotation is the BVH joint's world rotation (axes
    converted to rig space) times the rotation taking the skeleton bone's bind direction to the
    BVH bone's rest direction (the child offset, when the BVH joint has one child); unmapped joints
    keep their rest orientation relative to the parent. The root's translation follows the BVH
    root relative to its first frame (the first frame stands at the bind pose's root position),
    scaled by the ratio of rest hip heights (:func:`ground_motion` then puts the feet on the floor).
    BVH up axis: ``auto`` (the rest pose's root -> head direction) or +y/+z. Frames are sampled at
    ``fps`` (nearest BVH frame). ``in_place`` drops the root's horizontal motion (a walk on the spot).
    """
    where = bvh.path
    mapping = choose_joint_map(bvh.names, src.names, joint_map, where)
    tindex = {n: i for i, n in enumerate(src.names)}
    bindex = {n: i for i, n in enumerate(bvh.names)}
    rest = bvh.rest_global()
    rest_pos = rest[:, :3, 3]
    # axes: BVH -> rig
    root_b = 0
    if up == "auto":
        heads = [k for k, v in mapping.items() if v in ("head", "neck01", "Head")]
        top = bindex[heads[0]] if heads else int(np.argmax(rest_pos[:, 1]))
        d = rest_pos[top] - rest_pos[root_b]
        axis = int(np.argmax(np.abs(d)))
        up_vec = np.sign(d[axis]) * np.eye(3)[axis]
    else:
        axis, sign = _UP[up.lower()]
        up_vec = sign * np.eye(3)[axis]
    r_up = rotation_between(up_vec, [0.0, 1.0, 0.0])
    # forward: feet -> toes in the rest pose, else the BVH's own axes
    fwd = np.array([0.0, 0.0, 1.0])
    feet = [(bindex[k], v) for k, v in mapping.items() if v.startswith("foot")]
    if feet:
        j = feet[0][0]
        kids = bvh.children(j)
        toe = rest_pos[kids[0]] - rest_pos[j] if kids else (bvh.end_offsets[j] if bvh.end_offsets[j] is not None
                                                               else None)
        if toe is not None:
            t = r_up @ toe
            t[1] = 0
            if np.linalg.norm(t) > 1e-9:
                axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]], np.float64)
                fwd = axes[int(np.argmax(axes @ t))]
    r_face = rotation_between(fwd, [0.0, 0.0, 1.0]) if abs(fwd[2] + 1) > 1e-9 else np.diag([-1.0, 1.0, -1.0])
    c = r_face @ r_up  # BVH axes -> rig axes

    # scale: rest root height over the lowest joint (the hip height), else the joints' height range
    bvh_r = rest_pos @ c.T
    mapped_t = [tindex[v] for v in mapping.values()]
    src_y = src.heads[mapped_t, 1]
    src_h = src.heads[tindex[mapping[bvh.names[0]]], 1] - src_y.min()
    bvh_h = bvh_r[root_b, 1] - bvh_r[[bindex[k] for k in mapping], 1].min()
    if src_h > 1e-6 * max(np.ptp(src_y), 1e-12) and bvh_h > 1e-12:
        scale = src_h / bvh_h
    else:
        rng_b = np.ptp(bvh_r[:, 1])
        scale = np.ptp(src.heads[:, 1]) / rng_b if rng_b > 1e-12 else 1.0

    # rest bone directions
    corr = {}
    for bname, tname in mapping.items():
        jb, jt = bindex[bname], tindex[tname]
        kids = bvh.children(jb)
        if len(kids) == 1:
            db = bvh.offsets[kids[0]]
        elif not kids and bvh.end_offsets[jb] is not None:
            db = bvh.end_offsets[jb]
        else:
            corr[tname] = (jb, np.eye(3))
            continue
        dt = src.tails[jt] - src.heads[jt]
        db = c @ db
        if np.linalg.norm(db) < 1e-9 or np.linalg.norm(dt) < 1e-9:
            corr[tname] = (jb, np.eye(3))
        else:
            corr[tname] = (jb, rotation_between(dt, db))

    duration = bvh.num_frames * bvh.frame_time
    n = max(1, int(np.floor(duration * fps + 1e-6)))
    times = np.arange(n) / fps
    fidx = np.minimum(np.round(times / bvh.frame_time).astype(np.int64), bvh.num_frames - 1)
    glob_b = bvh.global_transforms(fidx)  # (T, JB, 4, 4)
    nt, nj = len(times), len(src.names)
    rot_b = np.einsum("ab,tjbc,dc->tjad", c, glob_b[:, :, :3, :3], c)  # C R C^T
    root_pos = np.einsum("ab,tb->ta", c, glob_b[:, root_b, :3, 3])
    local = np.broadcast_to(src.rest_local, (nt, nj, 4, 4)).copy()
    glob_rot = np.zeros((nt, nj, 3, 3))
    bind_rot = src.bind[:, :3, :3]
    for j, p in enumerate(src.parents):
        tname = src.names[j]
        if tname in corr:
            jb, cr = corr[tname]
            g = rot_b[:, jb] @ cr @ bind_rot[j]
        else:
            # keep the rest local rotation relative to the parent
            g = (glob_rot[:, p] if p >= 0 else np.broadcast_to(np.eye(3), (nt, 3, 3))) @ src.rest_local[j, :3, :3]
        glob_rot[:, j] = g
        parent_rot = glob_rot[:, p] if p >= 0 else np.broadcast_to(np.eye(3), (nt, 3, 3))
        local[:, j, :3, :3] = np.einsum("tba,tbc->tac", parent_rot, g)
    r0 = tindex[mapping[bvh.names[0]]]
    if src.parents[r0] < 0:
        # relative to the first frame: BVH root heights are absolute in some files (CMU: offset 0,
        # channel = hip height) and offset-relative in others (MakeHuman)
        delta = (root_pos - root_pos[0]) * scale
        if in_place:
            delta[:, [0, 2]] = 0.0
        local[:, r0, :3, 3] = src.rest_local[r0, :3, 3] + delta
    return times, local


def ground_motion(local: np.ndarray, parents: np.ndarray, bind: np.ndarray, points: np.ndarray,
                  joint_indices: np.ndarray, weights: np.ndarray) -> float:
    """Shift the root joints' translations (``local`` (T, J, 4, 4), in place) vertically so that
    the lowest skinned ``points`` (the 2 % lowest in the bind pose: the soles) sit, in the median
    frame, as high as in the bind pose: a retargeted walk's stance foot on the floor. Returns the
    shift in metres (subtracted)."""
    y = points[:, 1]
    low = y <= np.percentile(y, 2.0)
    glob = np.zeros_like(local)
    for j, p in enumerate(parents):
        glob[:, j] = local[:, j] if p < 0 else glob[:, p] @ local[:, j]
    skin = glob @ np.linalg.inv(bind)[None]
    per_frame = [np.percentile(lbs(points[low], joint_indices[low], weights[low], skin[f])[:, 1], 10.0)
                 for f in range(len(skin))]
    lift = float(np.median(per_frame) - np.percentile(y[low], 10.0))
    local[:, parents < 0, 1, 3] -= lift
    return lift


# ----------------------------------------------------------------------------- stage
@dataclass
class RigResult:
    output: Path
    count: int
    joints: int
    frames: int
    far: int
    align: dict
    stretched_share: float | None = None
    notes: list[str] = field(default_factory=list)


def read_avatar(path) -> GaussianSet:
    """Gaussians of a .ply / .spz or the first Gaussian prim of a USD stage (world space, default time)."""
    p = Path(path)
    ext = p.suffix.lower()
    if not p.is_file():
        raise UserError(f"{p}: no such avatar file")
    if ext == ".ply":

        return read_ply(p)
    if ext in (".usd", ".usda", ".usdc", ".usdz"):


        stage = Usd.Stage.Open(str(p))
        if stage is None:
            raise UserError(f"{p}: USD could not open the stage")
        prims = find_gaussian_prims(stage)
        if not prims:
            raise UserError(f"{p}: no ParticleField3DGaussianSplat prim")
        return read_gaussian_prim(prims[0], None)
    raise UserError(f"{p}: avatar must be .ply or .usd/.usda/.usdc, not '{ext}'")


def stretched_share(rest: GaussianSet, skinned: GaussianSet, threshold: float = 0.2) -> float:
    """Share of Gaussians whose skinned scale differs from the rest scale by more than ``threshold``
    (relative, the uniform scale part: max over axes of |s'/s - 1|)."""
    ratio = skinned.scales.astype(np.float64) / np.maximum(rest.scales.astype(np.float64), 1e-30)
    return float(np.mean(np.max(np.abs(ratio - 1.0), axis=1) > threshold))


def rig_avatar(avatar, skin, output, skeleton=None, weights=None, motion=None, joint_map=None,
               up: str = "+y", facing: str = "auto", align_matrix: np.ndarray | None = None,
               influences: int = 4, max_distance: float = 0.05, fps: float = FPS, prim_path: str = "/Avatar",
               motion_up: str = "auto", icp_iterations: int = 10, skinning_method: str = "lbs",
               log=None) -> RigResult:
    """Bind ``avatar`` to ``skin`` and write ``output`` (module docstring). Stage layout:
    ``/Avatar`` SkelRoot (usdgs role avatar on the Gaussians), ``/Avatar/Skeleton``,
    ``/Avatar/Skeleton/Motion`` SkelAnimation, ``/Avatar/Gaussians`` (bind-pose Gaussians, bound).
    Y-up, metres, ``timeCodesPerSecond`` = ``fps``, frames 1..T. ``skinning_method`` ``dq`` authors
    ``primvars:skel:skinningMethod`` dualQuaternion (UsdSkel's dual-quaternion skinning)."""

    say = log or (lambda msg: None)
    if skinning_method not in ("lbs", "dq"):
        raise UserError(f"--skinning-method must be lbs or dq, not '{skinning_method}'")
    src = load_source(skin, skeleton, weights)
    gs = read_avatar(avatar)
    if gs.count == 0:
        raise UserError(f"{avatar}: the avatar has no Gaussians")
    if align_matrix is not None:
        m, info = np.asarray(align_matrix, np.float64), {"explicit": True}
    else:
        m, info = align_to_mesh(gs, src.vertices, up=up, facing=facing, icp_iterations=icp_iterations,
                                faces=src.faces)
    say(f"  aligned: {json.dumps({k: (round(v, 5) if isinstance(v, float) else v) for k, v in info.items()})}")

    try:
        rig_gs = gs.transformed(m.T, label=prim_path + "/Gaussians")
    except GaussianDataError as exc:
        raise UserError(f"alignment matrix: {exc}") from None
    idx, wts, far, dist = transfer_weights(src, rig_gs.positions.astype(np.float64), influences, max_distance)
    if far:
        warnings.warn(f"{far} of {rig_gs.count} Gaussians are farther than {max_distance} m from the skin; they "
                      "take the nearest vertex's weights", stacklevel=2)
    say(f"  weights: {rig_gs.count} Gaussians, median distance to the skin {np.median(dist) * 1000:.1f} mm, "
        f"{far} beyond {max_distance} m")

    if motion is not None:
        mp = Path(motion)
        if mp.suffix.lower() == ".bvh":

            times, local = retarget_bvh(src, read_bvh(mp), parse_joint_map(joint_map), fps=fps, up=motion_up)
            lift = ground_motion(local, src.parents, src.bind, rig_gs.positions.astype(np.float64), idx, wts)
            say(f"  motion: {len(times)} frames at {fps:g} fps, root lowered by {lift * 1000:.1f} mm "
                "(feet on the floor)")
        elif mp.suffix.lower() in (".glb", ".gltf"):
            msrc = src if Path(skin).resolve() == mp.resolve() else gltf_source(mp, fps)
            if msrc.local_frames is None:
                raise UserError(f"{mp}: the glTF has no animation")
            if msrc.names != src.names:
                raise UserError(f"{mp}: its joints ({len(msrc.names)}) are not the skin's joints ({len(src.names)})")
            times, local = msrc.times, msrc.local_frames
        else:
            raise UserError(f"{mp}: --motion must be .bvh or .glb, not '{mp.suffix}'")
    elif src.local_frames is not None:
        times, local = src.times, src.local_frames
    else:
        times, local = np.zeros(1), src.rest_local[None]

    stage = new_stage(output, up_axis="Y", meters_per_unit=1.0, default_prim=prim_path.strip("/").split("/")[0])
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(len(times))
    root = UsdSkel.Root.Define(stage, Sdf.Path(prim_path))
    UsdGeom.ModelAPI(root.GetPrim())
    joints = src.joint_paths
    sk = uskel.author_skeleton(stage, f"{prim_path}/Skeleton", joints, src.bind, src.rest_local)
    trans, rots, sc = animation_arrays(local)
    uskel.author_animation(stage, f"{prim_path}/Skeleton/Motion", sk, joints, np.arange(len(times)) + 1.0, trans,
                           rots, sc)
    prim = write_gaussian_prim(stage, f"{prim_path}/Gaussians", rig_gs, keep_raw=False)
    apply_role(prim, "avatar")
    binding = uskel.bind_prim(prim, sk, idx, wts)
    if skinning_method == "dq":
        binding.CreateSkinningMethodAttr().Set(UsdSkel.Tokens.dualQuaternion)
    # the rest-pose extent is what UsdSkel-unaware tools see; skinned bounds come from describe
    save_stage_atomic(stage, output)
    result = RigResult(Path(output), rig_gs.count, len(joints), len(times), far, info, notes=list(src.notes))
    # stretch statistic over the motion (about 6 frames)

    shares = []
    for f in range(1, len(times) + 1, max(1, len(times) // 6)):
        shares.append(stretched_share(rig_gs, read_gaussian_prim(stage.GetPrimAtPath(f"{prim_path}/Gaussians"), f)))
    result.stretched_share = float(np.mean(shares)) if shares else None
    return result


# ----------------------------------------------------------------------------- glTF avatars (demo)
def blend_vertex_weights(joint_indices: np.ndarray, weights: np.ndarray, faces: np.ndarray, face_index: np.ndarray,
                         bary: np.ndarray, num_joints: int, influences: int | None = None):
    """Barycentric blend of a triangle's vertex weights at surface samples: (indices (n, K) int32,
    weights (n, K) float32, rows summing to 1). Duplicate joints are merged; ``influences`` None
    keeps every joint that has weight (K = the largest count, zero-padded), else the largest K."""
    corners = np.asarray(faces)[np.asarray(face_index)]
    kv = joint_indices.shape[1]
    n = len(face_index)
    idx = joint_indices[corners].reshape(n, 3 * kv)
    w = (weights[corners].astype(np.float64) * np.asarray(bary, np.float64)[:, :, None]).reshape(n, 3 * kv)
    dense = np.zeros((n, num_joints))
    np.add.at(dense, (np.repeat(np.arange(n), 3 * kv), idx.reshape(-1)), w.reshape(-1))
    k = int(influences) if influences else max(1, int((dense > 0).sum(axis=1).max()))
    if dense.shape[1] < k:
        dense = np.concatenate([dense, np.zeros((n, k - dense.shape[1]))], axis=1)
    top = np.argsort(-dense, axis=1, kind="stable")[:, :k]
    wk = np.take_along_axis(dense, top, axis=1)
    wk /= np.maximum(wk.sum(axis=1, keepdims=True), 1e-300)
    top = np.where((wk > 0) & (top < num_joints), top, top[:, :1])
    return top.astype(np.int32), wk.astype(np.float32)


def gltf_skeleton(mesh):
    """(order (J,) skin joint indices parents first, parents (J,), UsdSkel joint paths (J,)) of a
    ``usd_gs.io.gltf.SkinnedMesh``: the parent of a joint is its nearest ancestor node that is a joint."""
    nodes = mesh.joint_nodes
    order, new_index, parents = _gltf_joint_order(mesh)
    src = RigSource("", np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 1), np.int32),
                    np.zeros((0, 1), np.float32), [mesh.node_names[nodes[j]] or f"joint{j}" for j in order], parents,
                    np.zeros((len(order), 4, 4)), np.zeros((len(order), 4, 4)), np.zeros((len(order), 3)),
                    np.zeros((len(order), 3)))
    return np.array(order, np.int64), new_index, parents, src.joint_paths


def author_gltf_skinned_avatar(stage, mesh, prim_path: str, skel_path: str, times_s, time_codes, n_gaussians: int,
                               seed: int = 0, loop: bool = True, skel_xforms: dict | None = None):
    """Author a skinned Gaussian avatar of a glTF skinned mesh (the exact glTF skinning, UsdSkel form).

    The Gaussians are :func:`usd_gs.demo.mesh_avatar.posed_avatar_frames`'s surface samples (same
    faces, barycentrics, colours, sigma and inset for the same ``seed``) built on the mesh-space
    rest vertices (glTF ``POSITION``); each takes the barycentric blend of its triangle's vertex
    weights (every influence kept). ``Skeleton`` at ``skel_path``: joints parents first,
    ``bindTransforms`` = inverse bind matrices inverted (mesh space), ``restTransforms`` the rest
    pose; its ``SkelAnimation`` (``skel_path + "/Animation"``) samples the glTF clip at ``times_s``
    (seconds; ``loop`` repeats it) as time codes ``time_codes``; skeleton space = glTF world (Y-up,
    metres), so the skinning matrix of joint j at t is ``G_j(t) @ IBM_j``, as glTF. ``skel_xforms``
    ({time code: 4x4 USD row-vector matrix}) places the skeleton (root motion) by an ``xformOp:transform``.
    The Gaussian prim and the skeleton must sit under a SkelRoot the caller provides. Returns the prim.
    """

    rest_world = pose(mesh, None)[0]
    face, bary = sample_surface(rest_world, mesh.faces, n_gaussians, seed)
    colors = sample_colors(mesh, face, bary)
    spacing = np.sqrt(face_areas(rest_world, mesh.faces).sum() / max(n_gaussians, 1))
    rest = gaussians_on_mesh(mesh.rest_vertices, mesh.faces, mesh.normals, face, bary, colors, 0.1, 0.95,
                             spacing=spacing, sigma_factor=AVATAR_SIGMA_FACTOR, sh_degree=0, inset=AVATAR_INSET,
                             label=prim_path)
    order, new_index, parents, joints = gltf_skeleton(mesh)
    idx, wts = blend_vertex_weights(new_index[mesh.joints], mesh.weights, mesh.faces, face, bary, len(order))
    if loop and mesh.channels and loop_period(mesh) <= 0:
        loop = False
    nodes = mesh.joint_nodes[order]
    bind = np.linalg.inv(mesh.inverse_bind_matrices[order])
    rest_local = _locals(node_global_matrices(mesh, None)[nodes], parents)
    sk = uskel.author_skeleton(stage, skel_path, joints, bind, rest_local)
    frames = np.stack([_locals(node_global_matrices(mesh, float(t), loop)[nodes], parents) for t in times_s])
    lin = frames[:, :, :3, :3]
    sc = np.linalg.norm(lin, axis=2)
    rots = matrix_to_quaternion((lin / np.where(sc > 0, sc, 1.0)[:, :, None, :]).reshape(-1, 3, 3))
    uskel.author_animation(stage, skel_path + "/Animation", sk, joints, time_codes, frames[:, :, :3, 3],
                           rots.reshape(len(frames), len(order), 4), sc)
    if skel_xforms:
        op = UsdGeom.Xformable(sk).AddTransformOp()
        layer = stage.GetEditTarget().GetLayer()
        with Sdf.ChangeBlock():
            for t, m in skel_xforms.items():
                layer.SetTimeSample(op.GetAttr().GetPath(), float(t), Gf.Matrix4d(np.asarray(m).tolist()))
    prim = write_gaussian_prim(stage, prim_path, rest, keep_raw=False)
    uskel.bind_prim(prim, sk, idx, wts)
    return prim


# ----------------------------------------------------------------------------- demo: the rigged T-pose capture
RIGGED_FILES = {"avatar": "humans/tpose_avatar.ply", "skin": "humans/makehuman_base.obj",
                "skeleton": "humans/makehuman_default.mhskel", "weights": "humans/makehuman_default_weights.mhw",
                "motion": "humans/makehuman_walk1.bvh"}
"""Inputs of :func:`write_rigged_avatar_layer`, relative to the data directory."""

RIGGED_PLACEMENT = ((1.3, 0.0, 1.2), 41.5)
"""(position metres, heading degrees about +Y) of the demo's rigged avatar: on the floor between
the table and the biker's circle, facing the demo camera."""


def animation_arrays(local: np.ndarray):
    """(translations (T, J, 3), rotations (T, J, 4) wxyz, scales (T, J, 3)) of parent-relative
    (T, J, 4, 4) matrices (scale = column norms; shear dropped)."""
    lin = local[:, :, :3, :3]
    sc = np.linalg.norm(lin, axis=2)
    rots = matrix_to_quaternion((lin / np.where(sc > 0, sc, 1.0)[:, :, None, :]).reshape(-1, 3, 3))
    return local[:, :, :3, 3], rots.reshape(local.shape[0], local.shape[1], 4), sc


def write_rigged_avatar_layer(frames: int, data: Path, path: Path, fps: float = FPS,
                              prim_path: str = "/World/TPoseAvatar") -> int:
    """The demo layer of the rigged T-pose capture (:data:`RIGGED_FILES`): ``prim_path`` bound to
    ``prim_path + "_Skeleton"`` (MakeHuman skeleton, T-posed bind), walking on the spot with the
    MakeHuman walk (looped over ``frames`` at ``fps``), placed at :data:`RIGGED_PLACEMENT` by the
    skeleton's transform; ``/World`` is a SkelRoot (as in the demo's root layer). Returns the count."""

    files = {k: Path(data) / v for k, v in RIGGED_FILES.items()}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise UserError(f"the rigged avatar needs {', '.join(missing)} (missing)")
    src = makehuman_source(files["skin"], files["skeleton"], files["weights"])
    gs = read_avatar(files["avatar"])
    m, _ = align_to_mesh(gs, src.vertices, faces=src.faces)
    rig_gs = gs.transformed(m.T, label=prim_path)
    idx, wts, _, _ = transfer_weights(src, rig_gs.positions.astype(np.float64))
    times, local = retarget_bvh(src, read_bvh(files["motion"]), fps=fps, in_place=True)
    ground_motion(local, src.parents, src.bind, rig_gs.positions.astype(np.float64), idx, wts)
    cycle = np.arange(frames) % len(times)
    local = local[cycle]
    stage = new_stage(up_axis="Y", meters_per_unit=1.0, default_prim="World")
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    UsdSkel.Root.Define(stage, "/World")
    joints = src.joint_paths
    sk = uskel.author_skeleton(stage, prim_path + "_Skeleton", joints, src.bind, src.rest_local)
    tr, rot, sc = animation_arrays(local)
    uskel.author_animation(stage, prim_path + "_Skeleton/Walk", sk, joints, np.arange(1, frames + 1, dtype=np.float64),
                           tr, rot, sc)
    (x, y, z), heading = RIGGED_PLACEMENT
    xf = UsdGeom.Xformable(sk)
    xf.AddTranslateOp().Set(Gf.Vec3d(x, y, z))
    xf.AddRotateYOp().Set(float(heading))
    prim = write_gaussian_prim(stage, prim_path, rig_gs, keep_raw=False)
    apply_role(prim, "avatar")
    uskel.bind_prim(prim, sk, idx, wts)
    save_stage_atomic(stage, path)
    return rig_gs.count
