"""glTF scenes carry what TOML scenes carry: drives, start velocities, volumes, models, lights,
render settings and rotating kinematic bodies, from the extras and extensions stock Blender
writes (GLB files written here with trimesh and JSON edits).

Truths: each glTF scene and its TOML equivalent, written by hand, read into the same
:class:`~softvr.scene.SceneFile` fields and build the same bodies; independently of both, a
drive moves the held nodes by its offsets linearly interpolated at t, a start velocity is
v + w x (x - c) at every free node, a box keyed at 0 deg and 90 deg about the vertical has its
corners where scipy's Rotation turns them (slerp: linear angle) about its linearly moving
position, a directional light on a node turned -90 deg about x shines straight down (glTF
lights shine along their node's -z), a point light at the origin's side shines at the origin,
and Blender's default light strengths (sun 1 W/m^2 = 683 lux, lamp 1000 W = 683 1000 / (4 pi)
cd) have intensity 1; bad values are all named, by node, in one error.
"""

import json
import struct

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.scene import load_scene, read_scene
from softvr.scene.gltf import read_gltf_scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def _about(axis, degrees):
    """glTF quaternion (x, y, z, w) of a turn about a unit ``axis`` [3] (glTF y-up) [deg]."""
    half = np.radians(degrees) / 2
    return (*(np.sin(half) * np.asarray(axis, float)), np.cos(half))


def _glb(path, boxes, empties=(), lights=(), animations=(), scene_extras=None):
    """A GLB as Blender's exporter writes it: box meshes on nodes ``(name, size, translation,
    rotation, extras)`` (glTF y-up; rotation a quaternion x, y, z, w), Empties ``(name,
    extras)`` (nodes without a mesh), KHR_lights_punctual ``lights`` ``(name, translation,
    rotation, light)`` and ``animations`` ``(node name, path, times [k], values [k, 3 or 4])``
    (LINEAR), custom properties as ``extras``."""
    import trimesh

    scene = trimesh.Scene()
    for name, size, *_ in boxes:
        scene.add_geometry(trimesh.creation.box(size), node_name=name, geom_name=f"{name} mesh")
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    binary = bytearray(data[28 + length:28 + length + struct.unpack("<I", data[20 + length:24 + length])[0]])
    index = {}
    for i, node in enumerate(doc["nodes"]):
        _, _, translation, rotation, extras = next(b for b in boxes if b[0] == node["name"])
        node.pop("matrix", None)  # animated nodes carry translation, rotation, scale (glTF 2.0)
        node.update(translation=list(translation), rotation=list(rotation))
        if extras:
            node["extras"] = extras
        index[node["name"]] = i

    def add(node):
        doc["nodes"].append(node)
        doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
        index[node["name"]] = len(doc["nodes"]) - 1

    for name, extras in empties:
        add({"name": name, "extras": extras})
    if lights:
        doc["extensionsUsed"] = ["KHR_lights_punctual"]
        doc["extensions"] = {"KHR_lights_punctual": {"lights": [light for *_, light in lights]}}
        for k, (name, translation, rotation, _) in enumerate(lights):
            add({"name": name, "translation": list(translation), "rotation": list(rotation),
                 "extensions": {"KHR_lights_punctual": {"light": k}}})

    def accessor(values, kind):
        values = np.asarray(values, "<f4")
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": values.nbytes})
        binary.extend(values.tobytes())
        binary.extend(b"\0" * (-len(binary) % 4))
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                                 "count": len(values), "type": kind})
        return len(doc["accessors"]) - 1

    for name, target, times, values in animations:
        doc.setdefault("animations", []).append({
            "channels": [{"sampler": 0, "target": {"node": index[name], "path": target}}],
            "samplers": [{"input": accessor(times, "SCALAR"), "output": accessor(values, f"VEC{len(values[0])}"),
                          "interpolation": "LINEAR"}]})
    if scene_extras:
        doc["scenes"][0]["extras"] = scene_extras
    doc["buffers"][0]["byteLength"] = len(binary)
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path


def _toml(path, text):
    path.write_text('format = "softvr-scene 1"\n' + text)
    return path


def _sorted(points):
    points = np.asarray(points)
    return points[np.lexsort(np.round(points, 9).T)]


