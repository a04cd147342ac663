"""glTF skinned-mesh reader, animation sampling, LBS and the numpy PNG decoder.

References: trimesh's static load of CesiumMan (vertex positions in world space), Pillow
13.0's decode of CesiumMan's texture (channel sums measured once, hard-coded below), an
analytic two-bone bar built in this file, and hand-computed interpolation values.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from usd_gs.errors import InputFormatError
from usd_gs.io.gltf import (
    AnimationChannel,
    load_skinned_mesh,
    loop_period,
    node_global_matrices,
    pose,
    quat_slerp,
    sample_channel,
    skin_matrices,
    srgb_to_linear,
    vertex_normals,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CESIUM = DATA / "humans" / "CesiumMan.glb"


@pytest.fixture(scope="module")
def cesium():
    return load_skinned_mesh(CESIUM)


# ----------------------------------------------------------------------------- CesiumMan
def test_cesium_counts(cesium):
    m = cesium
    assert m.rest_vertices.shape == (3273, 3)  # data README: 3,273 vertices
    assert m.faces.shape == (4672, 3)
    assert m.num_joints == 19  # data README: 19 joints
    assert m.inverse_bind_matrices.shape == (19, 4, 4)
    assert m.joint_names[0] == "Skeleton_torso_joint_1"
    assert len(m.channels) == 57  # 19 joints x (translation, rotation, scale)
    assert all(c.times.size == 48 and c.interpolation == "LINEAR" for c in m.channels)
    assert m.start_time == pytest.approx(1 / 24, abs=1e-6)
    assert m.duration == pytest.approx(2.0, abs=1e-6)
    assert loop_period(m) == pytest.approx(2.0, abs=1e-6)
    np.testing.assert_allclose(m.weights.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-9)
    assert m.uvs.shape == (3273, 2)
    assert m.texture is not None and m.texture.shape == (1024, 1024, 3)


def test_cesium_texture_matches_pillow(cesium):
    # Channel sums of the uint8 image decoded by Pillow 13.0 (measured once, outside the tests).
    pillow_sums = np.array([232303558, 245097956, 242389853])
    m = cesium
    # texture = srgb_to_linear(u8 / 255) * baseColorFactor (1, 1, 1): invert the transfer curve.
    lin = m.texture.astype(np.float64)
    enc = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)
    u8 = np.round(enc * 255).astype(np.int64)
    np.testing.assert_array_equal(u8.sum(axis=(0, 1)), pillow_sums)


def test_rest_pose_matches_trimesh_and_bind(cesium):
    m = cesium
    tm = trimesh.load(CESIUM, force="mesh", process=False)
    # The skeleton's rest TRS is the bind pose: every skinning matrix G @ IBM equals the mesh
    # node's world matrix (the Z_UP root turns the Z-up mesh space into glTF Y-up).
    _, skin = skin_matrices(m, None)
    mesh_world = node_global_matrices(m, None)[m.mesh_node]
    np.testing.assert_allclose(skin, np.broadcast_to(mesh_world, skin.shape), atol=1e-6)
    verts, normals, _ = pose(m, None)
    np.testing.assert_allclose(verts, np.asarray(tm.vertices), atol=1e-5)
    np.testing.assert_array_equal(m.faces, np.asarray(tm.faces))
    world_rest = m.rest_vertices @ mesh_world[:3, :3].T + mesh_world[:3, 3]
    np.testing.assert_allclose(verts, world_rest, atol=1e-5)
    # LBS with the bind pose (G = IBM^-1) is the identity on the mesh-space vertices.
    from usd_gs.io.gltf import skin_vertices
    eye_skin = np.linalg.inv(m.inverse_bind_matrices) @ m.inverse_bind_matrices
    v_bind, _ = skin_vertices(eye_skin, m.joints, m.weights, m.rest_vertices)
    np.testing.assert_allclose(v_bind, m.rest_vertices, atol=1e-5)
    # Skinned normals agree with normals recomputed from the skinned faces.
    ref = vertex_normals(verts, m.faces)
    assert np.mean(np.sum(ref * normals, axis=1)) > 0.95


def test_walk_is_continuous(cesium):
    m = cesium
    dt = 1 / 240
    # 2.4 m/s is well above any limb speed of a walk; one 1/240 s step must stay below 1 cm.
    for t in np.linspace(0.0, 4.5, 23):
        a = pose(m, t, loop=True)[0]
        b = pose(m, t + dt, loop=True)[0]
        assert np.max(np.linalg.norm(b - a, axis=1)) < 0.01, t


def test_walk_cycle_is_periodic(cesium):
    m = cesium
    keys = m.channels[0].times
    frames = [pose(m, t)[0] for t in keys]
    steps = [np.max(np.linalg.norm(frames[i + 1] - frames[i], axis=1)) for i in range(len(frames) - 1)]
    wrap = np.max(np.linalg.norm(frames[0] - frames[-1], axis=1))
    # The clip closes: last key -> first key is an ordinary one-frame step, not a jump.
    assert wrap <= max(steps)
    assert wrap < 0.03
    # Looped pose repeats with the period, and pose(0) (looped) lies between last and first key.
    p = loop_period(m)
    for t in (0.3, 1.1, 1.99):
        np.testing.assert_allclose(pose(m, t, loop=True)[0], pose(m, t + p, loop=True)[0], atol=1e-9)
        np.testing.assert_allclose(pose(m, t, loop=True)[0], pose(m, t)[0], atol=1e-12)
    v0 = pose(m, 0.0, loop=True)[0]
    assert np.max(np.linalg.norm(v0 - frames[0], axis=1)) <= wrap + 1e-9
    assert np.max(np.linalg.norm(v0 - frames[-1], axis=1)) <= wrap + 1e-9
    # Clamped sampling: before the first key = first key.
    np.testing.assert_allclose(pose(m, 0.0)[0], frames[0], atol=1e-12)


def test_walk_stands_on_the_ground_and_has_human_height(cesium):
    m = cesium
    lows, highs = [], []
    for t in np.linspace(0.0, 2.0, 17):
        v = pose(m, t, loop=True)[0]
        lows.append(v[:, 1].min())
        highs.append(v[:, 1].max())
    # Measured: the lowest vertex of each frame lies between y = -0.026 and +0.042 m (the
    # clip's root bobs; there is no foot locking), head top 1.44..1.46 m while walking
    # (1.507 m standing in the rest pose): CesiumMan is a short (1.5 m) figure.
    assert -0.04 < min(lows) and max(lows) < 0.06
    assert 1.40 < min(highs) and max(highs) < 1.52
    rest = pose(m, None)[0]
    assert rest[:, 1].min() == pytest.approx(0.0, abs=1e-4)
    assert rest[:, 1].max() == pytest.approx(1.5065, abs=1e-3)
    # Faces +Z (glTF forward): the feet reach 0.18 m forward of the ankles, 0.08 m back.
    feet = rest[rest[:, 1] < 0.05]
    assert feet[:, 2].max() > 0.15 and feet[:, 2].min() > -0.1
    # Character's left (+X when facing +Z): the left ankle joint is at x > 0.
    ankle_l = m.joint_names.index("leg_joint_L_3")
    assert pose(m, None)[2][ankle_l][0, 3] > 0.05


# ----------------------------------------------------------------------------- interpolation
def _zrot(angle):
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def test_slerp_matches_axis_angle():
    q0, q1 = _zrot(0.2), _zrot(1.4)
    for u in (0.0, 0.25, 0.5, 1.0):
        np.testing.assert_allclose(quat_slerp(q0, q1, u), _zrot(0.2 + u * 1.2), atol=1e-12)
    # Shortest path: -q1 is the same rotation and must give the same result.
    np.testing.assert_allclose(quat_slerp(q0, -q1, 0.5), _zrot(0.8), atol=1e-12)
    # Nearly equal quaternions (lerp branch) stay unit and between.
    q = quat_slerp(_zrot(0.1), _zrot(0.1 + 1e-5), 0.5)
    np.testing.assert_allclose(q, _zrot(0.1 + 0.5e-5), atol=1e-12)


def test_channel_interpolation_modes():
    times = np.array([1.0, 2.0, 4.0])
    vals = np.array([[0.0, 0, 0], [2.0, 0, 0], [2.0, 4, 0]])
    lin = AnimationChannel(0, "translation", "LINEAR", times, vals)
    np.testing.assert_allclose(sample_channel(lin, 1.5), [1.0, 0, 0])
    np.testing.assert_allclose(sample_channel(lin, 3.0), [2.0, 2, 0])
    np.testing.assert_allclose(sample_channel(lin, 0.0), [0.0, 0, 0])  # clamped
    np.testing.assert_allclose(sample_channel(lin, 9.0), [2.0, 4, 0])
    step = AnimationChannel(0, "translation", "STEP", times, vals)
    np.testing.assert_allclose(sample_channel(step, 1.99), [0.0, 0, 0])
    np.testing.assert_allclose(sample_channel(step, 2.0), [2.0, 0, 0])
    # CUBICSPLINE: (in-tangent, value, out-tangent) per key. Hermite with out-tangent m0 and
    # in-tangent m1 (per second, times dt): at u = 0.5, p = (p0 + p1)/2 + dt (m0 - m1)/8.
    cs_vals = np.array([[0, 0, 0], [0.0, 0, 0], [1.0, 0, 0],
                        [3.0, 0, 0], [2.0, 0, 0], [0, 0, 0],
                        [0, 0, 0], [2.0, 4, 0], [0, 0, 0]], float)
    cub = AnimationChannel(0, "translation", "CUBICSPLINE", times, cs_vals)
    np.testing.assert_allclose(sample_channel(cub, 1.5), [1.0 + (1.0 - 3.0) / 8, 0, 0])
    np.testing.assert_allclose(sample_channel(cub, 2.0), [2.0, 0, 0])
    # Loop with period 4: the gap 4..5 runs last -> first key linearly.
    np.testing.assert_allclose(sample_channel(lin, 4.5, period=4.0), [1.0, 2, 0])
    np.testing.assert_allclose(sample_channel(lin, 5.5, period=4.0), sample_channel(lin, 1.5))
    rot = AnimationChannel(0, "rotation", "LINEAR", np.array([0.0, 1.0]), np.stack([_zrot(0.0), _zrot(1.0)]))
    np.testing.assert_allclose(sample_channel(rot, 0.3), _zrot(0.3), atol=1e-12)


# ----------------------------------------------------------------------------- synthetic GLB
def _glb(doc: dict, binary: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _two_bone_bar(tmp_path: Path, image: bytes | None = None, mime: str = "image/png") -> Path:
    """A bar along +x (0..2 m, y = +-0.1) skinned to joint 0 (x < 1) and joint 1 (x > 1,
    pivot at x = 1); x = 1 vertices are weighted 0.5/0.5. Joint 1 rotates about +z from 0
    to 90 degrees over 1 s (LINEAR). The root node carries a matrix (translation +y 5);
    positions and normals are interleaved (byteStride 24); JOINTS_0 uint8; WEIGHTS_0
    normalised uint8."""
    xs = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    pos = np.array([[x, y, 0.0] for x in xs for y in (-0.1, 0.1)], np.float32)
    nrm = np.tile([0.0, 0.0, 1.0], (len(pos), 1)).astype(np.float32)
    inter = np.concatenate([pos, nrm], axis=1).astype("<f4").tobytes()
    joints = np.zeros((len(pos), 4), np.uint8)
    weights = np.zeros((len(pos), 4), np.uint8)
    for i, p in enumerate(pos):
        if p[0] < 1:
            weights[i, 0] = 255
        elif p[0] > 1:
            joints[i, 0], weights[i, 0] = 1, 255
        else:
            joints[i, :2], weights[i, :2] = (0, 1), (128, 127)
    faces = []
    for k in range(len(xs) - 1):
        a, b, c, d = 2 * k, 2 * k + 1, 2 * k + 2, 2 * k + 3
        faces += [a, c, b, b, c, d]
    idx = np.array(faces, "<u2").tobytes()
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[1, 0, 3] = -1.0  # inverse of the joint-1 translation (1, 0, 0), column-vector form
    ibm_b = ibm.transpose(0, 2, 1).astype("<f4").tobytes()  # glTF is column-major
    times = np.array([0.0, 1.0], "<f4").tobytes()
    s = np.sin(np.pi / 4)
    rots = np.array([[0, 0, 0, 1], [0, 0, s, s]], "<f4").tobytes()  # glTF (x, y, z, w)
    chunks = [inter, joints.tobytes(), weights.tobytes(), idx, ibm_b, times, rots]
    uvs = np.stack([pos[:, 0] / 2.0, np.full(len(pos), 0.5)], axis=1).astype("<f4").tobytes()
    if image is not None:
        chunks += [uvs, image]
    views, blob = [], b""
    for i, c in enumerate(chunks):
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(c)}
        if i == 0:
            view["byteStride"] = 24
        views.append(view)
        blob += c + b"\0" * (-len(c) % 4)
    n = len(pos)
    acc = [
        {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": n, "type": "VEC3"},
        {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": n, "type": "VEC3"},
        {"bufferView": 1, "componentType": 5121, "count": n, "type": "VEC4"},
        {"bufferView": 2, "componentType": 5121, "normalized": True, "count": n, "type": "VEC4"},
        {"bufferView": 3, "componentType": 5123, "count": len(faces), "type": "SCALAR"},
        {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"},
        {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR"},
        {"bufferView": 6, "componentType": 5126, "count": 2, "type": "VEC4"},
    ]
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [
            {"name": "root", "children": [1, 3], "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 5, 0, 1]},
            {"name": "j0", "children": [2]},
            {"name": "j1", "translation": [1, 0, 0]},
            {"name": "bar", "mesh": 0, "skin": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "JOINTS_0": 2, "WEIGHTS_0": 3},
                                    "indices": 4}]}],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 5}],
        "animations": [{"channels": [{"sampler": 0, "target": {"node": 2, "path": "rotation"}}],
                        "samplers": [{"input": 6, "output": 7, "interpolation": "LINEAR"}]}],
        "buffers": [{"byteLength": len(blob)}], "bufferViews": views, "accessors": acc,
    }
    if image is not None:
        acc.append({"bufferView": 7, "componentType": 5126, "count": n, "type": "VEC2"})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 8
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 1.0],
                                                      "baseColorTexture": {"index": 0}}}]
        doc["textures"] = [{"source": 0}]
        doc["images"] = [{"bufferView": 8, "mimeType": mime}]
    path = tmp_path / "bar.glb"
    path.write_bytes(_glb(doc, blob))
    return path


def test_two_bone_bar_analytic(tmp_path):
    m = load_skinned_mesh(_two_bone_bar(tmp_path))
    assert m.rest_vertices.shape == (10, 3) and m.faces.shape == (8, 3)
    np.testing.assert_allclose(m.weights[4, :2], [128 / 255, 127 / 255], atol=1e-12)  # x = 1, y = -0.1
    lift = np.array([0.0, 5.0, 0.0])  # the root matrix
    v, n, joint_world = pose(m, 0.0)
    np.testing.assert_allclose(v, m.rest_vertices + lift, atol=1e-6)
    np.testing.assert_allclose(joint_world[1][:3, 3], [1.0, 5.0, 0.0], atol=1e-12)
    for t, ang in ((1.0, np.pi / 2), (0.5, np.pi / 4)):
        v, n, _ = pose(m, t)
        c, s = np.cos(ang), np.sin(ang)
        for i, p in enumerate(m.rest_vertices):
            q = np.array([1 + c * (p[0] - 1) - s * p[1], s * (p[0] - 1) + c * p[1], 0.0])  # about pivot (1, 0)
            w1 = 0.0 if p[0] < 1 else (1.0 if p[0] > 1 else 127 / 255)
            expect = (1 - w1) * p + w1 * q + lift
            np.testing.assert_allclose(v[i], expect, atol=1e-6)
        np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (10, 1)), atol=1e-9)  # rotation about z


def test_texture_and_base_colour(tmp_path):
    # A 2x1 PNG (sRGB 255 and 128 grey) modulated by baseColorFactor (linear) (0.5, 0.25, 1).
    img = np.array([[[255, 255, 255], [128, 128, 128]]])
    m = load_skinned_mesh(_two_bone_bar(tmp_path, _encode_png(img)))
    assert m.texture.shape == (1, 2, 3) and m.texture_note == ""
    np.testing.assert_allclose(m.base_color, [0.5, 0.25, 1.0])
    lin128 = ((128 / 255 + 0.055) / 1.055) ** 2.4
    np.testing.assert_allclose(m.texture[0], [[0.5, 0.25, 1.0], [0.5 * lin128, 0.25 * lin128, lin128]], rtol=1e-6)
    np.testing.assert_allclose(m.uvs[:, 1], 0.5)
    # An undecodable image falls back to the base colour, with a note naming the image.
    m2 = load_skinned_mesh(_two_bone_bar(tmp_path, b"\xff\xd8 not really a jpeg", "image/jpeg"))
    assert m2.texture is None and "images[0]" in m2.texture_note
    np.testing.assert_allclose(m2.base_color, [0.5, 0.25, 1.0])


def test_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"NOPE" + b"\0" * 40)
    with pytest.raises(InputFormatError, match="bad.glb.*magic"):
        load_skinned_mesh(bad)
    short = tmp_path / "short.glb"
    short.write_bytes(CESIUM.read_bytes()[:5000])
    with pytest.raises(InputFormatError, match="short.glb"):
        load_skinned_mesh(short)
    doc = {"asset": {"version": "2.0"}, "nodes": [{"mesh": 0, "skin": 0}]}
    broken = tmp_path / "broken.glb"
    broken.write_bytes(_glb(doc, b""))
    with pytest.raises(InputFormatError, match="broken.glb: malformed glTF"):
        load_skinned_mesh(broken)
    with pytest.raises(InputFormatError, match="not found"):
        load_skinned_mesh(tmp_path / "missing.glb")


def _encode_png(img: np.ndarray) -> bytes:
    """8-bit RGB PNG bytes written by Pillow."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img.astype(np.uint8), "RGB").save(buf, format="PNG")
    return buf.getvalue()


def test_srgb_to_linear_reference_points():
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, 0.21404114048223255, 1.0], rtol=1e-12)
