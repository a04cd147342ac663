"""Rendering Gaussians with the CPU splat rasteriser: cameras, cube faces, images and previews of stages.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.render import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "Camera": "camera",
    "cube_face_cameras": "camera",
    "RenderResult": "preview",
    "camera_prims": "preview",
    "drawn_gaussian_prims": "preview",
    "framing_camera": "preview",
    "gaussian_framing_bounds": "preview",
    "gaussian_world_bounds": "preview",
    "input_stage": "preview",
    "input_stage_path": "preview",
    "is_drawn": "preview",
    "read_stage_gaussians": "preview",
    "render_stage_frame": "preview",
    "resolve_camera": "preview",
    "side_by_side": "preview",
    "stage_label": "preview",
    "cube_faces_cross": "rasterize",
    "render": "rasterize",
    "render_batch": "rasterize",
    "render_cube_faces": "rasterize",
    "to_srgb8": "rasterize",
    "write_png": "rasterize",
})
