"""Skinned Gaussian prims: a ``ParticleField3DGaussianSplat`` bound to a ``UsdSkel.Skeleton``.

The prim holds the bind-pose (rest) Gaussians; ``UsdSkel.BindingAPI`` on it carries
``skel:skeleton`` (or inherits it from an ancestor, UsdSkel's rule), ``primvars:skel:jointIndices``
(int[]) and ``primvars:skel:jointWeights`` (float[]), both ``interpolation`` vertex (one set per
particle; ``constant``: one set for the whole prim) with ``elementSize`` = influences per particle,
optional ``primvars:skel:geomBindTransform`` (matrix4d, bind space -> skeleton space) and
``skel:joints`` (token[], the order the indices refer to; the skeleton's order when absent). The
prim must sit under a ``SkelRoot`` (UsdSkel ignores bindings outside one) and the skeleton must
have a ``SkelAnimation`` (``skel:animationSource``).

Evaluation at a time code (UsdSkel's conventions, row-vector matrices): the library computes the
joint matrices (``UsdSkel.Cache`` -> ``SkeletonQuery.ComputeSkinningTransforms``, remapped to the
prim's ``skel:joints`` order by the ``SkinningQuery``'s joint mapper); this module skins the
Gaussians with ``numba_kernels.skinning``: a bind point ``p`` goes to
``sum_k w_k * p * geomBind * S[j_k]`` in skeleton space, then through the skeleton's
local-to-world (world space; the skinned prim's own transform is ignored, as UsdSkel does).
Orientations follow the polar rotation of the blended 3x3, scales its uniform part
``det^(1/3)``, SH bands 1..3 are rotated exactly per band (the kernel's docstring). Weights are
used as authored (validated to sum to 1 within :data:`WEIGHT_SUM_TOL`). With
``primvars:skel:skinningMethod`` = ``dualQuaternion`` the centres follow UsdSkel's dual-quaternion
skinning instead (each joint's stretch blended linearly and applied first, its rigid part as a
blended unit dual quaternion, signs aligned with the largest-weight joint), and orientation, scale
and SH follow the 3x3 of that per-Gaussian affine map.

Nothing here imports numba at module level; :func:`skin_gaussian_set` imports the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from usd_gs.errors import GaussianDataError
from usd_gs.gaussians import GaussianSet

WEIGHT_SUM_TOL = 1e-4
"""|sum of a particle's joint weights - 1| allowed (validate and the reader)."""

JOINT_INDICES = "primvars:skel:jointIndices"
JOINT_WEIGHTS = "primvars:skel:jointWeights"
GEOM_BIND = "primvars:skel:geomBindTransform"
SKEL_REL = "skel:skeleton"
ANIM_REL = "skel:animationSource"

class BindingError(GaussianDataError):
    """A bad UsdSkel binding. ``attribute``: the attribute or relationship at fault; ``element``:
    the first bad element index or None; ``detail``: the message without the prim prefix."""

    def __init__(self, where: str, attribute: str, detail: str, element: int | None = None):
        super().__init__(f"{where}: {detail}")
        self.attribute, self.detail, self.element = attribute, detail, element


_CACHES: dict = {}  # (stage, skel root path) -> UsdSkel.Cache
_SH_TABLES: dict = {}


def _as_time(time) -> Usd.TimeCode:
    if time is None:
        return Usd.TimeCode.Default()
    return time if isinstance(time, Usd.TimeCode) else Usd.TimeCode(float(time))


def has_skel_binding(prim: Usd.Prim) -> bool:
    """True when the prim asks to be skinned: ``UsdSkel.BindingAPI`` applied or joint influences authored,
    and an (inherited) ``skel:skeleton`` target. A binding whose skeleton relationship has no target
    (e.g. blocked by an ``over`` of a baked output) is not skinned."""
    if not (prim.HasAPI(UsdSkel.BindingAPI) or prim.GetAttribute(JOINT_INDICES).HasAuthoredValue()):
        return False
    return bool(UsdSkel.BindingAPI(prim).GetInheritedSkeleton())


