"""``--bake-skinning``: skinned Gaussians of a bound prim baked into time samples (``usd_gs.usd.skel``)."""

from __future__ import annotations

from pxr import Sdf, Usd, UsdSkel

from usd_gs.usd.gaussian_prim import RAW_LOG_SCALES, RAW_LOGIT_OPACITIES, read_gaussian_prim, write_gaussian_prim
from usd_gs.usd.skel import SKEL_REL, BindingError, clear_caches, has_skel_binding


def bake_skinning(stage: Usd.Stage, prim_path, times) -> int:
    """Author the skinned Gaussians of a bound prim as time samples in ``stage``'s edit target
    (``--bake-skinning``: for viewers without UsdSkel support for splats), and block the binding
    there (``skel:skeleton`` with an empty target list) so that every reader, UsdSkel-aware or
    not, sees the baked values and nothing is skinned twice.

    At each time code of ``times`` the prim is read as it composes now (bind pose, any SH the edit
    target already holds, e.g. relit SH authored in bind space), skinned in prim-local space (the
    prim's own transform then applies to the baked values, as for any unbound prim), and written
    with ``write_gaussian_prim`` (positions, orientations, scales, opacities, SH rotated per
    Gaussian, extent). All frames are read before the binding is blocked. Returns the number of
    frames written; raises ``BindingError`` like :func:`evaluate_binding`.
    """
    prim = stage.GetPrimAtPath(Sdf.Path(str(prim_path)))
    if not prim or not has_skel_binding(prim):
        raise BindingError(str(prim_path), SKEL_REL, "is not a skinned Gaussian prim (no UsdSkel binding)")
    frames = [(float(t), read_gaussian_prim(prim, float(t), world=False)) for t in times]
    UsdSkel.BindingAPI(prim).GetSkeletonRel().SetTargets([])
    for name in (RAW_LOG_SCALES, RAW_LOGIT_OPACITIES):  # the bind pose's raw PLY values no longer apply
        if prim.HasAttribute(name):
            prim.GetAttribute(name).Block()
    for t, g in frames:
        write_gaussian_prim(stage, prim.GetPath(), g, time=t, keep_raw=False)
    clear_caches()
    return len(frames)