def test_drives_and_start_velocities_read_and_build_as_the_equivalent_toml(tmp_path):
    """A gel cube (0.1 m, centre at z = 0.05) with its top nodes held and driven 10 mm down over
    0.1 s, thrown at 0.1 m/s spinning at 2 rad/s about a vertical axis through (0, 0.01, 0.05);
    a rigid die thrown with it. No gravity, so only the drive moves the held nodes."""
    import trimesh

    motion = {"softvr_velocity": [0.1, 0.0, 0.0], "softvr_angular_velocity": [0.0, 0.0, 2.0]}
    path = _glb(tmp_path / "driven.glb", [
        ("gel", (0.1, 0.1, 0.1), (0.0, 0.05, 0.0), IDENTITY, {
            "softvr_type": "fem", "softvr_young": 2e4, "softvr_density": 900.0, "softvr_cells": 0.045,
            "softvr_fixed_above": 0.09, "softvr_spin_centre": [0.0, 0.01, 0.05], "softvr_drive_times": [0.0, 0.1],
            "softvr_drive_offsets": [0.0, 0.0, 0.0, 0.0, 0.0, -0.01], **motion}),
        ("die", (0.02, 0.02, 0.02), (0.3, 0.01, 0.0), IDENTITY, {
            "softvr_type": "rigid", "softvr_density": 500.0, **motion})],
        scene_extras={"softvr_dt": 0.01, "softvr_steps_per_frame": 1, "softvr_ground": 0,
                      "softvr_gravity": [0.0, 0.0, 0.0]})
    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "gel.obj")
    toml = _toml(tmp_path / "driven.toml", '''
[simulation]
dt = 0.01
steps_per_frame = 1
gravity = [0.0, 0.0, 0.0]
[material.gel]
young = 2e4
density = 900.0
[material.die]
density = 500.0
[[body]]
name = "gel"
type = "fem"
mesh = "gel.obj"
cells = 0.045
material = "gel"
position = [0.0, 0.0, 0.05]
fixed_above = 0.09
velocity = [0.1, 0.0, 0.0]
angular_velocity = [0.0, 0.0, 2.0]
spin_centre = [0.0, 0.01, 0.05]
[body.drive]
times = [0.0, 0.1]
offsets = [[0.0, 0.0, 0.0], [0.0, 0.0, -0.01]]
[[body]]
name = "die"
type = "rigid"
box = [0.02, 0.02, 0.02]
material = "die"
position = [0.3, 0.0, 0.01]
velocity = [0.1, 0.0, 0.0]
angular_velocity = [0.0, 0.0, 2.0]
''')
    g, t = read_gltf_scene(path), read_scene(toml)
    for key in ("dt", "steps_per_frame", "gravity", "friction", "pgs_iterations", "contact_margin"):
        assert g.simulation[key] == t.simulation[key], key
    for name in ("gel", "die"):
        a, b = g.body(name), t.body(name)
        np.testing.assert_allclose(a.position, b.position, atol=1e-7)
        for key in ("velocity", "angular_velocity", "spin_centre", "fixed_above", "fixed_below"):
            assert getattr(a, key) == getattr(b, key), (name, key)
    assert g.body("gel").drive == t.body("gel").drive == {"times": [0.0, 0.1],
                                                         "offsets": [[0.0, 0.0, 0.0], [0.0, 0.0, -0.01]]}
    with load_scene(path) as a, load_scene(toml) as b:
        ga, gb = a.bodies["gel"], b.bodies["gel"]
        np.testing.assert_allclose(_sorted(ga.q), _sorted(gb.q), atol=1e-7)
        assert ga.mass.sum() == pytest.approx(gb.mass.sum(), rel=1e-6)
        held = ga.fixed.copy()
        assert 0 < held.sum() < len(held) and held.sum() == gb.fixed.sum()
        np.testing.assert_array_equal(held, ga.q[:, 2] > 0.09)
        spin = np.array([0.1, 0.0, 0.0]) + np.cross([0.0, 0.0, 2.0], ga.q - [0.0, 0.01, 0.05])
        np.testing.assert_allclose(ga.v[~held], spin[~held], atol=1e-12)
        np.testing.assert_allclose(ga.v[held], 0.0)
        for ex in (a, b):
            die = ex.bodies["die"]
            np.testing.assert_allclose(die.velocity, [0.1, 0.0, 0.0])
            np.testing.assert_allclose(die.angular_velocity, [0.0, 0.0, 2.0])
        assert a.bodies["die"].mass == pytest.approx(b.bodies["die"].mass, rel=1e-5)
        start = ga.q[held].copy()
        for frame in range(1, 16):  # to 0.15 s: 5 mm down at 0.05 s, 10 mm from 0.1 s on
            a.step()
            t_now = 0.01 * frame
            np.testing.assert_allclose(ga.q[held] - start, [[0.0, 0.0, -0.01 * min(t_now / 0.1, 1.0)]] * len(start),
                                       atol=1e-9)