def _skel_root(prim: Usd.Prim) -> Usd.Prim | None:
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdSkel.Root):
            return p
        p = p.GetParent()
    return None


def _cache_for(prim: Usd.Prim, where: str, fresh: bool = False) -> UsdSkel.Cache:
    root = _skel_root(prim)
    if root is None:
        raise BindingError(where, SKEL_REL, f"has a UsdSkel binding ('{SKEL_REL}') but no SkelRoot ancestor; "
                           "UsdSkel skins only prims under a SkelRoot")
    # keyed by the stage's identity without holding a reference to it (a farm worker opens many stages)
    key = (hash(prim.GetStage()), root.GetPath())
    cache = None if fresh else _CACHES.get(key)
    if cache is None:
        if len(_CACHES) > 64:
            _CACHES.clear()
        cache = UsdSkel.Cache()
        cache.Populate(UsdSkel.Root(root), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
        _CACHES[key] = cache
    return cache


def clear_caches() -> None:
    """Forget the per-stage ``UsdSkel.Cache`` objects (after editing a skeleton or binding in place)."""
    _CACHES.clear()


@dataclass
class SkinBinding:
    """The evaluated binding of one prim at one time code.

    ``joint_indices`` (N, K) int32 into ``skinning`` rows; ``weights`` (N, K) float32;
    ``skinning`` (J, 4, 4) float64 COLUMN-vector matrices bind space -> world (or prim-local when
    read with ``world=False``): geomBind, the joint's skinning transform and the skeleton's
    local-to-world folded together. ``skeleton`` and ``animation`` are prim paths;
    ``time_range`` the (first, last) time samples of the animation or None. ``method`` is the
    prim's ``primvars:skel:skinningMethod`` (``classicLinear`` or ``dualQuaternion``); for the
    latter ``dual`` holds the kernel's dual-quaternion inputs (:func:`dual_quaternion_inputs`).
    """

    joint_indices: np.ndarray
    weights: np.ndarray
    skinning: np.ndarray
    skeleton: str
    animation: str
    method: str
    time_range: tuple[float, float] | None
    dual: tuple | None = None


def _queries(prim: Usd.Prim, where: str):
    cache = _cache_for(prim, where)
    binding = UsdSkel.BindingAPI(prim)
    skel = binding.GetInheritedSkeleton()
    skel_query = cache.GetSkelQuery(skel)
    if not skel_query or not cache.GetSkinningQuery(prim):  # stale cache (a new stage, or edited): rebuild once
        cache = _cache_for(prim, where, fresh=True)
        skel_query = cache.GetSkelQuery(skel)
    if not skel_query:
        raise BindingError(where, SKEL_REL, f"relationship '{SKEL_REL}' -> {skel.GetPrim().GetPath()} is not a "
                           "valid Skeleton (joints/bindTransforms/restTransforms)")
    skinning_query = cache.GetSkinningQuery(prim)
    if not skinning_query or not skinning_query.HasJointInfluences():
        raise BindingError(where, JOINT_INDICES, f"attributes '{JOINT_INDICES}' / '{JOINT_WEIGHTS}' are missing "
                           "or malformed (both int/float arrays with the same elementSize)")
    return skel, skel_query, skinning_query


def _anim_range(anim_query) -> tuple[float, float] | None:
    ts = list(anim_query.GetJointTransformTimeSamples())
    return (float(ts[0]), float(ts[-1])) if ts else None


def joint_influences(prim: Usd.Prim, n: int, time=None, where: str | None = None):
    """(indices (N, K) int32, weights (N, K) float32, joint count) of a bound prim, validated.

    Raises :class:`BindingError` naming the prim, attribute and first bad element: lengths
    not N * elementSize, an index outside the joint order, weights not summing to 1 within
    :data:`WEIGHT_SUM_TOL`, non-finite or negative weights.
    """
    from usd_gs.usd.frames import as_time

    tc = as_time(time)
    path = prim.GetPath().pathString
    where = where or path
    _, skel_query, sq = _queries(prim, where)
    return _influences(sq, skel_query, n, tc, where)


def _influences(sq, skel_query, n: int, tc, where: str):
    k = int(sq.GetNumInfluencesPerComponent())
    idx_attr = sq.GetJointIndicesPrimvar()
    w_attr = sq.GetJointWeightsPrimvar()
    idx = idx_attr.Get(tc)
    wts = w_attr.Get(tc)
    idx = np.asarray(idx if idx is not None else [], np.int32).reshape(-1)
    wts = np.asarray(wts if wts is not None else [], np.float32).reshape(-1)
    if k < 1:
        raise BindingError(where, JOINT_INDICES, f"attribute '{JOINT_INDICES}' has elementSize {k}, must be >= 1")
    rigid = sq.IsRigidlyDeformed()
    want = k if rigid else n * k
    for name, arr in ((JOINT_INDICES, idx), (JOINT_WEIGHTS, wts)):
        if arr.size != want:
            what = "constant interpolation" if rigid else f"{n} particles"
            raise BindingError(where, name, f"attribute '{name}' has {arr.size} elements but {what} with "
                               f"elementSize {k} need {want}")
    order = sq.GetJointOrder()
    n_joints = len(order) if order else len(skel_query.GetJointOrder())
    bad = (idx < 0) | (idx >= n_joints)
    if bad.any():
        e = int(np.flatnonzero(bad)[0])
        raise BindingError(where, JOINT_INDICES, f"attribute '{JOINT_INDICES}' element {e} (particle {e // k}) is "
                           f"{int(idx[e])}, outside the {n_joints} joints of the joint order", e)
    bad = ~np.isfinite(wts) | (wts < 0)
    if bad.any():
        e = int(np.flatnonzero(bad)[0])
        raise BindingError(where, JOINT_WEIGHTS, f"attribute '{JOINT_WEIGHTS}' element {e} (particle {e // k}) is "
                           f"{float(wts[e])!r}, weights must be finite and >= 0", e)
    sums = wts.reshape(-1, k).astype(np.float64).sum(axis=1)
    bad = np.abs(sums - 1.0) > WEIGHT_SUM_TOL
    if bad.any():
        p = int(np.flatnonzero(bad)[0])
        raise BindingError(where, JOINT_WEIGHTS, f"attribute '{JOINT_WEIGHTS}' particle {p} (elements {p * k}.."
                           f"{p * k + k - 1}) sums to {sums[p]:.6g}, not 1 within {WEIGHT_SUM_TOL:g} "
                           f"({int(bad.sum())} particles)", p * k)
    idx = idx.reshape(-1, k)
    wts = wts.reshape(-1, k)
    if rigid:
        idx = np.broadcast_to(idx, (n, k))
        wts = np.broadcast_to(wts, (n, k))
    return np.ascontiguousarray(idx), np.ascontiguousarray(wts), n_joints


def evaluate_binding(prim: Usd.Prim, n: int, time=None, world: bool = True) -> SkinBinding:
    """:class:`SkinBinding` of a bound prim with ``n`` particles at ``time`` (see module docstring).

    Raises :class:`BindingError` (a ``UserError``) naming the prim/skeleton and attribute: no SkelRoot, an
    invalid skeleton, a skeleton without animation, bad influences (:func:`joint_influences`).
    """
    from usd_gs.usd.frames import as_time

    tc = as_time(time)
    path = prim.GetPath().pathString
    where = f"{path} (time {tc.GetValue():g})" if not tc.IsDefault() else path
    skel, skel_query, sq = _queries(prim, where)
    anim_query = skel_query.GetAnimQuery()
    skel_path = skel.GetPrim().GetPath().pathString
    if not anim_query:
        raise BindingError(where, SKEL_REL, f"Skeleton {skel_path} has no animation (relationship '{ANIM_REL}' "
                           "has no valid SkelAnimation target); nothing to skin")
    idx, wts, n_joints = _influences(sq, skel_query, n, tc, where)
    xforms = skel_query.ComputeSkinningTransforms(tc)
    if xforms is None:
        raise BindingError(where, SKEL_REL, f"Skeleton {skel_path} could not compute skinning transforms")
    mapper = sq.GetJointMapper()
    if mapper and not mapper.IsNull() and not mapper.IsIdentity():
        # unmapped prim joints get identity (UsdSkel fills the target with identities too)
        xforms = mapper.RemapTransforms(xforms, Vt.Matrix4dArray(n_joints, Gf.Matrix4d(1.0)))
    mats = np.array(xforms, dtype=np.float64).reshape(-1, 4, 4)
    if mats.shape[0] != n_joints:
        raise BindingError(where, "skel:joints", f"Skeleton {skel_path} gives {mats.shape[0]} skinning transforms "
                           f"for a joint order of {n_joints}")
    geom_bind = np.array(sq.GetGeomBindTransform(tc), dtype=np.float64)
    skel_l2w = np.array(UsdGeom.Xformable(skel.GetPrim()).ComputeLocalToWorldTransform(tc), dtype=np.float64)
    post = skel_l2w
    if not world:
        prim_l2w = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc), dtype=np.float64)
        post = skel_l2w @ np.linalg.inv(prim_l2w)
    row = geom_bind[None] @ mats @ post[None]  # row-vector: p' = p G S_j L
    col = np.ascontiguousarray(np.transpose(row, (0, 2, 1)))
    if not np.isfinite(col).all():
        raise BindingError(where, SKEL_REL, f"Skeleton {skel_path} skinning transforms are not finite")
    method = str(sq.GetSkinningMethod()) if hasattr(sq, "GetSkinningMethod") else "classicLinear"
    dual = None
    if method == str(UsdSkel.Tokens.dualQuaternion):
        dual = dual_quaternion_inputs(np.transpose(mats, (0, 2, 1)), geom_bind.T, post.T)
    return SkinBinding(idx, wts, col, skel_path, anim_query.GetPrim().GetPath().pathString, method,
                       _anim_range(anim_query), dual)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def dual_quaternion_inputs(joint_col: np.ndarray, pre: np.ndarray, post: np.ndarray):
    """(dq (J, 8), stretch (J, 3, 3), pre, post) for dual-quaternion skinning from (J, 4, 4)
    column-vector joint skinning matrices (bind -> skeleton space): each 3x3 is split as
    ``R @ P`` (polar: ``R`` a rotation, ``P`` symmetric, applied first, as UsdSkel's DQS applies the
    scale part before the rigid part); ``R`` and the translation form a unit dual quaternion
    (real w, x, y, z, dual w, x, y, z)."""
    from usd_gs.gaussians import matrix_to_quaternion

    a = joint_col[:, :3, :3]
    u, _, vt = np.linalg.svd(a)
    r = u @ vt
    neg = np.linalg.det(r) < 0
    if neg.any():
        u[neg, :, 2] *= -1
        r = u @ vt
    stretch = np.transpose(r, (0, 2, 1)) @ a
    q = matrix_to_quaternion(r)
    t = np.concatenate([np.zeros((len(a), 1)), joint_col[:, :3, 3]], axis=1)
    dual = 0.5 * _quat_mul(t, q)
    return (np.ascontiguousarray(np.concatenate([q, dual], axis=1)), np.ascontiguousarray(stretch),
            np.ascontiguousarray(pre), np.ascontiguousarray(post))


