"""File formats: 3DGS captures (INRIA PLY, SPZ, .splat, compressed PLY, SOG, frame sequences), glTF skins,
environment images, and atomic file output. numpy in, ``GaussianSet`` out; no USD.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.io import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "atomic_output": "atomic",
    "is_compressed_ply": "compressed_ply",
    "read_compressed_ply": "compressed_ply",
    "cube_faces_to_latlong": "envmap",
    "directions_to_latlong_pixel": "envmap",
    "downsample_latlong": "envmap",
    "latlong_directions": "envmap",
    "latlong_lookup": "envmap",
    "latlong_solid_angles": "envmap",
    "latlong_to_cube_faces": "envmap",
    "project_latlong_to_sh": "envmap",
    "read_envmap": "envmap",
    "read_exr": "envmap",
    "read_hdr": "envmap",
    "sh_to_latlong": "envmap",
    "write_cube_faces_latlong": "envmap",
    "write_exr": "envmap",
    "AnimationChannel": "gltf",
    "SkinnedMesh": "gltf",
    "load_skinned_mesh": "gltf",
    "loop_period": "gltf",
    "node_global_matrices": "gltf",
    "pose": "gltf",
    "quat_slerp": "gltf",
    "sample_channel": "gltf",
    "skin_matrices": "gltf",
    "skin_vertices": "gltf",
    "srgb_to_linear": "gltf",
    "trs_matrices": "gltf",
    "vertex_normals": "gltf",
    "read_ply": "ply",
    "write_ply": "ply",
    "read_lod_set": "sog",
    "read_sog": "sog",
    "decode_splat": "splat",
    "encode_splat": "splat",
    "read_splat": "splat",
    "write_splat": "splat",
    "read_spz": "spz",
    "write_spz": "spz",
})
