"""Deep Gaussian Shadow Maps (paper 3.2-3.3) on ``GaussianSet`` inputs: configuration and wrappers, one frame's
shadows of every caster on every receiver, the static scene's shot-long atlas, and the shading arithmetic.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.shadows import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "DGSM": "dgsm",
    "DGSMConfig": "dgsm",
    "build_dgsm": "dgsm",
    "build_dgsm_directional": "dgsm",
    "exact_transmittance": "dgsm",
    "exact_transmittance_directional": "dgsm",
    "footprint_samples": "dgsm",
    "prepare_occluders": "dgsm",
    "roi_box_params": "dgsm",
    "roi_indices": "dgsm",
    "sample_dgsm": "dgsm",
    "shadow_transmittance": "dgsm",
    "attenuation_factor": "shading",
    "combine_lights": "shading",
    "light_shares": "shading",
    "scale_sh": "shading",
    "Receivers": "shot",
    "caster_transmittance": "shot",
    "occluder_sphere": "shot",
    "occluders_toward": "shot",
    "prim_boxes": "shot",
    "prim_spheres": "shot",
    "prims_in_shadow": "shot",
    "receiver_points": "shot",
    "shadow_cone_indices": "shot",
    "shared_transmittance": "shot",
    "toward_mask": "shot",
    "StaticSceneAtlas": "static_scene",
})