def dq_positions(points: np.ndarray, joint_indices: np.ndarray, weights: np.ndarray, dual) -> np.ndarray:
    """(N, 3) float64 centres under dual-quaternion skinning (numpy; the kernel's position math)."""
    dq, stretch, pre, post = dual
    p = points @ pre[:3, :3].T + pre[:3, 3]
    w = weights.astype(np.float64)
    best = joint_indices[np.arange(len(w)), np.argmax(w, axis=1)]
    sign = np.where(np.einsum("nkc,nc->nk", dq[joint_indices, :4], dq[best, :4]) < 0, -1.0, 1.0)
    blend = np.einsum("nk,nkc->nc", w * sign, dq[joint_indices])
    sp = np.einsum("nk,nkij,nj->ni", w, stretch[joint_indices], p)
    real, du = blend[:, :4], blend[:, 4:]
    ln = np.linalg.norm(real, axis=1, keepdims=True)
    ok = ln[:, 0] >= 1e-10
    real = np.where(ok[:, None], real / np.where(ok[:, None], ln, 1.0), [1.0, 0, 0, 0])
    du = np.where(ok[:, None], du / np.where(ok[:, None], ln, 1.0), 0.0)
    du = du - np.sum(real * du, axis=1, keepdims=True) * real
    conj = real * [1.0, -1, -1, -1]
    t = 2.0 * _quat_mul(du, conj)[:, 1:]
    from usd_gs.gaussians import quaternion_to_matrix

    q = np.einsum("nij,nj->ni", quaternion_to_matrix(real), sp) + t
    return q @ post[:3, :3].T + post[:3, 3]