def test_a_box_with_rotation_keys_turns_as_scipy_says_in_toml_and_gltf(tmp_path):
    """A 0.2 x 0.05 x 0.1 m kinematic box (z-up sizes) at rest turned 45 deg about the vertical
    in glTF (the keys, not the rest, set its orientation): rotation keys 0 deg at 0.5 s and 90 deg
    about glTF's y (softvr's z) at 1.5 s, translation keys 0.2 m along x from 0.5 s to 2.5 s.
    Both channels sampled at the union of their times (0, 1, 2 s after the first key) make the
    TOML motion; at every step the corners are Rz(90 min(t, 1)) of the half-sizes about the
    linearly moving position, and the body turns at pi/2 rad/s while it turns."""
    from scipy.spatial.transform import Rotation

    up = (0.0, 1.0, 0.0)  # glTF's up: softvr's z
    path = _glb(tmp_path / "turn.glb", [
        ("probe", (0.2, 0.1, 0.05), (0.0, 0.3, 0.0), _about(up, 45.0), {"softvr_type": "kinematic"})],
        animations=[("probe", "rotation", [0.5, 1.5], [IDENTITY, _about(up, 90.0)]),
                    ("probe", "translation", [0.5, 2.5], [(0.0, 0.3, 0.0), (0.2, 0.3, 0.0)])],
        scene_extras={"softvr_dt": 0.05, "softvr_steps_per_frame": 1, "softvr_ground": False})
    toml = _toml(tmp_path / "turn.toml", '''
[simulation]
dt = 0.05
steps_per_frame = 1
[[body]]
name = "probe"
type = "kinematic"
box = [0.2, 0.05, 0.1]
position = [0.0, 0.0, 0.3]
[body.motion]
times = [0.0, 1.0, 2.0]
positions = [[0.0, 0.0, 0.3], [0.1, 0.0, 0.3], [0.2, 0.0, 0.3]]
rotations = [[0.0, 0.0, 0.0], [0.0, 0.0, 90.0], [0.0, 0.0, 90.0]]
''')
    g, t = read_gltf_scene(path).body("probe"), read_scene(toml).body("probe")
    for key in ("times", "positions", "rotations"):
        np.testing.assert_allclose(g.motion[key], t.motion[key], atol=1e-5)
    np.testing.assert_allclose(g.rotation, t.rotation, atol=1e-5)  # the keyed start, not the rest
    np.testing.assert_allclose(g.position, t.position, atol=1e-7)
    half = np.array([0.1, 0.025, 0.05])
    corners = half * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    with load_scene(path) as a, load_scene(toml) as b:
        for frame in range(1, 51):
            a.step()
            b.step()
            time = 0.05 * frame
            truth = Rotation.from_euler("z", 90.0 * min(time, 1.0), degrees=True).apply(corners) + [
                0.1 * min(time, 2.0), 0.0, 0.3]
            for ex in (a, b):
                np.testing.assert_allclose(_sorted(ex._drawn_by_name["probe"].vertices()), _sorted(truth), atol=2e-6)
            if time < 1.0:
                np.testing.assert_allclose(a.bodies["probe"].v[3:], [0.0, 0.0, np.pi / 2], atol=1e-4)


