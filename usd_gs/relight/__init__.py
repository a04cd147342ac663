"""Relighting (paper 3.1, 3.4-3.5): light estimation, SH probes and their parallax correction, SH/ZH transfer,
and the main job's relighting of one avatar or object.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.relight import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "relight_factors": "avatar",
    "EstimatedLight": "light_estimation",
    "LightEstimationConfig": "light_estimation",
    "estimate_lights": "light_estimation",
    "make_viewpoints": "light_estimation",
    "CubeTexels": "parallax",
    "ProbeBlend": "parallax",
    "blend_weights": "parallax",
    "cluster_centres": "parallax",
    "cube_texels": "parallax",
    "nearest_centre": "parallax",
    "probe_clusters": "parallax",
    "reprojected_probes": "parallax",
    "SHProbe": "probe",
    "fit_probe": "probe",
    "hdr_dome_gaussians": "probe",
    "probe_from_latlong": "probe",
    "render_probe_faces": "probe",
    "rh_to_3dgs": "probe",
    "probe_rh": "transfer",
    "relight_gaussians": "transfer",
    "relight_scale": "transfer",
    "relight_sh": "transfer",
    "zh_colors": "transfer",
    "zh_relight_gaussians": "transfer",
})