def animation_range(prim: Usd.Prim) -> tuple[float, float] | None:
    """(first, last) time sample of the bound skeleton's animation (None without samples);
    raises like :func:`evaluate_binding` when the binding is unusable."""
    where = prim.GetPath().pathString
    skel, skel_query, _ = _queries(prim, where)
    anim_query = skel_query.GetAnimQuery()
    if not anim_query:
        raise BindingError(where, SKEL_REL, f"Skeleton {skel.GetPrim().GetPath()} has no animation (relationship "
                           f"'{ANIM_REL}' has no valid SkelAnimation target); nothing to skin")
    return _anim_range(anim_query)


def sh_rotation_tables(degree: int):
    """(dirs (M, 3), pinv (C, M)) float64 for the kernel's exact per-band SH rotation. Band l
    (1..``degree``) owns the 2l+1 directions ``dirs[l^2 - 1 : (l+1)^2 - 1]`` (M = degree (degree + 2);
    one unused row for degree 0), picked among 256 Fibonacci-sphere directions for a well-conditioned
    band basis (condition numbers 1.1, 2.0, 2.8); rows ``l^2 .. (l+1)^2 - 1`` of ``pinv`` hold the
    inverse of the band-l 3DGS basis at them in those columns, zeros elsewhere (band 0 unused)."""
    if degree in _SH_TABLES:
        return _SH_TABLES[degree]
    from usd_gs import sh3dgs

    n = 256
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    rr = np.sqrt(1.0 - z * z)
    cand = np.stack([rr * np.cos(phi), rr * np.sin(phi), z], axis=1)
    y_all = sh3dgs.eval_basis(cand, max(degree, 0))
    m = max(1, degree * (degree + 2))
    dirs = np.zeros((m, 3))
    dirs[:, 2] = 1.0
    c = sh3dgs.num_coeffs(degree)
    pinv = np.zeros((c, m))
    rng = np.random.default_rng(0)
    for band in range(1, degree + 1):
        s = slice(band * band, (band + 1) ** 2)
        nb = 2 * band + 1
        best, pick = np.inf, None
        for _ in range(3000):
            idx = rng.choice(n, nb, replace=False)
            cond = np.linalg.cond(y_all[idx][:, s])
            if cond < best:
                best, pick = cond, idx
        cols = slice(band * band - 1, (band + 1) ** 2 - 1)
        dirs[cols] = cand[pick]
        pinv[s, cols] = np.linalg.inv(y_all[pick][:, s])
    out = (np.ascontiguousarray(dirs), np.ascontiguousarray(pinv))
    _SH_TABLES[degree] = out
    return out