def test_a_volume_node_builds_the_volume_of_the_equivalent_toml(tmp_path):
    """A 20^3 CT (.npy, 2 mm voxels) of a soft-tissue ball (40 HU in -1000 HU air) as an Empty
    with the [volume] fields as properties (Blender's 0 / 1 booleans, int arrays as lists), a
    post coupled to it at a point and colliding with it only: the same volume, tets, masses and
    springs as the TOML scene."""
    grid = np.indices((20, 20, 20)).transpose(1, 2, 3, 0) - 9.5
    np.save(tmp_path / "ct.npy", np.where(np.linalg.norm(grid, axis=-1) < 7.0, 40, -1000).astype(np.int16))
    post = {"softvr_type": "kinematic", "softvr_collides_with": "ball", "softvr_couple_to": "ball",
            "softvr_coupling_points": [0.019, 0.019, 0.03], "softvr_coupling_stiffness": 100.0,
            "softvr_coupling_collide": 1}
    path = _glb(tmp_path / "ct.glb", [("post", (0.01, 0.01, 0.01), (0.019, 0.045, -0.019), IDENTITY, post)],
                empties=[("ball", {"softvr_type": "volume", "softvr_file": "ct.npy", "softvr_unit": 0.002,
                                   "softvr_cells": [4, 4, 4], "softvr_threshold": -300.0,
                                   "softvr_skin_triangles": 200, "softvr_fix_denser_than": 1150.0,
                                   "softvr_alpha": 1.0, "softvr_preset": "ct-skin", "softvr_render_step": 1,
                                   "softvr_mask": 1, "softvr_incremental": 0})],
                scene_extras={"softvr_ground": False})
    toml = _toml(tmp_path / "ct.toml", '''
[volume]
file = "ct.npy"
name = "ball"
unit = 0.002
cells = [4, 4, 4]
threshold = -300.0
skin_triangles = 200
fix_denser_than = 1150.0
alpha = 1.0
preset = "ct-skin"
render_step = 1
mask = true
incremental = false
[[body]]
name = "post"
type = "kinematic"
box = [0.01, 0.01, 0.01]
position = [0.019, 0.019, 0.045]
collides_with = ["ball"]
[body.motion]
times = [0.0]
positions = [[0.019, 0.019, 0.045]]
[[coupling]]
a = "post"
b = "ball"
points = [[0.019, 0.019, 0.03]]
stiffness = 100.0
collide = true
''')
    g, t = read_gltf_scene(path), read_scene(toml)
    assert g.volume == t.volume and g.volume["incremental"] is False
    assert g.couplings == t.couplings and g.body("post").collides_with == ("ball",)
    with load_scene(path, frames=1) as a, load_scene(toml, frames=1) as b:
        va, vb = a.bodies["ball"], b.bodies["ball"]
        np.testing.assert_array_equal(va.q, vb.q)
        np.testing.assert_array_equal(va.tets, vb.tets)
        np.testing.assert_allclose(va.mass, vb.mass)
        assert a.volume is not None and a.volume.spec == b.volume.spec
        (ca,), (cb,) = a.scene.couplings, b.scene.couplings
        np.testing.assert_allclose(ca.b.positions(), cb.b.positions(), atol=1e-12)
        assert a.scene.collision_enabled(a.index["post"], a.index["ball"])


def test_a_volumes_labels_renderer_and_the_video_rate_read_alike_from_toml_and_gltf(tmp_path):
    """palpation.toml's drawing keys, written by hand in both formats: ``[volume]`` labels (a
    segmentation file), mapper and sample_distance, and ``[render] fps``; what was written is
    what both read, the played scene's video rate is the written one (not 1 / (dt
    steps_per_frame) = 100 / s), and typos and bad values are named alike, all at once."""
    grid = np.linalg.norm(np.indices((20, 20, 20)).transpose(1, 2, 3, 0) - 9.5, axis=-1)
    np.save(tmp_path / "ct.npy", np.where(grid < 7.0, 40, -1000).astype(np.int16))
    np.save(tmp_path / "labels.npy", (grid < 7.0).astype(np.uint8))
    volume = {"softvr_type": "volume", "softvr_file": "ct.npy", "softvr_unit": 0.002, "softvr_cells": [4, 4, 4],
              "softvr_labels": "labels.npy", "softvr_mapper": "cpu", "softvr_sample_distance": 0.75}
    scene = {"softvr_ground": False, "softvr_fps": 12.0, "softvr_dt": 0.01, "softvr_steps_per_frame": 1}
    scenery = [("lamp", (0.01, 0.01, 0.01), (0.1, 0.1, 0.1), IDENTITY, {})]  # no softvr properties: not simulated
    path = _glb(tmp_path / "ct.glb", scenery, empties=[("ball", volume)], scene_extras=scene)
    toml = _toml(tmp_path / "ct.toml", '''
[simulation]
dt = 0.01
steps_per_frame = 1
[render]
fps = 12.0
[volume]
file = "ct.npy"
name = "ball"
unit = 0.002
cells = [4, 4, 4]
labels = "labels.npy"
mapper = "cpu"
sample_distance = 0.75
''')
    g, t = read_gltf_scene(path), read_scene(toml)
    assert g.volume == t.volume
    assert (t.volume["labels"], t.volume["mapper"], t.volume["sample_distance"]) == (tmp_path / "labels.npy", "cpu",
                                                                                      0.75)
    assert g.render["fps"] == t.render["fps"] == 12.0
    with load_scene(toml, frames=1) as played:
        assert played.fps == 12.0
    bad_volume = {**volume, "softvr_lables": "labels.npy", "softvr_mapper": "gpu", "softvr_sample_distance": 0.0,
                  "softvr_labels": "none.npy"}
    with pytest.raises(InputError) as gltf:
        read_gltf_scene(_glb(tmp_path / "bad.glb", scenery, empties=[("ball", bad_volume)],
                             scene_extras={**scene, "softvr_fps": -1.0}))
    (tmp_path / "bad.toml").write_text(toml.read_text().replace("fps = 12.0", "fps = -1.0").replace(
        'labels = "labels.npy"', 'labels = "none.npy"\nlables = "labels.npy"').replace('"cpu"', '"gpu"').replace(
        "0.75", "0.0"))
    with pytest.raises(InputError) as text:
        read_scene(tmp_path / "bad.toml")
    expected = {"fps": ("a number > 0 [frames/s]", "-1.0"),
                "lables": ("a known key (did you mean 'labels'?)", "'lables'"),
                "mapper": ("auto | warp | cpu", "gpu"),
                "sample_distance": ("a number > 0 [voxels]", "0.0")}
    for problems, volume_at, render_at in ((text.value.problems, "volume.", "render."),
                                           (gltf.value.problems, "node 'ball'.", "scene.")):
        found = {what: (e, f) for what, e, f in problems}
        for key, value in expected.items():
            assert found[(render_at if key == "fps" else volume_at) + key] == value, (key, found)
        assert found[volume_at + "labels"][1].startswith("no file "), found
        assert len(problems) == 5, found


