"""The demo shot generator (``usdgs demo make``): the generated room, Gaussian avatars from skinned meshes.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.demo import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "barycentric_points": "mesh_avatar",
    "bilinear": "mesh_avatar",
    "face_areas": "mesh_avatar",
    "gaussians_on_mesh": "mesh_avatar",
    "posed_avatar_frames": "mesh_avatar",
    "posed_meshes": "mesh_avatar",
    "sample_colors": "mesh_avatar",
    "sample_surface": "mesh_avatar",
    "tangent_frames": "mesh_avatar",
    "Box": "room",
    "DetailRegion": "room",
    "Lamp": "room",
    "RoomScene": "room",
    "default_boxes": "room",
    "make_room": "room",
    "CirclePath": "stage",
    "DemoOptions": "stage",
    "DemoResult": "stage",
    "canonical_matrix": "stage",
    "data_folder_for": "stage",
    "data_search_paths": "stage",
    "frame_times": "stage",
    "generator_string": "stage",
    "locate_data_dir": "stage",
    "look_at_matrix": "stage",
    "make_demo": "stage",
    "room_detail": "stage",
    "rotation_y": "stage",
    "usd_matrix": "stage",
})