def skin_arrays(rest: GaussianSet, joint_indices: np.ndarray, weights: np.ndarray, skinning: np.ndarray,
                dual=None):
    """Kernel call on a rest :class:`GaussianSet`: (positions, orientations, scales, sh, rotations)
    float32 (``numba_kernels.skinning.skin_gaussians``)."""
    from numba_kernels.skinning import skin_gaussians

    dirs, pinv = sh_rotation_tables(rest.sh_degree)
    f = np.float32
    return skin_gaussians(np.ascontiguousarray(rest.positions, f), np.ascontiguousarray(rest.orientations, f),
                          np.ascontiguousarray(rest.scales, f), np.ascontiguousarray(rest.sh, f),
                          np.ascontiguousarray(joint_indices, np.int32), np.ascontiguousarray(weights, f),
                          np.ascontiguousarray(skinning, np.float64), dirs, pinv, dual)


def skin_gaussian_set(rest: GaussianSet, binding: SkinBinding, label: str | None = None) -> GaussianSet:
    """The skinned :class:`GaussianSet` (opacities and extras kept; raw log-scales dropped,
    raw logits kept)."""
    pos, quat, scales, sh, _ = skin_arrays(rest, binding.joint_indices, binding.weights, binding.skinning,
                                           binding.dual)
    return GaussianSet(pos, quat, scales, rest.opacities, sh, None, rest.logit_opacities, dict(rest.extras),
                       label=label or rest.label)