_PARTS = '''format = "softvr-parts 1"
[[part]]
name = "bone"
mesh = "bone.stl"
kind = "fixed"
[[part]]
name = "pad"
mesh = "pad.stl"
kind = "soft"
cell_size = 0.03
young = 2e4
[[coupling]]
a = "pad"
b = "bone"
radius = 0.005
stiffness = 1000.0
'''


def test_a_model_node_builds_the_parts_of_the_equivalent_toml(tmp_path):
    """A parts file of a fixed bone plate and a soft pad 2 mm above it, as an Empty with
    ``softvr_file`` and a per-part opacity; a probe coupled to the pad at a point and colliding
    with the pad only: the same parts, masses, couplings and collision pairs as the TOML."""
    import trimesh

    trimesh.creation.box((0.1, 0.1, 0.02), trimesh.transformations.translation_matrix((0, 0, 0.01))).export(
        tmp_path / "bone.stl")
    trimesh.creation.box((0.06, 0.06, 0.06), trimesh.transformations.translation_matrix((0, 0, 0.052))).export(
        tmp_path / "pad.stl")
    (tmp_path / "parts.toml").write_text(_PARTS)
    probe = {"softvr_type": "kinematic", "softvr_collides_with": "pad", "softvr_couple_to": "pad",
             "softvr_coupling_points": [0.0, 0.0, 0.08], "softvr_coupling_stiffness": 50.0,
             "softvr_coupling_collide": True}
    path = _glb(tmp_path / "model.glb", [("probe", (0.02, 0.02, 0.02), (0.0, 0.1, 0.0), IDENTITY, probe)],
                empties=[("arm", {"softvr_type": "model", "softvr_file": "parts.toml",
                                  "softvr_opacity": {"pad": 0.5}})])
    toml = _toml(tmp_path / "model.toml", '''
[[plane]]
[[model]]
file = "parts.toml"
opacity = { pad = 0.5 }
[[body]]
name = "probe"
type = "kinematic"
box = [0.02, 0.02, 0.02]
position = [0.0, 0.0, 0.1]
collides_with = ["pad"]
[body.motion]
times = [0.0]
positions = [[0.0, 0.0, 0.1]]
[[coupling]]
a = "probe"
b = "pad"
points = [[0.0, 0.0, 0.08]]
stiffness = 50.0
collide = true
''')
    g, t = read_gltf_scene(path), read_scene(toml)
    assert g.models == t.models and g.model_parts() == {"bone": "fixed", "pad": "soft"}
    assert g.couplings == t.couplings
    with load_scene(path, frames=1) as a, load_scene(toml, frames=1) as b:
        assert set(a.bodies) == set(b.bodies) == {"bone", "pad", "probe"}
        np.testing.assert_allclose(a.bodies["pad"].mass, b.bodies["pad"].mass)
        assert [len(c) for c in a.scene.couplings] == [len(c) for c in b.scene.couplings]
        assert len(a.scene.couplings) == 2  # the parts' springs and the probe's
        for ex in (a, b):
            assert ex.scene.collision_enabled(ex.index["probe"], ex.index["pad"])
            assert not ex.scene.collision_enabled(ex.index["probe"], ex.index["bone"])
        assert a._drawn_by_name["pad"].opacity == 0.5