def read_skinned(prim: Usd.Prim, rest: GaussianSet, time=None, world: bool = True) -> GaussianSet:
    """Skin ``rest`` (the prim's bind-pose Gaussians read in prim-local space, untransformed) at ``time``."""
    binding = evaluate_binding(prim, rest.count, time, world)
    return skin_gaussian_set(rest, binding, label=prim.GetPath().pathString)


def skinned_bounds(prim: Usd.Prim, rest_positions: np.ndarray, pad: np.ndarray, time=None):
    """World (min, max) of the skinned centres at ``time``, grown by ``pad`` (3,) (the rest
    extent's margin around the centres); numpy only (describe stays numba-free)."""
    binding = evaluate_binding(prim, len(rest_positions), time, world=True)
    n = len(rest_positions)
    if n == 0:
        return None
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    p = np.asarray(rest_positions, np.float64)
    step = 65536
    for a in range(0, n, step):
        sl = slice(a, min(n, a + step))
        if binding.dual is not None:
            q = dq_positions(p[sl], binding.joint_indices[sl], binding.weights[sl], binding.dual)
            lo = np.minimum(lo, q.min(axis=0))
            hi = np.maximum(hi, q.max(axis=0))
            continue
        blend = np.einsum("nk,nkij->nij", binding.weights[sl].astype(np.float64),
                          binding.skinning[binding.joint_indices[sl]])
        q = np.einsum("nij,nj->ni", blend[:, :3, :3], p[sl]) + blend[:, :3, 3]
        lo = np.minimum(lo, q.min(axis=0))
        hi = np.maximum(hi, q.max(axis=0))
    return lo - pad, hi + pad


def gf_matrix(col_major_4x4: np.ndarray) -> Gf.Matrix4d:
    """``Gf.Matrix4d`` (row-vector) of a column-vector 4x4 numpy matrix."""
    return Gf.Matrix4d(np.asarray(col_major_4x4, np.float64).T.tolist())


# --------------------------------------------------------------------------- authoring
def author_skeleton(stage: Usd.Stage, path, joints: list[str], bind_world: np.ndarray,
                    rest_local: np.ndarray) -> UsdSkel.Skeleton:
    """Define a ``Skeleton``: ``joints`` (UsdSkel joint paths, parents first, e.g. ``"root/spine"``),
    ``bindTransforms`` (J, 4, 4) skeleton-space bind matrices and ``restTransforms`` (J, 4, 4)
    parent-relative rest matrices, both given COLUMN-vector (stored transposed, row-vector)."""
    skel = UsdSkel.Skeleton.Define(stage, Sdf.Path(str(path)))
    skel.CreateJointsAttr(Vt.TokenArray(list(joints)))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(
        np.transpose(np.asarray(bind_world, np.float64), (0, 2, 1)))))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(
        np.transpose(np.asarray(rest_local, np.float64), (0, 2, 1)))))
    return skel