class _Lights:
    """A renderer that records the lights a scene adds (and accepts the rest)."""

    def __init__(self):
        self.lights = []

    def add_light(self, position, focal_point, color, intensity):
        self.lights.append((position, focal_point, color, intensity))

    def add_mesh(self, *args, **kwargs):
        return 0

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def test_lights_and_render_settings_read_and_build_as_the_equivalent_toml(tmp_path):
    """A sun above (1, 2) at z = 3 turned -90 deg about x: it shines straight down; a 500 W lamp
    (intensity 0.5) shines at the origin; a 2000 W spot under a parent 0.3 m along x shines
    down; scene extras are the [render] table."""
    down = _about((1.0, 0.0, 0.0), -90.0)
    path = _glb(tmp_path / "lit.glb", [("post", (0.1, 0.1, 0.1), (0.0, 0.05, 0.0), IDENTITY,
                                        {"softvr_type": "kinematic"})],
                lights=[("Sun", (1.0, 3.0, -2.0), down, {"type": "directional", "color": [1.0, 0.9, 0.8],
                                                           "intensity": 683.0 * 0.8}),
                        ("Lamp", (0.5, 1.0, 0.0), IDENTITY, {"type": "point", "intensity": 683.0 * 500 / (4 * np.pi)}),
                        ("Spot", (0.0, 2.0, 0.0), down, {"type": "spot", "intensity": 683.0 * 2000 / (4 * np.pi),
                                                         "spot": {"outerConeAngle": 0.5}})],
                scene_extras={"softvr_size": [320, 240], "softvr_camera": "front", "softvr_azimuth": 30.0,
                              "softvr_elevation": 10.0, "softvr_zoom": 1.5, "softvr_background": [0.2, 0.2, 0.25],
                              "softvr_background_top": [0.5, 0.5, 0.6], "softvr_light_kit": 0,
                              "softvr_bounds": [-1.0, 1.0, -1.0, 1.0, 0.0, 2.0]})
    doc = _json(path)
    doc["nodes"].append({"name": "rig", "translation": [0.3, 0.0, 0.0], "children": [len(doc["nodes"]) - 1]})
    doc["scenes"][0]["nodes"] = [n for n in doc["scenes"][0]["nodes"] if n != len(doc["nodes"]) - 2]
    doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
    _rewrite(path, doc)
    toml = _toml(tmp_path / "lit.toml", '''
[render]
size = [320, 240]
camera = "front"
azimuth = 30.0
elevation = 10.0
zoom = 1.5
background = [0.2, 0.2, 0.25]
background_top = [0.5, 0.5, 0.6]
light_kit = false
bounds = [-1.0, 1.0, -1.0, 1.0, 0.0, 2.0]
[[light]]
position = [1.0, 2.0, 3.0]
focal_point = [1.0, 2.0, 2.0]
color = [1.0, 0.9, 0.8]
intensity = 0.8
[[light]]
position = [0.5, 0.0, 1.0]
intensity = 0.5
[[light]]
position = [0.3, 0.0, 2.0]
focal_point = [0.3, 0.0, 1.0]
intensity = 2.0
[[plane]]
[[body]]
name = "post"
type = "kinematic"
box = [0.1, 0.1, 0.1]
position = [0.0, 0.0, 0.05]
[body.motion]
times = [0.0]
positions = [[0.0, 0.0, 0.05]]
''')
    g, t = read_gltf_scene(path).render, read_scene(toml).render
    assert {k: v for k, v in g.items() if k != "lights"} == {k: v for k, v in t.items() if k != "lights"}
    assert len(g["lights"]) == len(t["lights"]) == 3
    for a, b in zip(g["lights"], t["lights"]):
        assert set(a) == set(b)
        for key in a:
            np.testing.assert_allclose(a[key], b[key], atol=1e-6, err_msg=key)
    with load_scene(path, frames=1) as a, load_scene(toml, frames=1) as b:
        assert (a.width, a.height) == (b.width, b.height) == (320, 240)
        assert vars(a.camera) == vars(b.camera)
        assert a.renderer_options() == b.renderer_options() and a.renderer_options()["light_kit"] is False
        ra, rb = _Lights(), _Lights()
        a.setup_render(ra)
        b.setup_render(rb)
        np.testing.assert_allclose(np.array(ra.lights, dtype=object)[:, :2].tolist(),
                                   np.array(rb.lights, dtype=object)[:, :2].tolist(), atol=1e-6)
        np.testing.assert_allclose([x[3] for x in ra.lights], [0.8, 0.5, 2.0], rtol=1e-6)


def test_bad_glTF_and_toml_values_are_all_named(tmp_path):
    """Every bad property in one error, each named by its node (or the scene, or the light);
    TOML refuses rotations on a tool and a rotation count that is not one per time."""
    spin = _about((0.0, 1.0, 0.0), 30.0)
    path = _glb(tmp_path / "bad.glb", [
        ("gel", (0.1, 0.1, 0.1), (0.0, 0.05, 0.0), IDENTITY, {
            "softvr_type": "fem", "softvr_drive_times": [0.0], "softvr_drive_offsets": [0.0, 0.1],
            "softvr_velocity": [1.0, 2.0]}),
        ("rod", (0.1, 0.1, 0.1), (0.5, 0.05, 0.0), IDENTITY, {
            "softvr_type": "rigid", "softvr_drive_times": [0.0], "softvr_drive_offsets": [0.0, 0.0, 0.0]}),
        ("finger", (0.02, 0.02, 0.02), (0.0, 0.3, 0.0), IDENTITY, {"softvr_type": "tool", "softvr_stiffness": 1.0})],
        empties=[("ct", {"softvr_type": "volume", "softvr_file": "missing.npy", "softvr_cells": [2, 2],
                         "softvr_glow": 1}),
                 ("arm", {"softvr_type": "model", "softvr_file": "nothing.toml", "softvr_scale": 2.0})],
        lights=[("Sun", (0.0, 3.0, 0.0), IDENTITY, {"type": "area", "intensity": -1.0})],
        animations=[("finger", "rotation", [0.0, 1.0], [IDENTITY, spin])],
        scene_extras={"softvr_size": [0, 10], "softvr_light_kit": 2})
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    message = str(info.value)
    for fragment in ("bad.glb", "node 'gel'.drive_offsets: expected x0, y0, z0, x1, ... [m]: 3 numbers per time",
                     "node 'gel'.drive_offsets: expected held nodes to drive", "node 'gel'.velocity",
                     "node 'rod'.drive_offsets: expected a drive only on a fem or cloth object",
                     "node 'finger' animation: expected location keys only on a tool", "node 'ct'.file",
                     "node 'ct'.cells", "node 'ct'.glow", "node 'arm'.file", "node 'arm'.scale",
                     "KHR_lights_punctual.lights[0].type", "KHR_lights_punctual.lights[0].intensity",
                     "scene.size", "scene.light_kit"):
        assert fragment in message, fragment
    toml = _toml(tmp_path / "bad.toml", '''
[material.m]
[[body]]
name = "finger"
type = "tool"
sphere = 0.01
material = "m"
stiffness = 100.0
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.1], [0.0, 0.0, 0.2]]
rotations = [[0.0, 0.0, 0.0], [0.0, 0.0, 90.0]]
[[body]]
name = "probe"
type = "kinematic"
sphere = 0.01
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.1], [0.0, 0.0, 0.2]]
rotations = [[0.0, 0.0, 0.0]]
''')
    with pytest.raises(InputError) as info:
        read_scene(toml)
    assert "body[0].motion.rotations: expected positions only on a tool" in str(info.value)
    assert "body[1].motion.rotations: expected one [rx, ry, rz] [deg] per time" in str(info.value)


def _json(path):
    data = path.read_bytes()
    return json.loads(data[20:20 + struct.unpack("<I", data[12:16])[0]])


def _rewrite(path, doc):
    """``path`` with its JSON chunk replaced by ``doc`` (its BIN chunk kept)."""
    data = path.read_bytes()
    rest = data[20 + struct.unpack("<I", data[12:16])[0]:]
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk + rest
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def test_check_of_a_gltf_names_bad_objects_and_the_crossing_valid_ones_at_once(tmp_path, capsys):
    """As for TOML: a bad object (density in g/cm^3) is left out of the geometric check and
    reported; two valid rigid boxes that start crossing are reported with it; a bad coupling
    is reported without hiding its object."""
    from softvr.cli import main

    rigid = {"softvr_type": "rigid", "softvr_density": 600.0}
    path = tmp_path / "crossing.glb"
    _glb(path, [("left", (0.2, 0.2, 0.2), (0.0, 0.15, 0.0), IDENTITY, rigid),
                ("right", (0.2, 0.2, 0.2), (0.15, 0.2, -0.05), IDENTITY, rigid),
                ("heavy", (0.2, 0.2, 0.2), (0.1, 0.2, 0.0), IDENTITY, {**rigid, "softvr_density": 1.05}),
                ("far", (0.1, 0.1, 0.1), (2.0, 0.1, 0.0), IDENTITY,
                 {**rigid, "softvr_couple_to": "ghost", "softvr_coupling_stiffness": 100.0,
                  "softvr_coupling_points": [2.0, 0.0, 0.1]})])
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "3 problems" in err
    assert "node 'heavy'.density" in err and "1.05 (in other units?)" in err
    assert "node 'far'.couple_to" in err and "ghost" in err
    assert "bodies 'left' and 'right'" in err and "'heavy'" not in err.split("node 'heavy'.density")[1]