def author_animation(stage: Usd.Stage, path, skeleton: UsdSkel.Skeleton, joints: list[str], times,
                     translations: np.ndarray, rotations: np.ndarray, scales: np.ndarray | None = None
                     ) -> UsdSkel.Animation:
    """Define a ``SkelAnimation`` bound to ``skeleton`` (``skel:animationSource``), time-sampled at
    ``times`` (T,): parent-relative ``translations`` (T, J, 3), ``rotations`` (T, J, 4) (w, x, y, z),
    ``scales`` (T, J, 3) (ones if None)."""
    anim = UsdSkel.Animation.Define(stage, Sdf.Path(str(path)))
    anim.CreateJointsAttr(Vt.TokenArray(list(joints)))
    t_attr, r_attr, s_attr = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr(), anim.CreateScalesAttr()
    tr = np.asarray(translations, np.float32)
    rot = np.asarray(rotations, np.float32)
    sc = np.ones(tr.shape, np.float16) if scales is None else np.asarray(scales, np.float16)
    xyzw = np.ascontiguousarray(np.concatenate([rot[..., 1:], rot[..., :1]], axis=-1))
    with Sdf.ChangeBlock():
        for i, t in enumerate(np.asarray(times, np.float64).reshape(-1)):
            t_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(tr[i])), float(t))
            r_attr.Set(Vt.QuatfArray.FromNumpy(xyzw[i]), float(t))
            s_attr.Set(Vt.Vec3hArray.FromNumpy(np.ascontiguousarray(sc[i])), float(t))
    UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPrim().GetPath()])
    return anim


def bind_prim(prim: Usd.Prim, skeleton: UsdSkel.Skeleton, joint_indices: np.ndarray, weights: np.ndarray,
              geom_bind: np.ndarray | None = None, joints: list[str] | None = None) -> UsdSkel.BindingAPI:
    """Apply ``UsdSkel.BindingAPI`` to ``prim``: ``skel:skeleton``, joint indices/weights (N, K) as
    vertex primvars with elementSize K, optional geomBindTransform (COLUMN-vector 4x4) and
    ``skel:joints``."""
    idx = np.ascontiguousarray(np.asarray(joint_indices, np.int32))
    wts = np.ascontiguousarray(np.asarray(weights, np.float32))
    k = idx.shape[1]
    binding = UsdSkel.BindingAPI.Apply(prim)
    binding.CreateSkeletonRel().SetTargets([skeleton.GetPrim().GetPath()])
    binding.CreateJointIndicesPrimvar(False, k).Set(Vt.IntArray.FromNumpy(idx.reshape(-1)))
    binding.CreateJointWeightsPrimvar(False, k).Set(Vt.FloatArray.FromNumpy(wts.reshape(-1)))
    if geom_bind is not None:
        binding.CreateGeomBindTransformAttr(gf_matrix(geom_bind))
    if joints is not None:
        binding.CreateJointsAttr(Vt.TokenArray(list(joints)))
    return binding


def binding_problems(prim: Usd.Prim, n: int, times) -> list[tuple[str, str, int | None, float | None]]:
    """Validation of a bound prim: [(attribute, message, first bad element, time)] over ``times``
    (time codes; the first problem of each attribute only). Empty when the binding is usable."""
    out = []
    seen = set()
    for tc in times:
        try:
            evaluate_binding(prim, n, tc)
        except BindingError as exc:
            if exc.attribute not in seen:
                seen.add(exc.attribute)
                out.append((exc.attribute, exc.detail, exc.element, None if tc.IsDefault() else float(tc.GetValue())))
            if exc.attribute == SKEL_REL:
                break
    return out