def test_a_gltf_scene_extra_asks_for_the_collision_free_start(tmp_path, capsys):
    """``softvr_collision_free_start`` (what the add-on sets; Blender writes 1): a soft box
    sunk 10 mm into a fixed table starts on it (every surface point at or above its top,
    z = 0.2 m, after the y-up -> z-up turn)."""
    from softvr.cli import main

    path = tmp_path / "sunk.glb"
    _glb(path, [("table", (0.4, 0.2, 0.4), (0.0, 0.1, 0.0), IDENTITY, {"softvr_type": "fixed"}),
                ("jelly", (0.1, 0.1, 0.1), (0.0, 0.24, 0.0), IDENTITY,
                 {"softvr_type": "fem", "softvr_young": 2e4, "softvr_cells": 0.025})],
         scene_extras={"softvr_collision_free_start": 1})
    assert main(["check", str(path)]) == 0
    assert "'jelly' pushed out of 'table'" in capsys.readouterr().out
    with load_scene(path, frames=1) as example:
        assert example._drawn_by_name["jelly"].vertices()[:, 2].min() >= 0.2 - 1e-6


def test_a_render_mesh_and_a_collision_budget_read_as_the_equivalent_toml(tmp_path):
    """A rigid die (0.1 m box) drawn as another object's mesh (a 0.12 m box, scenery: no
    softvr_type) and a fem block whose collision surface is simplified to 8 triangles: the
    drawn die is the other object's box where it is (z-up), the same as TOML's ``render_mesh``
    file gives, and it moves with the die; the budget is TOML's ``collision_triangles``."""
    import trimesh

    path = _glb(tmp_path / "drawn.glb", [
        ("die", (0.1, 0.1, 0.1), (0.0, 0.3, 0.0), IDENTITY,
         {"softvr_type": "rigid", "softvr_density": 500.0, "softvr_render_mesh": "die look"}),
        ("die look", (0.12, 0.12, 0.12), (0.0, 0.3, 0.0), IDENTITY, None),
        ("block", (0.2, 0.1, 0.2), (0.5, 0.05, 0.0), IDENTITY,
         {"softvr_type": "fem", "softvr_cells": 0.05, "softvr_collision_triangles": 8})])
    trimesh.creation.box((0.12, 0.12, 0.12)).export(tmp_path / "look.obj")
    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "die.obj")
    trimesh.creation.box((0.2, 0.2, 0.1)).export(tmp_path / "block.obj")
    toml = _toml(tmp_path / "drawn.toml", '''
[material.die]
density = 500.0
[material.block]
[[plane]]
[[body]]
name = "die"
type = "rigid"
mesh = "die.obj"
render_mesh = "look.obj"
material = "die"
position = [0.0, 0.0, 0.3]
[[body]]
name = "block"
type = "fem"
mesh = "block.obj"
cells = 0.05
material = "block"
collision_triangles = 8
position = [0.5, 0.0, 0.05]
''')
    glb_scene, toml_scene = read_gltf_scene(path), read_scene(toml)
    assert glb_scene.body("block").collision_triangles == toml_scene.body("block").collision_triangles == 8
    with load_scene(path, frames=2) as a, load_scene(toml, frames=2) as b:
        drawn = _sorted(a._drawn_by_name["die"].vertices())
        corners = _sorted(np.array(np.meshgrid([-0.06, 0.06], [-0.06, 0.06], [0.24, 0.36])).reshape(3, -1).T)
        np.testing.assert_allclose(drawn, corners, atol=1e-6)
        np.testing.assert_allclose(drawn, _sorted(b._drawn_by_name["die"].vertices()), atol=1e-6)
        assert len(a._drawn_by_name["block"].triangles) == len(b._drawn_by_name["block"].triangles)
        for _ in range(2):
            a.step()
        fall = a.bodies["die"].position[2] - 0.3
        assert fall < -1e-3  # it falls, and its drawn box with it
        np.testing.assert_allclose(_sorted(a._drawn_by_name["die"].vertices()), corners + [0.0, 0.0, fall],
                                   atol=1e-6)
